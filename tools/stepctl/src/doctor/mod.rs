//! `stepctl doctor`: the bring-up checks (docs/stepctl.md "stepctl doctor",
//! docs/bring-up.md). [`read`] asks the box everything once (diagnostics,
//! each axis's state, chip STATUS, what the bridge configured on each chip
//! and what the chip holds, the tick counter twice, the I/O extension's
//! loopback when asked); [`judge`] is a pure function of what was read and
//! says OK / WARN / FAIL per check, what it means and what to look at on
//! the board.
//!
//! This file holds the readings, the verdicts and the report; [`read`] is in
//! `read.rs`, the box-wide checks in `judge.rs`, each axis's in `axis.rs`.

mod axis;
mod judge;
mod read;

pub use axis::{judge_axis, judge_registers};
pub use judge::{
    judge, judge_chain, judge_loopback, judge_modbus, judge_other_buses, judge_reset_cause,
    judge_settings, judge_supply, judge_temperature, judge_tick,
};
pub use read::read;

use bridge_logic::ext_space::configured;
use bridge_logic::postep60::PowerStage;
use bridge_logic::powerstep::registers::Register;
use serde::Serialize;

use crate::bus::{u32_of, Bus};
use crate::error::{Error, Result};

/// The powerSTEP01's motor supply range the doctor takes as plausible, V
/// (the datasheet's operating range is 7.5–85 V; below 8 V the chip's
/// under-voltage lockout is close).
pub const SUPPLY_MIN_V: f64 = 8.0;
pub const SUPPLY_MAX_V: f64 = 85.0;
/// How far from the board's nominal supply is still OK (voltage-mode
/// currents are computed for the nominal).
pub const SUPPLY_TOLERANCE: f64 = 0.20;
/// Registers per extension read (USB carries at most 16).
const CHUNK: u16 = 16;

/// OK / WARN / FAIL.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum Verdict {
    Ok,
    Warn,
    Fail,
}

impl Verdict {
    pub fn label(self) -> &'static str {
        match self {
            Verdict::Ok => "OK",
            Verdict::Warn => "WARN",
            Verdict::Fail => "FAIL",
        }
    }
}

/// One judged check.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Check {
    pub check: String,
    pub verdict: Verdict,
    /// What was found, in one line.
    pub meaning: String,
    /// What to look at on the board (empty when OK).
    pub check_on_board: String,
}

fn check(
    name: impl Into<String>,
    verdict: Verdict,
    meaning: impl Into<String>,
    board: &str,
) -> Check {
    Check {
        check: name.into(),
        verdict,
        meaning: meaning.into(),
        check_on_board: if verdict == Verdict::Ok {
            String::new()
        } else {
            board.to_string()
        },
    }
}

/// What the user says the box should be.
#[derive(Debug, Clone, PartialEq)]
pub struct Expect {
    /// Chips on the chain (`--expect-axes`); None: any number but 0.
    pub axes: Option<u16>,
    /// The board's nominal motor supply, V (`--supply`).
    pub supply_v: f64,
    /// How far the measured tick rate may be off, and which share of the
    /// ticks may have overrun, before the tick is a WARN (a fraction;
    /// `--tick-tolerance` in %).
    pub tick_tolerance: f64,
}

/// `--tick-tolerance`'s default, %: a board's crystal and the Modbus
/// timing error of the measurement stay far below it.
pub const TICK_TOLERANCE_PERCENT: f64 = 2.0;

impl Default for Expect {
    fn default() -> Expect {
        Expect {
            axes: None,
            supply_v: f64::from(PowerStage::REFERENCE.supply_millivolts) / 1000.0,
            tick_tolerance: TICK_TOLERANCE_PERCENT / 100.0,
        }
    }
}

/// One axis as read.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisReading {
    /// The id stepctl addressed it with.
    pub unit: u8,
    /// 0x0600..0x0609, or why it could not be read.
    pub block: std::result::Result<Vec<u16>, String>,
    /// STATUS by GetParam (0x011B, clears nothing).
    pub status: std::result::Result<u16, String>,
    /// 0x0700..0x0723.
    pub configured: std::result::Result<Vec<u16>, String>,
    /// The chip's value of every register the bridge configures.
    pub chip: Vec<(Register, std::result::Result<u32, String>)>,
}

/// A measured tick rate: ticks counted between two reads `seconds` apart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickRate {
    pub ticks: u32,
    pub seconds: f64,
}

/// The I/O extension's loopback transfer.
#[derive(Debug, Clone, PartialEq)]
pub enum Loopback {
    /// Not asked for.
    NotRun,
    /// Not run, and why (the port's box mapping in use, refused).
    Skipped(String),
    /// Sent and received 32 bits.
    Done { sent: u32, received: u32 },
}

/// Everything the doctor read.
#[derive(Debug, Clone, PartialEq)]
pub struct Reading {
    pub bus: String,
    /// Diagnostics 0x0300..0x034F, or why the box did not answer.
    pub diag: std::result::Result<Vec<u16>, String>,
    pub axes: Vec<AxisReading>,
    pub tick: Option<TickRate>,
    pub loopback: Loopback,
}

