//! The commands that move an axis: move, jog, run, stop, home.

use std::time::{Duration, Instant};

use bridge_logic::ext_space::{block, homing};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

use super::{list, Ctx, Output};
use crate::bus::{deadline, words_of};
use crate::cli::{Limits, Wait};
use crate::error::{Error, Result};
use crate::ops::{self, ext, one, reg};

/// Switch an auto-run axis to position mode (what a move means); a note.
pub(super) fn position_mode(ctx: &mut Ctx, unit: u8) -> Result<Option<String>> {
    let mode = one(ctx.bus, unit, reg::DRIVER_MODE)?;
    if mode == 6 {
        ctx.write(unit, reg::SET_MODE, &[4])?;
        return Ok(Some(format!(
            "axis {unit}: driver mode auto run -> position (for the move)"
        )));
    }
    Ok(None)
}

fn set_limits(ctx: &mut Ctx, unit: u8, l: &Limits) -> Result<()> {
    for (v, address) in [(l.speed, 0x51), (l.acc, 0x52), (l.dec, 0x53)] {
        if let Some(v) = v {
            ctx.write(unit, address, &[v])?;
        }
    }
    Ok(())
}

pub(super) fn move_to(
    ctx: &mut Ctx,
    unit: u8,
    target: i32,
    limits: &Limits,
    wait: &Wait,
) -> Result<Output> {
    let note = position_mode(ctx, unit)?;
    if let Some(n) = &note {
        eprintln!("stepctl: {n}");
    }
    set_limits(ctx, unit, limits)?;
    let start = ops::motion(ctx.bus, unit)?;
    ctx.write(unit, reg::SET_POSITION, &words_of(target as u32))?;
    if wait.no_wait {
        return Ok(Output::new(
            format!("axis {unit}: moving to {target}"),
            json!({ "axis": unit, "target": target, "waited": false }),
        ));
    }
    let t0 = Instant::now();
    let end = wait_arrival(ctx, unit, start.position, target, wait.timeout)?;
    let s = t0.elapsed().as_secs_f64();
    Ok(Output::new(
        format!("axis {unit}: at {} after {s:.2} s", end.position),
        json!({ "axis": unit, "target": target, "position": end.position, "waited": true, "seconds": s }),
    ))
}

/// `jog`: a move relative to the axis's current target.
pub(super) fn jog(
    ctx: &mut Ctx,
    unit: u8,
    steps: i32,
    limits: &Limits,
    wait: &Wait,
) -> Result<Output> {
    let now = ops::motion(ctx.bus, unit)?;
    let target = now.target.checked_add(steps).ok_or_else(|| {
        Error::Usage(format!(
            "jog {steps} from {} leaves the 32-bit position range",
            now.target
        ))
    })?;
    move_to(ctx, unit, target, limits, wait)
}

pub(super) fn stop(ctx: &mut Ctx, axes: &[u8]) -> Result<Output> {
    let axes = ctx.axes(axes)?;
    for a in &axes {
        ctx.write(*a, reg::STOP, &[0])?;
    }
    Ok(Output::new(
        format!("stopped axis {}", list(&axes)),
        json!({ "stopped": axes }),
    ))
}

/// Poll until the axis rests on `target`; a fault or a stop elsewhere
/// ends it with [`Error::Fault`], the timeout with [`Error::Timeout`].
fn wait_arrival(
    ctx: &mut Ctx,
    unit: u8,
    from: i32,
    target: i32,
    timeout_s: f64,
) -> Result<ops::Motion> {
    let len = u64::from(target.abs_diff(from));
    let bar = if ctx.interactive && !ctx.json {
        let b = ProgressBar::new(len.max(1));
        if let Ok(style) =
            ProgressStyle::with_template("axis {prefix} [{bar:40}] {pos}/{len} steps {msg}")
        {
            b.set_style(style.progress_chars("=> "));
        }
        b.set_prefix(unit.to_string());
        b
    } else {
        ProgressBar::hidden()
    };
    let deadline = deadline(seconds(timeout_s));
    let mut resting_elsewhere: u32 = 0;
    loop {
        let m = ops::motion(ctx.bus, unit)?;
        bar.set_position(u64::from(m.position.abs_diff(from)).min(len));
        bar.set_message(format!("{} steps/s", m.speed));
        if m.faults & ops::STOPPING_FAULTS != 0 {
            bar.abandon();
            return Err(Error::Fault(format!(
                "axis {unit}: fault {} at position {} (target {target}): the axis stopped; \
                 clear with `stepctl reset-faults {unit}`",
                ops::fault_names(m.faults),
                m.position
            )));
        }
        if m.settled() && m.position == target {
            bar.finish_and_clear();
            return Ok(m);
        }
        // Resting, not on the target, several polls in a row: something
        // stopped it (Stop, an end switch, another master's target).
        if m.settled() {
            resting_elsewhere = resting_elsewhere.saturating_add(1);
            if resting_elsewhere >= 5 {
                bar.abandon();
                return Err(Error::Fault(format!(
                    "axis {unit}: stopped at {} before reaching {target} (a Stop, the end switch or \
                     another master's command)",
                    m.position
                )));
            }
        } else {
            resting_elsewhere = 0;
        }
        if Instant::now() >= deadline {
            bar.abandon();
            return Err(Error::Timeout(format!(
                "axis {unit}: still at {} ({}) after {timeout_s} s, target {target}",
                m.position,
                ops::state_name(m.state)
            )));
        }
        ctx.sleep();
    }
}

