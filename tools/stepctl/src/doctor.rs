//! `stepctl doctor`: the bring-up checks (README "stepctl doctor",
//! docs/bring-up.md). [`read`] asks the box everything once (diagnostics,
//! each axis's state, chip STATUS, what the bridge configured on each chip
//! and what the chip holds, the tick counter twice, the I/O extension's
//! loopback when asked); [`judge`] is a pure function of what was read and
//! says OK / WARN / FAIL per check, what it means and what to look at on
//! the board.

use std::time::{Duration, Instant};

use bridge_logic::ext_space::{block, configured, diag};
use bridge_logic::postep60::PowerStage;
use bridge_logic::powerstep::registers::Register;
use serde::Serialize;

use crate::bus::{u32_of, Bus};
use crate::error::{Error, Result};
use crate::ops::{ext, fault_names};

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

fn read_block(bus: &mut dyn Bus, unit: u8, address: u16, len: u16) -> Result<Vec<u16>> {
    let mut out = Vec::with_capacity(usize::from(len));
    let mut at = 0;
    while at < len {
        let n = CHUNK.min(len - at);
        out.extend(bus.read(unit, address + at, n)?);
        at += n;
    }
    Ok(out)
}

fn word(d: &[u16], at: u8) -> u16 {
    d.get(usize::from(at)).copied().unwrap_or(0)
}

fn dword(d: &[u16], at: u8) -> u32 {
    let i = usize::from(at);
    u32_of(d.get(i..i + 2).unwrap_or(&[]))
}

/// The tick counter and the host time halfway through its read.
fn ticks_now(bus: &mut dyn Bus, unit: u8) -> Result<(u32, Instant)> {
    let t0 = Instant::now();
    let r = bus.read(unit, ext(block::DIAG, diag::TICKS), 2)?;
    let t1 = Instant::now();
    Ok((u32_of(&r), t0 + (t1 - t0) / 2))
}

/// What the bridge configures on an axis: (register, value) from 0x0700's mask.
pub fn configured_registers(block: &[u16]) -> Vec<(Register, u32)> {
    let mask = dword(block, configured::MASK);
    Register::all()
        .filter(|r| mask & 1 << r.address() != 0)
        .map(|r| (r, u32::from(word(block, r.address()))))
        .collect()
}

fn read_chip(bus: &mut dyn Bus, unit: u8, reg: Register) -> std::result::Result<u32, String> {
    let width = if reg.bytes() == 3 { 2 } else { 1 };
    bus.read(unit, 0x0100 | u16::from(reg.address()), width)
        .map(|r| u32_of(&r))
        .map_err(|e| e.to_string())
}

fn read_axis(bus: &mut dyn Bus, unit: u8) -> AxisReading {
    let block = read_block(bus, unit, ext(block::AXIS, 0), 10).map_err(|e| e.to_string());
    let status = read_chip(bus, unit, Register::Status).map(|v| v as u16);
    let configured = read_block(bus, unit, ext(block::CONFIGURED, 0), configured::LEN as u16)
        .map_err(|e| e.to_string());
    let chip = match &configured {
        Ok(c) => configured_registers(c)
            .into_iter()
            .map(|(r, _)| (r, read_chip(bus, unit, r)))
            .collect(),
        Err(_) => Vec::new(),
    };
    AxisReading {
        unit,
        block,
        status,
        configured,
        chip,
    }
}

/// Read everything [`judge`] needs. Only a box that does not answer at all
/// ends it early (`diag` then holds why).
pub fn read(bus: &mut dyn Bus, opts: &Options) -> Reading {
    let unit = opts.first_id;
    let mut r = Reading {
        bus: bus.name(),
        diag: Err(String::new()),
        axes: Vec::new(),
        tick: None,
        loopback: Loopback::NotRun,
    };
    r.diag =
        read_block(bus, unit, ext(block::DIAG, 0), diag::LEN as u16).map_err(|e| e.to_string());
    let Ok(d) = &r.diag else {
        return r;
    };
    let start = ticks_now(bus, unit);
    let n = word(d, diag::CHAIN_LENGTH);
    for k in 0..n {
        let Some(u) = u8::try_from(u16::from(unit) + k).ok() else {
            break;
        };
        r.axes.push(read_axis(bus, u));
    }
    if opts.loopback {
        r.loopback = loopback(bus, unit, n);
    }
    if let Ok((t0, at0)) = start {
        let rest = Duration::from_secs_f64(opts.seconds.max(0.0)).saturating_sub(at0.elapsed());
        std::thread::sleep(rest);
        if let Ok((t1, at1)) = ticks_now(bus, unit) {
            if t1 >= t0 {
                r.tick = Some(TickRate {
                    ticks: t1 - t0,
                    seconds: (at1 - at0).as_secs_f64(),
                });
            }
        }
    }
    r
}

/// I/O extension registers (`docs/ioext.md`).
mod io {
    pub const OPTIONS: u16 = 0x0200;
    pub const CONFIG: u16 = 0x0202;
    pub const TX: u16 = 0x0210;
    pub const RX: u16 = 0x0220;
    pub const MAPPING: u16 = 0x0240;
    /// Bit 11 of the configuration: a transfer ended.
    pub const DONE: u32 = 1 << 11;
    /// 32 bits, mode 0, N = 10 (1.02 µs a bit), CS released, no restart.
    pub const LOOPBACK_CONFIG: u32 = 1 << 28 | 10 << 16 | 31;
    pub const PATTERN: u32 = 0xA55A_0FF0;
}

/// One 32-bit transfer with a MOSI → MISO jumper: what comes back must be
/// what went out. The port's options, configuration and transmit words are
/// put back after it; refused while the box mapping uses the port.
fn loopback(bus: &mut dyn Bus, unit: u8, axes: u16) -> Loopback {
    match run_loopback(bus, unit, axes) {
        Ok(l) => l,
        Err(e) => Loopback::Skipped(e.to_string()),
    }
}