/// Options of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    pub first_id: u8,
    pub loopback: bool,
    /// At least this long between the two tick-counter reads.
    pub seconds: f64,
}

fn word(d: &[u16], at: u8) -> u16 {
    d.get(usize::from(at)).copied().unwrap_or(0)
}

fn dword(d: &[u16], at: u8) -> u32 {
    let i = usize::from(at);
    u32_of(d.get(i..i + 2).unwrap_or(&[]))
}

/// What the bridge configures on an axis: (register, value) from 0x0700's mask.
pub fn configured_registers(block: &[u16]) -> Vec<(Register, u32)> {
    let mask = dword(block, configured::MASK);
    Register::all()
        .filter(|r| mask & 1 << r.address() != 0)
        .map(|r| (r, u32::from(word(block, r.address()))))
        .collect()
}

/// Counts of OK, WARN and FAIL.
pub fn summary(checks: &[Check]) -> (usize, usize, usize) {
    let n = |v| checks.iter().filter(|c| c.verdict == v).count();
    (n(Verdict::Ok), n(Verdict::Warn), n(Verdict::Fail))
}

/// The report as text: one line per check, what to check indented below.
pub fn text(checks: &[Check]) -> String {
    let mut s = String::new();
    for c in checks {
        s.push_str(&format!(
            "{:<4}  {}: {}\n",
            c.verdict.label(),
            c.check,
            c.meaning
        ));
        if !c.check_on_board.is_empty() {
            s.push_str(&format!("      check: {}\n", c.check_on_board));
        }
    }
    let (ok, warn, fail) = summary(checks);
    s.push_str(&format!("{ok} OK, {warn} WARN, {fail} FAIL"));
    s
}

/// For `stepctl doctor`: read, judge.
pub fn run(bus: &mut dyn Bus, opts: &Options, expect: &Expect) -> Result<Vec<Check>> {
    if !(0.0..=60.0).contains(&opts.seconds) {
        return Err(Error::Usage(format!("--seconds {}: 0..=60", opts.seconds)));
    }
    let r = read(bus, opts);
    Ok(judge(&r, expect))
}

/// What the doctor's tests share: a healthy box as read, and a check by name.
#[cfg(test)]
mod test_util {
    use super::*;
    use bridge_logic::ext_space::{configured, diag};

    /// The diagnostics block of a healthy 2-axis box on 24 V, 25 °C, after
    /// `ticks` ticks of 1000 µs.
    pub(crate) fn healthy_diag() -> Vec<u16> {
        let mut d = vec![0u16; diag::LEN];
        d[usize::from(diag::MODBUS_FRAMES) + 1] = 500;
        d[usize::from(diag::TICK_MAX_US) + 1] = 180;
        d[usize::from(diag::TICKS) + 1] = 50_000;
        d[usize::from(diag::CHAIN_LENGTH)] = 2;
        d[usize::from(diag::RESET_CAUSE)] = 1;
        d[usize::from(diag::TICK_PERIOD_US)] = 1000;
        d[usize::from(diag::SUPPLY)] = 333;
        d[usize::from(diag::TEMPERATURE)] = 200;
        d
    }

    pub(crate) fn set32(d: &mut [u16], at: u8, v: u32) {
        d[usize::from(at)] = (v >> 16) as u16;
        d[usize::from(at) + 1] = v as u16;
    }

    /// An axis that rests, configured with CONFIG and OCD_TH as read back.
    pub(crate) fn healthy_axis(unit: u8) -> AxisReading {
        let mut block = vec![0u16; 10];
        block[6] = 1;
        let mut c = vec![0u16; configured::LEN];
        c[usize::from(Register::Config.address())] = 0x2C98;
        c[usize::from(Register::OcdTh.address())] = 8;
        let mask = 1u32 << Register::Config.address() | 1 << Register::OcdTh.address();
        set32(&mut c, configured::MASK, mask);
        c[usize::from(configured::SET_UP)] = 1;
        AxisReading {
            unit,
            block: Ok(block),
            status: Ok(0xE612),
            configured: Ok(c),
            chip: vec![(Register::OcdTh, Ok(8)), (Register::Config, Ok(0x2C98))],
        }
    }

    pub(crate) fn healthy() -> Reading {
        Reading {
            bus: "tcp fake:5020".into(),
            diag: Ok(healthy_diag()),
            axes: vec![healthy_axis(1), healthy_axis(2)],
            tick: Some(TickRate {
                ticks: 1000,
                seconds: 1.0,
            }),
            loopback: Loopback::NotRun,
        }
    }

    pub(crate) fn find<'a>(checks: &'a [Check], name: &str) -> &'a Check {
        checks
            .iter()
            .find(|c| c.check == name)
            .unwrap_or_else(|| panic!("no check {name:?} in {checks:#?}"))
    }

    pub(crate) fn expect2() -> Expect {
        Expect {
            axes: Some(2),
            ..Expect::default()
        }
    }
}