pub(super) fn run_at(ctx: &mut Ctx, unit: u8, speed: i32) -> Result<Output> {
    if one(ctx.bus, unit, reg::DRIVER_MODE)? != 6 {
        ctx.write(unit, reg::SET_MODE, &[6])?;
    }
    ctx.write(unit, reg::SET_INVERT, &[u16::from(speed < 0)])?;
    ctx.write(
        unit,
        reg::SET_REQUESTED_SPEED,
        &[speed.unsigned_abs() as u16],
    )?;
    Ok(Output::new(
        format!(
            "axis {unit}: running at {speed} steps/s (auto run; `stepctl stop {unit}` stops it)"
        ),
        json!({ "axis": unit, "speed": speed }),
    ))
}

fn homing_result(code: u16) -> &'static str {
    match code {
        1 => "the end switch was not found within the max travel",
        2 => "homing timed out",
        3 => "the end switch is disabled (enable it in the axis's settings, e.g. USB 0xB1)",
        4 => "homing was aborted",
        5 => "the axis faulted",
        6 => "the axis is not ready (moving, asleep or faulted)",
        _ => "unknown reason",
    }
}

pub(super) fn home(ctx: &mut Ctx, unit: u8, wait: &Wait) -> Result<Output> {
    let cmd = ext(block::HOMING, homing::COMMAND);
    if let Err(e) = ctx.bus.write(unit, cmd, &[1]) {
        return Err(match e {
            Error::Exception { code: 4, what, .. } => {
                let r = one(ctx.bus, unit, ext(block::HOMING, homing::RESULT)).unwrap_or(0);
                Error::Exception {
                    code: 4,
                    what,
                    reason: Some(format!("homing refused: {}", homing_result(r))),
                }
            }
            other => other,
        });
    }
    if wait.no_wait {
        return Ok(Output::new(
            format!("axis {unit}: homing"),
            json!({ "axis": unit, "waited": false }),
        ));
    }
    let deadline = deadline(seconds(wait.timeout));
    loop {
        let h = ctx.bus.read(unit, cmd, 3)?;
        match h.first().copied().unwrap_or(0) {
            4 => {
                return Ok(Output::new(
                    format!("axis {unit}: homed, position 0 is the switch edge"),
                    json!({ "axis": unit, "homed": true }),
                ))
            }
            5 => {
                return Err(Error::Fault(format!(
                    "axis {unit}: homing failed: {}",
                    homing_result(h.get(1).copied().unwrap_or(0))
                )))
            }
            _ => {}
        }
        if Instant::now() >= deadline {
            let _ = ctx.bus.write(unit, cmd, &[0]);
            return Err(Error::Timeout(format!(
                "axis {unit}: homing not done after {} s: aborted",
                wait.timeout
            )));
        }
        ctx.sleep();
    }
}

/// `--timeout` in seconds as a span: negative or NaN is 0, too large for a
/// `Duration` (or infinite) is the longest one.
fn seconds(s: f64) -> Duration {
    Duration::try_from_secs_f64(s.max(0.0)).unwrap_or(Duration::MAX)
}

#[cfg(test)]
mod tests {
    use crate::app::test_util::*;

