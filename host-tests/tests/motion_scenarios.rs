//! Motion scenarios: 4 simulated powerSTEP01s driven by the bridge's axes at
//! a 1 kHz control tick (issue: motion).

#![allow(clippy::needless_range_loop)] // devices are addressed by chain index

use bridge_logic::motion::axis::logical_to_physical;
use bridge_logic::motion::{AxisConfig, AxisFault, Limits};
use bridge_logic::powerstep::registers::{sign_extend_22, wrap_22};
use bridge_logic::powerstep::{DriveMode, StepSel};
use host_tests::clock::{SimClock, SimControl};
use host_tests::rig::{config as cfg, Rig};
use host_tests::rng::Rng;
use stepbridge_sim::Fault;

/// The build setting `STEPBRIDGE_TICK_HZ` (CI runs this file at 1, 2 and 5 kHz).
const TICK_US: u32 = bridge_logic::rate::TICK_US;

/// Mixed step modes: logical = physical, logical coarser, logical finer
/// (1/256 on a chip at 1/16, current mode), full steps on 1/128.
fn mixed_axes() -> [AxisConfig; 4] {
    [
        cfg(7, StepSel::OneTwentyEighth, DriveMode::Voltage),
        cfg(4, StepSel::OneTwentyEighth, DriveMode::Voltage),
        cfg(8, StepSel::Sixteenth, DriveMode::Current),
        cfg(0, StepSel::OneTwentyEighth, DriveMode::Voltage),
    ]
}

/// Limits in logical steps from full-step values.
fn limits_full(cfg: &AxisConfig, v: u32, a: u32, d: u32) -> Limits {
    let k = 1u32 << cfg.logical_shift;
    Limits {
        max_speed: v * k,
        acc: a * k,
        dec: d * k,
    }
}

/// Every chip sits exactly on its axis's required position, and the axis
/// reports it. An axis stopped at once (`held`) stays where the chip stopped,
/// which lies less than one logical step from the required position.
fn assert_landed(rig: &mut Rig, seq: usize, held: &[bool]) {
    for k in 0..rig.group.len() {
        let axis = rig.group.axis(k).unwrap();
        let c = axis.config();
        let want = logical_to_physical(axis.required_position(), c.logical_shift, c.step);
        let abs = rig.chain.bus().device(k).unwrap().abs_pos();
        assert_eq!(
            rig.chip_position(k),
            axis.chip_position(),
            "sequence {seq}, axis {k}: axis read-back"
        );
        assert_eq!(
            i64::from(abs),
            i64::from(sign_extend_22(wrap_22(rig.chip_position(k) as i32))),
            "sequence {seq}, axis {k}: wide position"
        );
        if held[k] {
            let step = logical_to_physical(1, c.logical_shift, c.step).max(1);
            let off = rig.chip_position(k) - want;
            assert!(
                off.abs() < step,
                "sequence {seq}, axis {k}: held at {} for required {want}",
                rig.chip_position(k)
            );
        } else {
            assert_eq!(
                abs,
                sign_extend_22(wrap_22(want as i32)),
                "sequence {seq}, axis {k}: ABS_POS {abs} != target {want}"
            );
        }
        assert!(!rig.chain.bus().device(k).unwrap().is_busy());
    }
}

