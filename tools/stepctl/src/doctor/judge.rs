//! The box-wide verdicts: link, chain, supply, temperature, settings, reset
//! cause, bus errors, control tick, I/O extension loopback; [`judge`] runs
//! them and each axis's (`axis.rs`).

use bridge_logic::ext_space::diag;

use super::{check, dword, judge_axis, word, Check, Expect, Loopback, Reading, TickRate, Verdict};
use super::{SUPPLY_MAX_V, SUPPLY_MIN_V, SUPPLY_TOLERANCE};

pub(super) const BOARD_CHAIN: &str = "SPI1 to the chain: SCK PA5, MOSI PA7 to SDI of chip 0, MISO PA6 from SDO of the last chip, \
                           CS PA4 to every chip; STBY/RESET PC4 high after boot; every chip's VDD (3.3 V) and motor \
                           supply VS; each SDO to the next SDI (one dead chip breaks the whole echo)";
const BOARD_SUPPLY: &str = "the bench supply's voltage and current limit, the motor supply at the chips (VS), \
                            the divider into PA0 (÷20 on the reference board) and the ADC reference (VDDA)";
pub(super) const BOARD_UVLO: &str = "supply dips at the chip: the bench supply's current limit (raise it above the motor current), \
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
    if i2c == 0 && usb == 0 && trips == 0 {
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

#[cfg(test)]
mod tests {
    use super::super::read::io;
    use super::*;
    use crate::doctor::test_util::*;
    use crate::doctor::*;

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
}