    #[test]
    fn move_writes_the_target_by_fc_10_and_waits_until_it_rests_there() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 0B B8 F1 D1",
                "01 10 00 50 00 02 41 D9",
            ),
            (MOTION_1, &motion(1, 1500, 1000, 3000, 2, 0)),
            (MOTION_1, &motion(1, 0, 3000, 3000, 1, 0)),
        ]);
        let o = run_on(&mut m, &["move", "1", "3000"]).unwrap();
        assert_eq!(o.json["position"], 3000);
        assert!(m.link.done());
    }

    #[test]
    fn move_with_limits_writes_them_first() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            ("01 06 00 51 07 D0 DB B7", "01 06 00 51 07 D0 DB B7"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 FF FF FC 18 B7 BD",
                "01 10 00 50 00 02 41 D9",
            ),
        ]);
        run_on(
            &mut m,
            &["move", "1", "-1000", "--speed", "2000", "--no-wait"],
        )
        .unwrap();
        assert!(m.link.done());
    }

    #[test]
    fn a_fault_during_a_move_exits_4_naming_the_fault() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 0B B8 F1 D1",
                "01 10 00 50 00 02 41 D9",
            ),
            (MOTION_1, &motion(1, 0, 1200, 1200, 1, 0x06)),
        ]);
        let e = run_on(&mut m, &["move", "1", "3000"]).unwrap_err();
        assert_eq!(e.exit_code(), 4);
        assert!(
            e.to_string().contains("fault AOCP,BOCP at position 1200"),
            "{e}"
        );
    }

    #[test]
    fn an_axis_that_rests_short_of_its_target_exits_4() {
        let mut script = vec![
            (
                "01 03 00 14 00 01 C4 0E".to_string(),
                "01 03 02 00 04 B9 87".to_string(),
            ),
            (MOTION_1.to_string(), motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 0B B8 F1 D1".into(),
                "01 10 00 50 00 02 41 D9".into(),
            ),
        ];
        for _ in 0..5 {
            script.push((MOTION_1.into(), motion(1, 0, 800, 800, 1, 0)));
        }
        let script = fixed(&script);
        let refs: Vec<(&str, &str)> = script
            .iter()
            .map(|(a, b)| (a.as_str(), b.as_str()))
            .collect();
        let mut m = rtu(&refs);
        let e = run_on(&mut m, &["move", "1", "3000"]).unwrap_err();
        assert_eq!(e.exit_code(), 4);
        assert!(
            e.to_string()
                .contains("stopped at 800 before reaching 3000"),
            "{e}"
        );
    }

    #[test]
    fn move_on_an_asleep_axis_surfaces_exception_04_with_its_meaning() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            ("01 10 00 50 00 02 04 00 00 0B B8 F1 D1", "01 90 04 4D C3"),
            ("01 03 00 13 00 01 75 CF", "01 03 02 00 01 79 84"),
            ("01 03 00 25 00 01 95 C1", "01 03 02 00 00 B8 44"),
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
        ]);
        let e = run_on(&mut m, &["move", "1", "3000"]).unwrap_err();
        assert_eq!(e.exit_code(), 3);
        assert!(
            e.to_string().contains("exception 04: axis is asleep"),
            "{e}"
        );
    }

    #[test]
    fn move_switches_an_auto_run_axis_to_position_mode_first() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 06 38 46"),
            ("01 06 00 05 00 04 98 08", "01 06 00 05 00 04 98 08"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 00 0A 76 94",
                "01 10 00 50 00 02 41 D9",
            ),
        ]);
        run_on(&mut m, &["move", "1", "10", "--no-wait"]).unwrap();
        assert!(m.link.done());
    }

    #[test]
    fn jog_moves_relative_to_the_current_target() {
        let mut m = rtu(&[
            (MOTION_1, &motion(1, 0, 500, 500, 1, 0)),
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 500, 500, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 01 90 F7 6F",
                "01 10 00 50 00 02 41 D9",
            ),
        ]);
        let o = run_on(&mut m, &["jog", "1", "-100", "--no-wait"]).unwrap();
        assert_eq!(o.json["target"], 400);
    }

    #[test]
    fn run_sets_auto_run_then_invert_then_the_speed() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            ("01 06 00 05 00 06 19 C9", "01 06 00 05 00 06 19 C9"),
            ("01 06 00 55 00 01 58 1A", "01 06 00 55 00 01 58 1A"),
            ("01 06 00 54 05 DC CA D3", "01 06 00 54 05 DC CA D3"),
        ]);
        run_on(&mut m, &["run", "1", "-1500"]).unwrap();
        assert!(m.link.done());
    }

    #[test]
    fn stop_zero_wake_sleep_and_reset_faults_write_their_registers() {
        for (args, frame) in [
            (&["stop", "2"][..], "02 06 00 5F 00 00 B9 EB"),
            (&["zero", "1"][..], "01 06 00 5E 00 00 E8 18"),
            (&["wake", "1"][..], "01 06 00 03 00 DA F8 51"),
            (&["sleep", "1"][..], "01 06 00 03 00 0F 39 CE"),
            (&["reset-faults", "1"][..], "01 06 00 35 00 00 99 C4"),
        ] {
            let f = fixed(&[(frame.to_string(), frame.to_string())]);
            let mut m = rtu(&[(f[0].0.as_str(), f[0].1.as_str())]);
            run_on(&mut m, args).unwrap();
            assert!(m.link.done(), "{args:?}");
        }
    }

    #[test]
    fn home_starts_through_the_extension_and_waits_for_done() {
        let mut m = rtu(&[
            ("01 06 04 00 00 01 49 3A", "01 06 04 00 00 01 49 3A"),
            (
                "01 03 04 00 00 03 04 FB",
                "01 03 06 00 02 00 00 00 00 58 B5",
            ),
            (
                "01 03 04 00 00 03 04 FB",
                "01 03 06 00 04 00 00 00 01 11 75",
            ),
        ]);
        let o = run_on(&mut m, &["home", "1"]).unwrap();
        assert_eq!(o.json["homed"], true);
    }

    #[test]
    fn home_refused_names_the_homing_result() {
        let mut m = rtu(&[
            ("01 06 04 00 00 01 49 3A", "01 86 04 43 A3"),
            ("01 03 04 01 00 01 D4 FA", "01 03 02 00 03 F8 45"),
        ]);
        let e = run_on(&mut m, &["home", "1"]).unwrap_err();
        assert!(
            e.to_string()
                .contains("exception 04: homing refused: the end switch is disabled"),
            "{e}"
        );
    }
}