fn run_loopback(bus: &mut dyn Bus, unit: u8, axes: u16) -> Result<Loopback> {
    for k in 0..axes {
        let Some(u) = u8::try_from(u16::from(unit) + k).ok() else {
            break;
        };
        let m = bus.read(u, io::MAPPING + 8 * k, 7)?;
        if m.iter().any(|e| e & 0x8000 != 0) {
            return Ok(Loopback::Skipped(format!(
                "the I/O extension drives the box panel (axis {u} has mapped inputs or lamps, \
                 0x{:04X}): unmap them first",
                io::MAPPING + 8 * k
            )));
        }
    }
    let options = bus.read(unit, io::OPTIONS, 2)?;
    let config = bus.read(unit, io::CONFIG, 2)?;
    let tx = bus.read(unit, io::TX, 2)?;
    let words = |v: u32| [(v >> 16) as u16, v as u16];
    bus.write(unit, io::CONFIG, &words(io::LOOPBACK_CONFIG))?;
    bus.write(unit, io::OPTIONS, &[0, 1])?;
    // Reading the receive words clears the status bit; writing the
    // transmit words starts the transfer at the next control tick.
    bus.read(unit, io::RX, 2)?;
    bus.write(unit, io::TX, &words(io::PATTERN))?;
    let deadline = Instant::now() + Duration::from_secs(2);
    let received = loop {
        let c = u32_of(&bus.read(unit, io::CONFIG, 2)?);
        if c & io::DONE != 0 {
            break Some(u32_of(&bus.read(unit, io::RX, 2)?));
        }
        if Instant::now() >= deadline {
            break None;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    // Put the port back as it was (the status bit is not configuration;
    // the transmit words are written while the port is on, which sends
    // them once).
    bus.write(unit, io::CONFIG, &words(u32_of(&config) & !io::DONE))?;
    bus.write(unit, io::TX, &tx)?;
    bus.write(unit, io::OPTIONS, &options)?;
    Ok(match received {
        Some(received) => Loopback::Done {
            sent: io::PATTERN,
            received,
        },
        None => Loopback::Skipped("the transfer did not end within 2 s".into()),
    })
}

// ------------------------------------------------------------ judgement

const BOARD_CHAIN: &str = "SPI1 to the chain: SCK PA5, MOSI PA7 to SDI of chip 0, MISO PA6 from SDO of the last chip, \
                           CS PA4 to every chip; STBY/RESET PC4 high after boot; every chip's VDD (3.3 V) and motor \
                           supply VS; each SDO to the next SDI (one dead chip breaks the whole echo)";
const BOARD_SUPPLY: &str = "the bench supply's voltage and current limit, the motor supply at the chips (VS), \
                            the divider into PA0 (÷20 on the reference board) and the ADC reference (VDDA)";
const BOARD_UVLO: &str = "supply dips at the chip: the bench supply's current limit (raise it above the motor current), \
                          bulk and local decoupling at VS, the supply wiring's resistance, STBY/RESET glitches; then \
                          `stepctl reset-faults AXIS`";

/// The verdicts for everything read.
pub fn judge(r: &Reading, e: &Expect) -> Vec<Check> {
    let d = match &r.diag {
        Ok(d) => d,
        Err(why) => {
            return vec![check(
                "link",
                Verdict::Fail,
                format!("no answer from the box on {}: {why}", r.bus),
                "the box's power and the MCU's 3.3 V; Modbus: RS-485 A/B (swap them once), termination, \
                 --baud/--parity as the box's settings (factory 9600 even), --first-id; USB: the cable and \
                 the udev rule; the defmt log (cargo fw-run) says whether the firmware booted",
            )]
        }
    };
    let mut out = vec![check(
        "link",
        Verdict::Ok,
        format!("the box answers on {}", r.bus),
        "",
    )];
    out.push(judge_chain(d, e));
    out.push(judge_supply(word(d, diag::SUPPLY), e.supply_v));
    out.push(judge_temperature(word(d, diag::TEMPERATURE)));
    out.push(judge_settings(d));
    out.push(judge_reset_cause(word(d, diag::RESET_CAUSE)));
    out.push(judge_modbus(d));
    out.push(judge_other_buses(d));
    out.push(judge_tick(d, r.tick, e.tick_tolerance));
    for (k, a) in r.axes.iter().enumerate() {
        let resets = word(d, diag::CHIP_RESETS_AXIS0.saturating_add(k as u8));
        out.extend(judge_axis(a, resets));
    }
    match &r.loopback {
        Loopback::NotRun => {}
        Loopback::Skipped(why) => out.push(check(
            "I/O extension loopback",
            Verdict::Warn,
            format!("not run: {why}"),
            "the port's settings (0x0200..): disable the box mapping before the loopback",
        )),
        Loopback::Done { sent, received } => out.push(judge_loopback(*sent, *received)),
    }
    out
}

pub fn judge_chain(d: &[u16], e: &Expect) -> Check {
    let n = word(d, diag::CHAIN_LENGTH);
    let state = word(d, diag::CHAIN_STATE);
    let errors = dword(d, diag::CHAIN_ERRORS);
    let want = e
        .axes
        .map(|x| format!(", {x} expected"))
        .unwrap_or_default();
    if n == 0 {
        return check(
            "chain",
            Verdict::Fail,
            format!("no powerSTEP01 found at boot (chain length 0{want}): the detection pattern never came back"),
            BOARD_CHAIN,
        );
    }
    match e.axes {
        Some(x) if x != n => {
            return check(
                "chain",
                Verdict::Fail,
                format!("{n} chips found, {x} expected"),
                "a chip bypassed or missing: each chip's SDO to the next one's SDI, solder joints, the \
                 chips' supplies; a chip held in reset (STBY)",
            )
        }
        _ => {}
    }
    match state {
        2 => check(
            "chain",
            Verdict::Fail,
            format!("{n} chips, but the chain is dead: {errors} failed batches, STBY is held low until the MCU resets"),
            "SPI1 signal integrity (SCK PA5, MISO PA6, MOSI PA7, CS PA4: lengths, ground, ringing), the \
             chips' supplies; restart after fixing",
        ),
        1 => check(
            "chain",
            Verdict::Fail,
            format!("{n} chips, the last chain batch failed ({errors} failed batches)"),
            "SPI1 signal integrity and the chips' supplies",
        ),
        _ if errors > 0 => check(
            "chain",
            Verdict::Warn,
            format!("{n} chips{want}, working; {errors} chain batches failed since the counters were cleared"),
            "SPI1 signal integrity (SCK, MISO, MOSI, CS: lengths, ground, ringing)",
        ),
        _ => check("chain", Verdict::Ok, format!("{n} chips{want}, working"), ""),
    }
}

/// `code` in 0x10's units (72 mV).
pub fn judge_supply(code: u16, nominal_v: f64) -> Check {
    let v = f64::from(code) * 0.072;
    if !(SUPPLY_MIN_V..=SUPPLY_MAX_V).contains(&v) {
        return check(
            "supply",
            Verdict::Fail,
            format!(
                "{v:.1} V measured: outside the powerSTEP01's {SUPPLY_MIN_V:.0}–{SUPPLY_MAX_V:.0} V \
                 (off, current-limited, or a wrong reading)"
            ),
            BOARD_SUPPLY,
        );
    }
    if (v - nominal_v).abs() > nominal_v * SUPPLY_TOLERANCE {
        return check(
            "supply",
            Verdict::Warn,
            format!(
                "{v:.1} V measured, {nominal_v:.1} V nominal: voltage-mode currents (KVAL) are computed for \
                 the nominal and scale with the real supply"
            ),
            "the bench supply's setting (or pass --supply V for this board's nominal), the divider into PA0",
        );
    }
    check(
        "supply",
        Verdict::Ok,
        format!("{v:.1} V ({nominal_v:.1} V nominal)"),
        "",
    )
}

/// `code` in 0x11's units (0.125 °C; the box reads 0 for anything ≤ 0 °C).
pub fn judge_temperature(code: u16) -> Check {
    let t = f64::from(code) * 0.125;
    let board =
        "the ADC's temperature channel and VREFINT (a wrong VDDA shifts both the supply and the \
                 temperature), then the board's cooling";
    if code == 0 || t > 105.0 {
        check(
            "temperature",
            Verdict::Fail,
            format!("{t:.1} °C: not a plausible die temperature"),
            board,
        )
    } else if t > 70.0 {
        check(
            "temperature",
            Verdict::Warn,
            format!("{t:.1} °C: hot"),
            "airflow and heat sinking; the motor currents",
        )
    } else {
        check("temperature", Verdict::Ok, format!("{t:.1} °C"), "")
    }
}

pub fn judge_settings(d: &[u16]) -> Check {
    let source = word(d, diag::SETTINGS_SOURCE);
    let last = word(d, diag::LAST_SAVE);
    let errors = dword(d, diag::SAVE_ERRORS);
    let board = "the settings store (flash sectors 10–11): save once (`stepctl settings save`) and restart; \
                 if it stays unreadable or saves fail, erase the two sectors with probe-rs and save again";
    if source == 2 {
        return check(
            "settings",
            Verdict::Fail,
            "the store could not be read at boot: factory settings are in use (the LED blinks at 5 Hz)",
            board,
        );
    }
    if last == 2 || errors > 0 {
        return check(
            "settings",
            Verdict::Fail,
            format!("the last save failed ({errors} failed saves)"),
            board,
        );
    }
    let what = match source {
        0 => "loaded from the store",
        _ => "factory settings (nothing saved yet)",
    };
    let pending = if last == 3 { "; a save is pending" } else { "" };
    check("settings", Verdict::Ok, format!("{what}{pending}"), "")
}

pub fn judge_reset_cause(code: u16) -> Check {
    match code {
        3 => check(
            "reset cause",
            Verdict::Fail,
            "the watchdog reset the MCU: the control loop stalled",
            "what ran before the reset (the defmt log), a save's erase interrupted, a hang in a driver",
        ),
        5 => check(
            "reset cause",
            Verdict::Warn,
            "brown-out: the MCU's 3.3 V dipped",
            "the 3.3 V regulator and its input, decoupling at the MCU",
        ),
        1 => check("reset cause", Verdict::Ok, "power-on", ""),
        2 => check("reset cause", Verdict::Ok, "reset pin (probe or button)", ""),
        4 => check("reset cause", Verdict::Ok, "software (a system reset was asked for)", ""),
        _ => check(
            "reset cause",
            Verdict::Ok,
            "not reported (no reset flags: QEMU)",
            "",
        ),
    }
}

pub fn judge_modbus(d: &[u16]) -> Check {
    let frames = dword(d, diag::MODBUS_FRAMES);
    let crc = dword(d, diag::MODBUS_CRC_ERRORS);
    let framing = dword(d, diag::MODBUS_FRAMING_ERRORS);
    let bad = crc.saturating_add(framing);
    let board =
        "RS-485: A/B polarity, 120 Ω termination at both ends of the line only, bias resistors, \
                 a common ground, one baud rate and parity on every node";
    let what = format!("{frames} frames, {crc} CRC errors, {framing} framing errors");
    if bad == 0 {
        check("Modbus line", Verdict::Ok, what, "")
    } else if bad > 3.max(frames / 100) {
        check("Modbus line", Verdict::Fail, what, board)
    } else {
        check("Modbus line", Verdict::Warn, what, board)
    }
}

pub fn judge_other_buses(d: &[u16]) -> Check {
    let i2c = dword(d, diag::I2C_UNKNOWN)
        .saturating_add(dword(d, diag::I2C_SHORT))
        .saturating_add(dword(d, diag::I2C_LONG));
    let usb = dword(d, diag::USB_BAD).saturating_add(dword(d, diag::USB_UNKNOWN));
    let trips = dword(d, diag::WATCHDOG_TRIPS);
    let what = format!(
        "I2C {i2c} bad requests, USB {usb} bad reports, communication watchdog {trips} trips"
    );
    if i2c + usb + trips == 0 {
        check("other buses", Verdict::Ok, what, "")
    } else {
        check(
            "other buses",
            Verdict::Warn,
            what,
            "the I2C master's commands and pull-ups (PB6/PB7), the USB host software; a watchdog trip: a \
             master that went silent while an axis moved",
        )
    }
}

/// The control tick: FAIL if none ran or the measured rate is off by more
/// than half; WARN if it is off by more than `tolerance`, if more than
/// `tolerance` of the ticks overran, or if none overran but the longest
/// took 90 % of the period (plus the tolerance) or more.
pub fn judge_tick(d: &[u16], rate: Option<TickRate>, tolerance: f64) -> Check {
    let period = u32::from(word(d, diag::TICK_PERIOD_US));
    let max = dword(d, diag::TICK_MAX_US);
    let overruns = dword(d, diag::TICK_OVERRUNS);
    let ticks = dword(d, diag::TICKS).max(1);
    let share = f64::from(overruns) / f64::from(ticks);
    let nominal = if period > 0 {
        1e6 / f64::from(period)
    } else {
        0.0
    };
    let measured = rate
        .filter(|r| r.seconds > 0.0)
        .map(|r| f64::from(r.ticks) / r.seconds);
    let mut what = format!("period {period} µs, longest {max} µs, {overruns} overruns");
    if let Some(m) = measured {
        what.push_str(&format!(", measured {m:.0} Hz of {nominal:.0} Hz"));
    }
    let board = "the load per tick (chips on the chain, a slow I/O-extension transfer), the MCU clock (HSE 8 MHz \
                 crystal: a slow rate means the PLL runs from the wrong source)";
    if period == 0 {
        return check(
            "control tick",
            Verdict::Fail,
            "no control tick has run",
            board,
        );
    }
    let off = measured.map(|m| (m - nominal).abs() / nominal);
    if off.is_some_and(|o| o > 0.5) {
        return check("control tick", Verdict::Fail, what, board);
    }
    let close = overruns == 0 && f64::from(max) >= f64::from(period) * (0.9 + tolerance);
    if share > tolerance || close || off.is_some_and(|o| o > tolerance) {
        return check("control tick", Verdict::Warn, what, board);
    }
    check("control tick", Verdict::Ok, what, "")
}

/// STATUS bits (the facts file's §2).
mod st {
    pub const HIZ: u16 = 1 << 0;
    pub const UVLO: u16 = 1 << 9;
    pub const TH_SHIFT: u16 = 11;
    pub const OCD: u16 = 1 << 13;
}

pub fn judge_axis(a: &AxisReading, resets: u16) -> Vec<Check> {
    let u = a.unit;
    let mut out = Vec::new();
    let name = |what: &str| format!("axis {u} {what}");
    // State and latched faults.
    match &a.block {
        Err(e) => out.push(check(
            name("state"),
            Verdict::Fail,
            format!("cannot be read: {e}"),
            BOARD_CHAIN,
        )),
        Ok(b) => {
            let faults = word(b, 8);
            let stopping = faults & 0x3F;
            let stuck = matches!(a.status, Ok(0x0000 | 0xFFFF));
            let what = if stuck {
                format!(
                    "faults {} (decoded from a STATUS that reads stuck: see STATUS)",
                    fault_names(faults)
                )
            } else {
                format!("faults {}", fault_names(faults))
            };
            if faults & 1 << 5 != 0 {
                out.push(check(
                    name("faults"),
                    Verdict::Fail,
                    format!("{what}: under-voltage lockout latched (the supply at the chip dipped, or the chip reset)"),
                    &BOARD_UVLO.replace("AXIS", &u.to_string()),
                ));
            } else if faults & 0x06 != 0 {
                out.push(check(
                    name("faults"),
                    Verdict::Fail,
                    format!("{what}: overcurrent, the bridges switched off"),
                    &format!(
                        "the current setting against the motor's rating (`stepctl settings set {u} current …`), \
                         OCD_TH, shorts in the motor wiring and connector; then `stepctl reset-faults {u}`"
                    ),
                ));
            } else if faults & 0x01 != 0 {
                out.push(check(
                    name("faults"),
                    Verdict::Fail,
                    format!("{what}: thermal shutdown"),
                    "heat sinking of the chips, the motor current",
                ));
            } else if stopping != 0 {
                out.push(check(
                    name("faults"),
                    Verdict::Fail,
                    format!("{what}: a gate-driver fault"),
                    "the power stage's gate drive (GATECFG1/2), the bootstrap capacitors, VS",
                ));
            } else if faults != 0 {
                out.push(check(
                    name("faults"),
                    Verdict::Warn,
                    format!("{what}: a stall was detected"),
                    "the load and the speed, STALL_TH",
                ));
            } else {
                out.push(check(name("faults"), Verdict::Ok, "none", ""));
            }
        }
    }
    if resets > 0 {
        out.push(check(
            name("chip resets"),
            Verdict::Warn,
            format!("the chip reset {resets} time(s) since the counters were cleared (the bridge set it up again each time)"),
            "the chip's supplies (VS and VDD dips, decoupling, the bench supply's current limit), \
             STBY/RESET (PC4) glitches, ESD on the motor cable",
        ));
    }
    // STATUS.
    out.push(match a.status {
        Err(ref e) => check(
            name("STATUS"),
            Verdict::Fail,
            format!("the chip does not answer GetParam: {e}"),
            BOARD_CHAIN,
        ),
        Ok(s @ (0x0000 | 0xFFFF)) => check(
            name("STATUS"),
            Verdict::Fail,
            format!("0x{s:04X}: SDO stuck {} (a dead chip, or a broken SDO→SDI link on the way to MISO)", if s == 0 { "low" } else { "high" }),
            BOARD_CHAIN,
        ),
        Ok(s) => {
            let th = s >> st::TH_SHIFT & 3;
            if th >= 2 {
                check(name("STATUS"), Verdict::Fail, format!("0x{s:04X}: thermal shutdown"), "heat sinking, the motor current")
            } else if s & st::OCD == 0 {
                check(name("STATUS"), Verdict::Fail, format!("0x{s:04X}: overcurrent flagged"), "the current setting, the motor wiring")
            } else if th == 1 {
                check(name("STATUS"), Verdict::Warn, format!("0x{s:04X}: thermal warning"), "heat sinking, the motor current")
            } else if s & st::UVLO == 0 {
                check(name("STATUS"), Verdict::Warn, format!("0x{s:04X}: under-voltage flagged"), BOARD_UVLO)
            } else {
                let hiz = if s & st::HIZ != 0 { ", bridges off" } else { "" };
                check(name("STATUS"), Verdict::Ok, format!("0x{s:04X}{hiz}"), "")
            }
        }
    });
    out.push(judge_registers(a));
    out
}

/// The chip's registers against what the bridge configured.
pub fn judge_registers(a: &AxisReading) -> Check {
    let name = format!("axis {} chip registers", a.unit);
    let c = match &a.configured {
        Ok(c) => c,
        Err(e) => {
            return check(
                name,
                Verdict::Fail,
                format!("what the bridge configured cannot be read (0x0700): {e}"),
                "the firmware version (0x0700 needs this firmware)",
            )
        }
    };
    let moving = a.block.as_ref().map(|b| word(b, 6) != 1).unwrap_or(false);
    let pending = word(c, configured::PENDING);
    let set_up = word(c, configured::SET_UP) != 0;
    let wanted = configured_registers(c);
    let mut differ = Vec::new();
    let mut unread = Vec::new();
    let mut compared = 0;
    for (reg, want) in &wanted {
        // The motion registers change while the axis moves.
        if moving && matches!(reg, Register::MaxSpeed | Register::Acc | Register::Dec) {
            continue;
        }
        let reg_name = reg.info().voltage_mode_name;
        match a.chip.iter().find(|(r, _)| r == reg).map(|(_, v)| v) {
            Some(Ok(v)) => {
                compared += 1;
                if v & reg.mask() != want & reg.mask() {
                    differ.push(format!(
                        "{reg_name} reads 0x{v:X}, the bridge wrote 0x{want:X}"
                    ));
                }
            }
            Some(Err(e)) => unread.push(format!("{reg_name}: {e}")),
            None => unread.push(format!("{reg_name}: not read")),
        }
    }
    if !set_up || pending > 0 {
        return check(
            name,
            Verdict::Warn,
            format!("the bridge is still configuring the chip ({pending} writes pending): run the doctor again"),
            "if it stays: the chip refuses writes (CMD_ERROR) or keeps resetting",
        );
    }
    if !unread.is_empty() {
        return check(
            name,
            Verdict::Fail,
            format!(
                "{} registers cannot be read: {}",
                unread.len(),
                unread.join("; ")
            ),
            BOARD_CHAIN,
        );
    }
    if !differ.is_empty() {
        let shown: Vec<_> = differ.iter().take(3).cloned().collect();
        let more = if differ.len() > 3 {
            format!(" (+{} more)", differ.len() - 3)
        } else {
            String::new()
        };
        return check(
            name,
            Verdict::Fail,
            format!("{} of {compared} differ: {}{more}", differ.len(), shown.join("; ")),
            "SPI1 bit errors (SCK/MISO/MOSI integrity, CS timing), a chip that does not take writes, a chip \
             that reset and answers with its reset values, or a dead chip on the chain",
        );
    }
    check(
        name,
        Verdict::Ok,
        format!("{compared} configured registers read back as written"),
        "",
    )
}

pub fn judge_loopback(sent: u32, received: u32) -> Check {
    if sent == received {
        check(
            "I/O extension loopback",
            Verdict::Ok,
            format!("sent 0x{sent:08X}, received it back"),
            "",
        )
    } else {
        check(
            "I/O extension loopback",
            Verdict::Fail,
            format!("sent 0x{sent:08X}, received 0x{received:08X}"),
            "the jumper PB15 (MOSI) → PB14 (MISO) on the I/O extension's connector; nothing else on the port \
             (a panel's '165 answers instead of the jumper)",
        )
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modbus::fake::{framed, rtu};

    /// The diagnostics block of a healthy 2-axis box on 24 V, 25 °C, after
    /// `ticks` ticks of 1000 µs.
    fn healthy_diag() -> Vec<u16> {
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

    fn set32(d: &mut [u16], at: u8, v: u32) {
        d[usize::from(at)] = (v >> 16) as u16;
        d[usize::from(at) + 1] = v as u16;
    }

    /// An axis that rests, configured with CONFIG and OCD_TH as read back.
    fn healthy_axis(unit: u8) -> AxisReading {
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

    fn healthy() -> Reading {
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

    fn find<'a>(checks: &'a [Check], name: &str) -> &'a Check {
        checks
            .iter()
            .find(|c| c.check == name)
            .unwrap_or_else(|| panic!("no check {name:?} in {checks:#?}"))
    }

    fn expect2() -> Expect {
        Expect {
            axes: Some(2),
            ..Expect::default()
        }
    }

    #[test]
    fn a_healthy_box_is_all_ok_and_every_ok_has_nothing_to_check() {
        let checks = judge(&healthy(), &expect2());
        assert_eq!(summary(&checks), (checks.len(), 0, 0), "{checks:#?}");
        assert!(checks.iter().all(|c| c.check_on_board.is_empty()));
        assert!(find(&checks, "chain")
            .meaning
            .contains("2 chips, 2 expected"));
        assert!(find(&checks, "axis 2 chip registers")
            .meaning
            .contains("2 configured registers read back"));
        let t = text(&checks);
        assert!(t.starts_with("OK    link:"), "{t}");
        assert!(
            t.ends_with(&format!("{} OK, 0 WARN, 0 FAIL", checks.len())),
            "{t}"
        );
    }

    #[test]
    fn no_answer_is_one_link_failure_that_names_the_wiring() {
        let r = Reading {
            diag: Err("no reply from id 1 on tcp fake:5020".into()),
            ..healthy()
        };
        let checks = judge(&r, &Expect::default());
        assert_eq!(checks.len(), 1);
        assert_eq!(checks[0].verdict, Verdict::Fail);
        assert!(checks[0].check_on_board.contains("A/B"));
    }

    #[test]
    fn chain_length_0_fails_and_points_at_spi1_stby_and_the_chip_supply() {
        let mut d = healthy_diag();
        d[usize::from(diag::CHAIN_LENGTH)] = 0;
        d[usize::from(diag::CHAIN_STATE)] = 3;
        let c = judge_chain(&d, &Expect::default());
        assert_eq!(c.verdict, Verdict::Fail);
        for pin in ["PA5", "PA6", "PA7", "PA4", "STBY", "VS"] {
            assert!(
                c.check_on_board.contains(pin),
                "{pin}: {}",
                c.check_on_board
            );
        }
    }

    #[test]
    fn fewer_chips_than_expected_fail_a_dead_or_failing_chain_fails_old_errors_warn() {
        let d = healthy_diag();
        let c = judge_chain(
            &d,
            &Expect {
                axes: Some(4),
                ..Expect::default()
            },
        );
        assert_eq!(
            (c.verdict, c.meaning.as_str()),
            (Verdict::Fail, "2 chips found, 4 expected")
        );
        assert_eq!(
            judge_chain(&d, &Expect::default()).verdict,
            Verdict::Ok,
            "no count expected"
        );
        let mut dead = d.clone();
        dead[usize::from(diag::CHAIN_STATE)] = 2;
        set32(&mut dead, diag::CHAIN_ERRORS, 10);
        let c = judge_chain(&dead, &Expect::default());
        assert_eq!(c.verdict, Verdict::Fail);
        assert!(c.meaning.contains("dead"), "{}", c.meaning);
        let mut failing = d.clone();
        failing[usize::from(diag::CHAIN_STATE)] = 1;
        assert_eq!(
            judge_chain(&failing, &Expect::default()).verdict,
            Verdict::Fail
        );
        let mut old = d;
        set32(&mut old, diag::CHAIN_ERRORS, 3);
        assert_eq!(judge_chain(&old, &Expect::default()).verdict, Verdict::Warn);
    }

    #[test]
    fn supply_outside_8_to_85_v_fails_far_from_nominal_warns() {
        let code = |v: f64| (v / 0.072).round() as u16;
        assert_eq!(judge_supply(code(24.0), 24.0).verdict, Verdict::Ok);
        assert_eq!(
            judge_supply(code(27.0), 24.0).verdict,
            Verdict::Ok,
            "within 20 %"
        );
        assert_eq!(judge_supply(code(3.0), 24.0).verdict, Verdict::Fail);
        assert_eq!(judge_supply(code(7.9), 24.0).verdict, Verdict::Fail);
        assert_eq!(judge_supply(code(90.0), 24.0).verdict, Verdict::Fail);
        let w = judge_supply(code(12.0), 24.0);
        assert_eq!(w.verdict, Verdict::Warn);
        assert!(
            w.meaning.contains("12.0 V measured, 24.0 V nominal"),
            "{}",
            w.meaning
        );
        assert_eq!(
            judge_supply(code(48.0), 48.0).verdict,
            Verdict::Ok,
            "--supply 48"
        );
        assert!(judge_supply(0, 24.0).check_on_board.contains("PA0"));
    }

    #[test]
    fn an_implausible_temperature_fails_a_hot_one_warns() {
        assert_eq!(judge_temperature(200).verdict, Verdict::Ok);
        assert_eq!(judge_temperature(0).verdict, Verdict::Fail, "≤ 0 °C");
        assert_eq!(judge_temperature(900).verdict, Verdict::Fail, "112 °C");
        assert_eq!(judge_temperature(600).verdict, Verdict::Warn, "75 °C");
    }

    #[test]
    fn an_unreadable_store_or_a_failed_save_fails_an_empty_store_is_fine() {
        let mut d = healthy_diag();
        assert_eq!(judge_settings(&d).meaning, "loaded from the store");
        d[usize::from(diag::SETTINGS_SOURCE)] = 1;
        assert_eq!(judge_settings(&d).verdict, Verdict::Ok);
        d[usize::from(diag::SETTINGS_SOURCE)] = 2;
        assert_eq!(judge_settings(&d).verdict, Verdict::Fail);
        d[usize::from(diag::SETTINGS_SOURCE)] = 0;
        d[usize::from(diag::LAST_SAVE)] = 2;
        assert_eq!(judge_settings(&d).verdict, Verdict::Fail);
        d[usize::from(diag::LAST_SAVE)] = 3;
        assert!(judge_settings(&d).meaning.contains("pending"));
    }

    #[test]
    fn a_watchdog_reset_fails_as_a_stalled_loop_a_brown_out_warns() {
        let c = judge_reset_cause(3);
        assert_eq!(c.verdict, Verdict::Fail);
        assert!(c.meaning.contains("control loop stalled"));
        assert_eq!(judge_reset_cause(5).verdict, Verdict::Warn);
        for ok in [0, 1, 2, 4] {
            assert_eq!(judge_reset_cause(ok).verdict, Verdict::Ok, "{ok}");
        }
    }

    #[test]
    fn modbus_errors_warn_and_fail_above_one_percent_of_the_frames() {
        let mut d = healthy_diag();
        assert_eq!(judge_modbus(&d).verdict, Verdict::Ok);
        set32(&mut d, diag::MODBUS_CRC_ERRORS, 2);
        let w = judge_modbus(&d);
        assert_eq!(w.verdict, Verdict::Warn);
        assert!(w.check_on_board.contains("termination"));
        set32(&mut d, diag::MODBUS_FRAMING_ERRORS, 5);
        assert_eq!(judge_modbus(&d).verdict, Verdict::Fail, "7 of 500");
    }

    #[test]
    fn other_bus_errors_and_watchdog_trips_warn() {
        let mut d = healthy_diag();
        assert_eq!(judge_other_buses(&d).verdict, Verdict::Ok);
        set32(&mut d, diag::WATCHDOG_TRIPS, 1);
        assert_eq!(judge_other_buses(&d).verdict, Verdict::Warn);
    }

    #[test]
    fn the_tick_warns_on_overruns_a_close_maximum_or_a_rate_off_and_fails_far_off() {
        let d = healthy_diag();
        let rate = |hz: u32| {
            Some(TickRate {
                ticks: hz,
                seconds: 1.0,
            })
        };
        let tol = TICK_TOLERANCE_PERCENT / 100.0;
        assert_eq!(judge_tick(&d, rate(1000), tol).verdict, Verdict::Ok);
        assert_eq!(
            judge_tick(&d, None, tol).verdict,
            Verdict::Ok,
            "not measured"
        );
        assert_eq!(judge_tick(&d, rate(950), tol).verdict, Verdict::Warn);
        assert_eq!(judge_tick(&d, rate(950), 0.10).verdict, Verdict::Ok);
        assert_eq!(judge_tick(&d, rate(400), 0.5).verdict, Verdict::Fail);
        let mut close = d.clone();
        set32(&mut close, diag::TICK_MAX_US, 950);
        assert_eq!(judge_tick(&close, rate(1000), tol).verdict, Verdict::Warn);
        let mut over = d.clone();
        set32(&mut over, diag::TICK_MAX_US, 1400);
        set32(&mut over, diag::TICK_OVERRUNS, 5000);
        let w = judge_tick(&over, rate(1000), tol);
        assert_eq!(w.verdict, Verdict::Warn, "10 % overran");
        assert!(w.meaning.contains("5000 overruns"), "{}", w.meaning);
        set32(&mut over, diag::TICK_OVERRUNS, 5);
        assert_eq!(
            judge_tick(&over, rate(1000), tol).verdict,
            Verdict::Ok,
            "0.01 %"
        );
        let mut none = d;
        none[usize::from(diag::TICK_PERIOD_US)] = 0;
        assert_eq!(judge_tick(&none, None, tol).verdict, Verdict::Fail);
    }

    #[test]
    fn uvlo_latched_fails_with_the_supply_advice_and_chip_resets_warn() {
        let mut a = healthy_axis(3);
        a.block.as_mut().unwrap()[8] = 1 << 5;
        let checks = judge_axis(&a, 2);
        let f = find(&checks, "axis 3 faults");
        assert_eq!(f.verdict, Verdict::Fail);
        assert!(f.meaning.contains("UVLO"), "{}", f.meaning);
        assert!(f.check_on_board.contains("decoupling"));
        assert!(f.check_on_board.contains("reset-faults 3"));
        let r = find(&checks, "axis 3 chip resets");
        assert_eq!(r.verdict, Verdict::Warn);
        assert!(r.meaning.contains("2 time(s)"));
        assert!(judge_axis(&healthy_axis(3), 0)
            .iter()
            .all(|c| c.check != "axis 3 chip resets"));
    }

    #[test]
    fn overcurrent_fails_with_the_current_setting_to_check() {
        let mut a = healthy_axis(2);
        a.block.as_mut().unwrap()[8] = 0x06;
        let f = judge_axis(&a, 0).remove(0);
        assert_eq!(f.verdict, Verdict::Fail);
        assert!(f.check_on_board.contains("stepctl settings set 2 current"));
    }

    #[test]
    fn a_stuck_status_fails_and_thermal_flags_are_judged() {
        for stuck in [0x0000, 0xFFFF] {
            let mut a = healthy_axis(1);
            a.status = Ok(stuck);
            let checks = judge_axis(&a, 0);
            let s = find(&checks, "axis 1 STATUS");
            assert_eq!(s.verdict, Verdict::Fail);
            assert!(s.meaning.contains("SDO stuck"), "{}", s.meaning);
        }
        let status = |s: u16| {
            let mut a = healthy_axis(1);
            a.status = Ok(s);
            find(&judge_axis(&a, 0), "axis 1 STATUS").verdict
        };
        assert_eq!(status(0xE612 | 1 << 11), Verdict::Warn, "thermal warning");
        assert_eq!(status(0xE612 | 2 << 11), Verdict::Fail, "bridge shutdown");
        assert_eq!(
            status(0xE612 & !(1 << 13)),
            Verdict::Fail,
            "OCD (active low)"
        );
        assert_eq!(
            status(0xE612 & !(1 << 9)),
            Verdict::Warn,
            "UVLO (active low)"
        );
        let mut a = healthy_axis(1);
        a.status = Err("exception 04".into());
        assert_eq!(
            find(&judge_axis(&a, 0), "axis 1 STATUS").verdict,
            Verdict::Fail
        );
    }

    #[test]
    fn a_register_that_differs_from_what_the_bridge_wrote_fails() {
        let mut a = healthy_axis(1);
        a.chip[1].1 = Ok(0x2E88);
        let c = judge_registers(&a);
        assert_eq!(c.verdict, Verdict::Fail);
        assert!(
            c.meaning
                .contains("CONFIG reads 0x2E88, the bridge wrote 0x2C98"),
            "{}",
            c.meaning
        );
        a.chip[1].1 = Err("timeout".into());
        assert_eq!(judge_registers(&a).verdict, Verdict::Fail);
    }

    #[test]
    fn pending_writes_warn_and_motion_registers_are_skipped_while_moving() {
        let mut a = healthy_axis(1);
        a.configured.as_mut().unwrap()[usize::from(configured::PENDING)] = 3;
        assert_eq!(judge_registers(&a).verdict, Verdict::Warn);
        let mut m = healthy_axis(1);
        let c = m.configured.as_mut().unwrap();
        c[usize::from(Register::MaxSpeed.address())] = 0x20;
        let mask = dword(c, configured::MASK) | 1 << Register::MaxSpeed.address();
        set32(c, configured::MASK, mask);
        m.chip.push((Register::MaxSpeed, Ok(0x41)));
        assert_eq!(
            judge_registers(&m).verdict,
            Verdict::Fail,
            "at rest it must match"
        );
        m.block.as_mut().unwrap()[6] = 2;
        assert_eq!(judge_registers(&m).verdict, Verdict::Ok, "moving: skipped");
    }

    #[test]
    fn the_loopback_passes_only_with_the_pattern_back() {
        assert_eq!(
            judge_loopback(io::PATTERN, io::PATTERN).verdict,
            Verdict::Ok
        );
        let f = judge_loopback(io::PATTERN, 0xFFFF_0000);
        assert_eq!(f.verdict, Verdict::Fail);
        assert!(f.check_on_board.contains("PB15"));
        let r = Reading {
            loopback: Loopback::Skipped("mapped".into()),
            ..healthy()
        };
        assert_eq!(
            find(&judge(&r, &expect2()), "I/O extension loopback").verdict,
            Verdict::Warn
        );
    }

    #[test]
    fn json_names_each_verdict_in_capitals() {
        let c = judge_supply(0, 24.0);
        let j = serde_json::to_value(&c).unwrap();
        assert_eq!(j["verdict"], "FAIL");
        assert_eq!(j["check"], "supply");
    }

    // ------------------------------------------------ scripted frames

    /// A request reading `n` registers at `a` of id 1, and its reply.
    fn read_frames(a: u16, values: &[u16]) -> (String, String) {
        let [a0, a1] = a.to_be_bytes();
        let q = framed(&[1, 0x03, a0, a1, 0, values.len() as u8]);
        let mut body = vec![1, 0x03, (values.len() * 2) as u8];
        for v in values {
            body.extend_from_slice(&v.to_be_bytes());
        }
        (q, framed(&body))
    }

    #[test]
    fn the_axis_reads_are_the_axis_block_status_the_configured_block_and_each_register() {
        let mut c = vec![0u16; configured::LEN];
        c[usize::from(Register::OcdTh.address())] = 8;
        set32(&mut c, configured::MASK, 1 << Register::OcdTh.address());
        c[usize::from(configured::SET_UP)] = 1;
        let block = [0, 0, 0, 100, 0, 100, 1, 0, 0, 0xE612];
        let mut script = vec![read_frames(0x0600, &block), read_frames(0x011B, &[0xE612])];
        for (i, chunk) in c.chunks(16).enumerate() {
            script.push(read_frames(0x0700 + 16 * i as u16, chunk));
        }
        script.push(read_frames(0x0113, &[8]));
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        let a = read_axis(&mut m, 1);
        assert!(m.link.done());
        assert_eq!(a.status, Ok(0xE612));
        assert_eq!(a.chip, vec![(Register::OcdTh, Ok(8))]);
        assert_eq!(judge_registers(&a).verdict, Verdict::Ok);
    }

    #[test]
    fn the_diagnostics_are_read_in_chunks_of_16_registers() {
        let d = healthy_diag();
        let mut script = Vec::new();
        for (i, chunk) in d.chunks(16).enumerate() {
            script.push(read_frames(0x0300 + 16 * i as u16, chunk));
        }
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        assert_eq!(read_block(&mut m, 1, 0x0300, diag::LEN as u16).unwrap(), d);
        assert!(m.link.done());
    }

    #[test]
    fn the_loopback_sends_the_pattern_and_puts_the_port_back() {
        let w = |a: u16, v: &[u16]| {
            let [a0, a1] = a.to_be_bytes();
            let mut body = vec![1, 0x10, a0, a1, 0, v.len() as u8, (v.len() * 2) as u8];
            for x in v {
                body.extend_from_slice(&x.to_be_bytes());
            }
            (framed(&body), framed(&[1, 0x10, a0, a1, 0, v.len() as u8]))
        };
        let script = vec![
            read_frames(0x0240, &[0; 7]),
            read_frames(0x0200, &[0, 0]),
            read_frames(0x0202, &[0x1000, 0x0007]),
            read_frames(0x0210, &[0x1234, 0x5678]),
            w(0x0202, &[0x100A, 0x001F]),
            w(0x0200, &[0, 1]),
            read_frames(0x0220, &[0, 0]),
            w(0x0210, &[0xA55A, 0x0FF0]),
            read_frames(0x0202, &[0x100A, 0x081F]),
            read_frames(0x0220, &[0xA55A, 0x0FF0]),
            w(0x0202, &[0x1000, 0x0007]),
            w(0x0210, &[0x1234, 0x5678]),
            w(0x0200, &[0, 0]),
        ];
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        assert_eq!(
            loopback(&mut m, 1, 1),
            Loopback::Done {
                sent: 0xA55A_0FF0,
                received: 0xA55A_0FF0
            }
        );
        assert!(m.link.done());
    }

    #[test]
    fn a_box_with_no_chip_is_read_through_its_first_id_and_fails_the_chain() {
        let mut d = healthy_diag();
        d[usize::from(diag::CHAIN_LENGTH)] = 0;
        d[usize::from(diag::CHAIN_STATE)] = 3;
        let mut script = Vec::new();
        for (i, chunk) in d.chunks(16).enumerate() {
            script.push(read_frames(0x0300 + 16 * i as u16, chunk));
        }
        script.push(read_frames(0x034C, &[0, 100]));
        script.push(read_frames(0x034C, &[0, 110]));
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        let opts = Options {
            first_id: 1,
            loopback: false,
            seconds: 0.0,
        };
        let r = read(&mut m, &opts);
        assert!(m.link.done());
        assert!(r.axes.is_empty());
        assert_eq!(r.tick.map(|t| t.ticks), Some(10));
        let checks = judge(&r, &Expect::default());
        assert_eq!(find(&checks, "chain").verdict, Verdict::Fail);
        assert_eq!(
            find(&checks, "supply").verdict,
            Verdict::Ok,
            "read with no chip"
        );
    }

    #[test]
    fn over_usb_the_blocks_are_extension_reads_0xe0_of_at_most_16_registers() {
        use crate::usb::fake::{bus, reply};
        let d = healthy_diag();
        let replies = d
            .chunks(16)
            .map(|c| {
                let bytes: Vec<u8> = c.iter().flat_map(|v| v.to_be_bytes()).collect();
                vec![reply(0, 0, 0, 0xE0, &[(16, &bytes)])]
            })
            .collect();
        let mut b = bus(replies);
        assert_eq!(read_block(&mut b, 1, 0x0300, diag::LEN as u16).unwrap(), d);
        let w = &b.hid.0.written;
        assert_eq!(w.len(), 5);
        assert_eq!(
            (w[4][1], w[4][20], w[4][21], w[4][22]),
            (0xE0, 0x03, 0x40, 16)
        );
    }

    #[test]
    fn a_mapped_panel_is_not_overwritten_by_the_loopback() {
        let script = [read_frames(0x0240, &[0x8003, 0, 0, 0, 0, 0, 0])];
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        assert!(matches!(loopback(&mut m, 1, 1), Loopback::Skipped(why) if why.contains("unmap")));
        assert!(m.link.done());
    }
}