#[test]
fn a_thousand_random_sequences_land_exactly_with_following_error_below_one_full_step() {
    let axes = mixed_axes();
    let base = limits_full(&axes[0], 4000, 20_000, 20_000);
    let mut rig = Rig::new(&axes, base);
    let mut rng = Rng(0x5EED_57E9_B41D_6E00);
    let mut beyond_2_21 = 0;
    let mut reversals = 0;
    for seq in 0..1000 {
        let mut held = [false; 4];
        for k in 0..4 {
            let c = axes[k];
            // New limits between moves (chip ACC/DEC are written at rest).
            let v = rng.range(200, 12_000) as u32;
            let a = rng.range(2_000, 40_000) as u32;
            let d = rng.range(2_000, 40_000) as u32;
            rig.axis(k).set_limits(limits_full(&c, v, a, d));
            let here = rig.axis(k).required_position();
            let span = if rng.below(10) == 0 {
                // Long: beyond 2^21 physical microsteps (16 384 full steps at 1/128).
                beyond_2_21 += 1;
                20_000i64 << c.logical_shift
            } else {
                (i64::from(v) / 2) << c.logical_shift
            };
            let target = here + rng.range(-span, span);
            rig.axis(k).move_to(target);
        }
        // Let them run, then disturb some of them mid-move.
        rig.run(rng.below(600) as u32);
        for k in 0..4 {
            let c = axes[k];
            match rng.below(8) {
                0 => {
                    // Retarget behind the axis: decelerate, reverse, come back.
                    let here = rig.axis(k).required_position();
                    let v = rig.group.axis(k).unwrap().profile().velocity();
                    let back =
                        if v >= 0 { -1 } else { 1 } * (rng.range(1, 3000) << c.logical_shift);
                    rig.axis(k).move_to(here + back);
                    reversals += 1;
                }
                1 => {
                    let here = rig.axis(k).required_position();
                    rig.axis(k)
                        .move_to(here + rng.range(-2000, 2000) * (1 << c.logical_shift));
                }
                2 => {
                    // New max speed mid-move (lower or higher).
                    let lim = rig.axis(k).profile().limits();
                    let v = rng.range(200, 12_000) as u32;
                    rig.axis(k).set_limits(Limits {
                        max_speed: v << c.logical_shift,
                        ..lim
                    });
                }
                3 => rig.axis(k).soft_stop(),
                4 => {
                    rig.axis(k).stop_now();
                    held[k] = true;
                }
                _ => {}
            }
        }
        rig.run_until_settled(200_000);
        assert_landed(&mut rig, seq, &held);
        for k in 0..4 {
            assert_eq!(
                rig.group.axis(k).unwrap().fault(),
                None,
                "sequence {seq}, axis {k}"
            );
        }
    }
    let worst: Vec<f64> = (0..4)
        .map(|k| rig.max_following[k] as f64 / f64::from(axes[k].step.microsteps()))
        .collect();
    println!(
        "1000 sequences, {beyond_2_21} moves beyond 2^21 microsteps, {reversals} reversals, \
         {} ticks; max following error per axis (full steps): {worst:?}",
        rig.clock.ticks()
    );
    for (k, w) in worst.iter().enumerate() {
        assert!(*w <= 1.0, "axis {k}: following error {w} full steps");
    }
    assert!(beyond_2_21 > 0 && reversals > 0);
}

#[test]
fn a_move_beyond_the_22_bit_range_lands_exactly() {
    let axes = [cfg(7, StepSel::OneTwentyEighth, DriveMode::Voltage)];
    let mut rig = Rig::new(&axes, limits_full(&axes[0], 12_000, 40_000, 40_000));
    // 40 000 full steps = 5 120 000 microsteps > 2^22.
    rig.axis(0).move_to(40_000 * 128);
    rig.run_until_settled(20_000);
    assert_eq!(rig.chip_position(0), 40_000 * 128);
    assert_eq!(rig.group.axis(0).unwrap().actual_position(), 40_000 * 128);
    rig.axis(0).move_to(-3);
    rig.run_until_settled(20_000);
    assert_eq!(rig.chip_position(0), -3);
}

#[test]
fn all_axes_of_a_streaming_tick_complete_their_run_in_the_same_window() {
    let axes = mixed_axes();
    let mut rig = Rig::new(&axes, limits_full(&axes[0], 1000, 10_000, 10_000));
    for k in 0..4 {
        rig.axis(k).move_to(50_000);
    }
    rig.run(20);
    let report = rig.last_report.unwrap();
    assert_eq!(report.windows, 5);
    assert_eq!(report.sync_window, 4);
    assert_eq!(report.bytes, 20);
}

#[test]
fn chip_reset_mid_move_stops_where_the_chip_is_and_recovers() {
    let axes = [cfg(4, StepSel::OneTwentyEighth, DriveMode::Voltage)];
    let mut rig = Rig::new(&axes, limits_full(&axes[0], 2000, 10_000, 10_000));
    rig.axis(0).move_to(100_000);
    rig.run(300);
    let before = rig.chip_position(0);
    rig.chain
        .bus_mut()
        .device_mut(0)
        .unwrap()
        .inject(Fault::PowerCycle);
    rig.resync_chip_tracking(0, 0);
    rig.run(10);
    let axis = rig.group.axis(0).unwrap();
    assert_eq!(axis.fault(), Some(AxisFault::ChipReset));
    // The axis holds near where the chip was (within the last 2 ms of motion),
    // it did not jump to the reset chip's zero.
    let held = axis.required_position();
    assert!(
        (held - before / 8).abs() < 2000 / 1000 * 16 * 3 + 16,
        "held {held}, before {}",
        before / 8
    );
    rig.run_until_settled(1000);
    // The chip's frame was re-based to the axis position: a new move lands exactly.
    rig.axis(0).move_to(held + 5000);
    rig.run_until_settled(20_000);
    let want = logical_to_physical(held + 5000, 4, StepSel::OneTwentyEighth);
    assert_eq!(
        rig.chain.bus().device(0).unwrap().abs_pos(),
        sign_extend_22(wrap_22(want as i32))
    );
}

