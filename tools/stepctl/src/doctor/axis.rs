//! One axis's verdicts: latched faults, chip resets, STATUS, and the chip's
//! registers against what the bridge configured.

use bridge_logic::ext_space::configured;
use bridge_logic::powerstep::registers::Register;

use super::judge::{BOARD_CHAIN, BOARD_UVLO};
use super::{check, configured_registers, word, AxisReading, Check, Verdict};
use crate::ops::fault_names;

/// STATUS bits (the facts file's §2).
mod st {
    pub const HIZ: u16 = 1 << 0;
    pub const UVLO: u16 = 1 << 9;
    pub const TH_SHIFT: u16 = 11;
    pub const OCD: u16 = 1 << 13;
}

pub fn judge_axis(a: &AxisReading, resets: u16) -> Vec<Check> {
    let mut out = vec![judge_faults(a)];
    if resets > 0 {
        out.push(judge_resets(a.unit, resets));
    }
    out.push(judge_status(a));
    out.push(judge_registers(a));
    out
}

/// The axis's state and its latched faults (0x0608).
fn judge_faults(a: &AxisReading) -> Check {
    let u = a.unit;
    let name = |what: &str| format!("axis {u} {what}");
    let b = match &a.block {
        Err(e) => {
            return check(
                name("state"),
                Verdict::Fail,
                format!("cannot be read: {e}"),
                BOARD_CHAIN,
            )
        }
        Ok(b) => b,
    };
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
        check(
            name("faults"),
            Verdict::Fail,
            format!("{what}: under-voltage lockout latched (the supply at the chip dipped, or the chip reset)"),
            &BOARD_UVLO.replace("AXIS", &u.to_string()),
        )
    } else if faults & 0x06 != 0 {
        check(
            name("faults"),
            Verdict::Fail,
            format!("{what}: overcurrent, the bridges switched off"),
            &format!(
                "the current setting against the motor's rating (`stepctl settings set {u} current …`), \
                 OCD_TH, shorts in the motor wiring and connector; then `stepctl reset-faults {u}`"
            ),
        )
    } else if faults & 0x01 != 0 {
        check(
            name("faults"),
            Verdict::Fail,
            format!("{what}: thermal shutdown"),
            "heat sinking of the chips, the motor current",
        )
    } else if stopping != 0 {
        check(
            name("faults"),
            Verdict::Fail,
            format!("{what}: a gate-driver fault"),
            "the power stage's gate drive (GATECFG1/2), the bootstrap capacitors, VS",
        )
    } else if faults != 0 {
        check(
            name("faults"),
            Verdict::Warn,
            format!("{what}: a stall was detected"),
            "the load and the speed, STALL_TH",
        )
    } else {
        check(name("faults"), Verdict::Ok, "none", "")
    }
}

/// Chip resets counted since the counters were cleared (none is no check).
fn judge_resets(u: u8, resets: u16) -> Check {
    check(
            format!("axis {u} chip resets"),
            Verdict::Warn,
            format!("the chip reset {resets} time(s) since the counters were cleared (the bridge set it up again each time)"),
            "the chip's supplies (VS and VDD dips, decoupling, the bench supply's current limit), \
             STBY/RESET (PC4) glitches, ESD on the motor cable",
    )
}

/// STATUS as read by GetParam.
fn judge_status(a: &AxisReading) -> Check {
    let name = |what: &str| format!("axis {} {what}", a.unit);
    match a.status {
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
    }
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
    let Comparison {
        differ,
        unread,
        compared,
    } = compare(a, &configured_registers(c), moving);
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
            format!(" (+{} more)", differ.len().saturating_sub(3))
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

/// The chip's registers as read against what the bridge wrote.
struct Comparison {
    /// One line per register whose value differs.
    differ: Vec<String>,
    /// One line per register that could not be read, and why.
    unread: Vec<String>,
    /// How many registers were read and compared.
    compared: usize,
}

/// Compare each configured register with the chip's value (the motion
/// registers are skipped while the axis moves: they change then).
fn compare(a: &AxisReading, wanted: &[(Register, u32)], moving: bool) -> Comparison {
    let mut out = Comparison {
        differ: Vec::new(),
        unread: Vec::new(),
        compared: 0,
    };
    for (reg, want) in wanted {
        if moving && matches!(reg, Register::MaxSpeed | Register::Acc | Register::Dec) {
            continue;
        }
        let reg_name = reg.info().voltage_mode_name;
        match a.chip.iter().find(|(r, _)| r == reg).map(|(_, v)| v) {
            Some(Ok(v)) => {
                out.compared = out.compared.saturating_add(1);
                if v & reg.mask() != want & reg.mask() {
                    out.differ.push(format!(
                        "{reg_name} reads 0x{v:X}, the bridge wrote 0x{want:X}"
                    ));
                }
            }
            Some(Err(e)) => out.unread.push(format!("{reg_name}: {e}")),
            None => out.unread.push(format!("{reg_name}: not read")),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::doctor::test_util::*;
    use crate::doctor::*;

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
}