#[test]
fn overcurrent_mid_move_stops_the_axis_and_reports_it() {
    let axes = [cfg(7, StepSel::OneTwentyEighth, DriveMode::Voltage)];
    let mut rig = Rig::new(&axes, limits_full(&axes[0], 2000, 10_000, 10_000));
    rig.axis(0).move_to(1_000_000);
    rig.run(200);
    rig.chain
        .bus_mut()
        .device_mut(0)
        .unwrap()
        .inject(Fault::Overcurrent);
    rig.run(10);
    assert_eq!(
        rig.group.axis(0).unwrap().fault(),
        Some(AxisFault::Overcurrent)
    );
    assert!(rig.group.axis(0).unwrap().profile().velocity() == 0);
}

#[test]
fn overcurrent_switches_the_bridges_off_and_does_not_land() {
    let axes = [cfg(7, StepSel::OneTwentyEighth, DriveMode::Voltage)];
    let mut rig = Rig::new(&axes, limits_full(&axes[0], 2000, 10_000, 10_000));
    rig.axis(0).move_to(1_000_000);
    rig.run(200);
    rig.chain
        .bus_mut()
        .device_mut(0)
        .unwrap()
        .inject(Fault::Overcurrent);
    rig.run(20);
    let dev = rig.chain.bus().device(0).unwrap();
    assert!(dev.is_hiz(), "bridges off after an overcurrent");
    let p = dev.abs_pos();
    rig.run(500);
    assert_eq!(
        rig.chain.bus().device(0).unwrap().abs_pos(),
        p,
        "no landing move"
    );
    assert!(rig.chain.bus().device(0).unwrap().is_hiz());
}

/// A chain bus that can be told to fail its next window.
struct Flaky {
    sim: stepbridge_sim::SimChain,
    fail_next: bool,
}

impl bridge_logic::powerstep::ChainBus for Flaky {
    type Error = ();
    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ()> {
        if std::mem::take(&mut self.fail_next) {
            return Err(());
        }
        self.sim.transfer(tx, rx);
        Ok(())
    }
}

/// The group on the flaky chain as one simulated control loop.
struct FlakyLoop {
    group: bridge_logic::motion::AxisGroup,
    chain: bridge_logic::powerstep::Chain<Flaky>,
}

impl SimControl for FlakyLoop {
    fn control_tick(&mut self, _now_ms: u64) {
        let _ = self.group.tick(&mut self.chain);
    }
    fn chips(&mut self) -> &mut stepbridge_sim::SimChain {
        &mut self.chain.bus_mut().sim
    }
}

#[test]
fn a_chain_error_sets_every_chip_up_again_and_moves_still_land() {
    use bridge_logic::motion::{Axis, AxisGroup, AxisState};
    use bridge_logic::powerstep::Chain;
    let c = cfg(4, StepSel::OneTwentyEighth, DriveMode::Voltage);
    let mut chain = Chain::new(Flaky {
        sim: stepbridge_sim::SimChain::new(2),
        fail_next: false,
    });
    assert_eq!(chain.detect(), Ok(2));
    let mut group = AxisGroup::new();
    for _ in 0..2 {
        let _ = group.push(Axis::new(c, limits_full(&c, 2000, 10_000, 10_000)));
    }
    let mut l = FlakyLoop { group, chain };
    let mut clock = SimClock::new(TICK_US);
    clock.run(&mut l, 10);
    l.group.axis_mut(0).unwrap().move_to(40_000);
    clock.run(&mut l, 300);
    l.chain.bus_mut().fail_next = true;
    clock.tick(&mut l);
    assert_eq!(
        l.group.axis(0).unwrap().fault(),
        Some(AxisFault::ChainError)
    );
    assert!(matches!(
        l.group.axis(0).unwrap().state(),
        AxisState::Setup(_)
    ));
    clock.run(&mut l, 20);
    // The chip was stopped (HardHiZ at setup) and set up again.
    let held = l.group.axis(0).unwrap().chip_position();
    assert_eq!(
        i64::from(l.chain.bus().sim.device(0).unwrap().abs_pos()),
        held
    );
    l.group.axis_mut(0).unwrap().move_to(50_000);
    for _ in 0..30_000 {
        clock.tick(&mut l);
        if l.group.is_settled() {
            break;
        }
    }
    assert!(l.group.is_settled());
    assert_eq!(l.chain.bus().sim.device(0).unwrap().abs_pos(), 50_000 * 8);
}
