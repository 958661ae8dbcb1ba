//! Late and skipped control ticks against chips that keep running on real
//! time.
//!
//! The firmware's control tick (`Bridge::tick_pipelined`, each batch clocked
//! through the simulated chips at its start, as the QEMU image's driver
//! does) on a virtual clock whose ticks may come late, or not at all (the
//! previous batch still on the bus: an overrun), while the chips live
//! through every nanosecond of it at their last `Run` speed, as a
//! powerSTEP01 does. The scenario is the one filed against the QEMU image:
//! max speed, acceleration and deceleration 65 535 (Modbus 0x51–0x53) and a
//! target of +150 000 steps from 0 (factory step mode 1/16).
//!
//! What a user sees must stay true: a chip never passes its target by more
//! than the distance it covered in the time the ticks were late (no lead it
//! had before the final braking carries it further), and every move still
//! lands exactly on its target.

use bridge_logic::bridge::{BatchState, Bridge, PipelinedTick};
use bridge_logic::motion::axis::logical_to_physical;
use bridge_logic::motion::Mode;
use bridge_logic::postep60::{PowerStage, Request, Settings};
use bridge_logic::powerstep::chain::{clock_windows, Frames, MAX_DEVICES, MAX_WINDOWS};
use host_tests::rng::Rng;
use host_tests::sim_bridge::{all_settled, chip, new_bridge, TICK_US};
use stepbridge_sim::SimChain;

const BOARD: PowerStage = PowerStage::REFERENCE;
const EMPTY: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];

/// The filed scenario's limits (Modbus 0x51–0x53) and target (0x50).
const LIMIT: u32 = 65_535;
const TARGET: i32 = 150_000;
/// The move takes ~3.3 s: 1 s up, ~1.3 s at 65 535 steps/s, 1 s down.
const MOVE_MS: u64 = 3_400;
/// Microsteps a landing may read past the target before the GoTo puts the
/// chip on it (the read-back resolution, as in `motion_truth`).
const LANDING_TOLERANCE: i64 = 1;

/// The target in chip microsteps (factory step mode on the reference board).
fn target_microsteps() -> i64 {
    logical_to_physical(
        i64::from(TARGET),
        Settings::FACTORY.axes[0].step_mode,
        BOARD.step,
    )
}

/// A bridge ticked the firmware's way on a virtual clock whose ticks may be
/// late or skipped, and what the chips did.
struct Late {
    bridge: Bridge<SimChain>,
    rx: Frames,
    ended: Frames,
    running: bool,
    ms: u64,
    /// Per axis: the farthest the chip got (microsteps) since the move began.
    peak: Vec<i64>,
    /// Per axis: microsteps the chip covered in late time while its profile
    /// braked onto the target (the final approach; a lead from before it
    /// must not carry the chip past the target).
    late_distance: Vec<i64>,
    /// Per axis: the profile's speed at the last tick (2⁻³² steps/tick) and
    /// whether it was braking.
    speed: Vec<(i64, bool)>,
}

impl Late {
    /// `n` chips, configured, at rest.
    fn new(n: usize) -> Late {
        let mut l = Late {
            bridge: new_bridge(n, Settings::FACTORY, BOARD),
            rx: EMPTY,
            ended: EMPTY,
            running: false,
            ms: 0,
            peak: vec![0; n],
            late_distance: vec![0; n],
            speed: vec![(0, false); n],
        };
        for _ in 0..30 {
            l.tick(0, false);
        }
        assert!(all_settled(&l.bridge), "configured and at rest");
        l
    }

    fn axes(&self) -> usize {
        self.bridge.axes()
    }

    fn position(&self, k: usize) -> i64 {
        i64::from(chip(&self.bridge, k).abs_pos())
    }

    /// The profile of axis `k` brakes onto its target: it got slower since
    /// it was last faster (a skipped tick leaves it as it was).
    fn braking(&mut self, k: usize) -> bool {
        let p = self.bridge.axis(k).expect("axis").profile();
        let v = p.velocity_internal().abs();
        let (last, was) = self.speed[k];
        let braking =
            matches!(p.mode(), Mode::Position(_)) && v > 0 && (v < last || (v == last && was));
        self.speed[k] = (v, braking);
        braking
    }

    /// The chips live through `ns`.
    fn chips_run(&mut self, ns: u64) {
        self.bridge.chain_mut().bus_mut().advance(ns);
        for k in 0..self.axes() {
            self.peak[k] = self.peak[k].max(self.position(k));
        }
    }

    /// One control tick (`skip`: the previous batch is still on the bus,
    /// the tick does nothing but count an overrun), then the chips live
    /// through a period, and `late_us` more before the next tick comes.
    fn tick(&mut self, late_us: u64, skip: bool) {
        self.ms += 1;
        let braking: Vec<bool> = (0..self.axes()).map(|k| self.braking(k)).collect();
        let previous = if skip {
            BatchState::Running
        } else if self.running {
            self.ended = self.rx;
            BatchState::Done(Ok(&self.ended))
        } else {
            BatchState::Idle
        };
        let rx = &mut self.rx;
        let step = self.bridge.tick_pipelined(self.ms, previous, |plan, bus| {
            clock_windows(bus, plan, plan.devices(), rx)
        });
        if step != PipelinedTick::Overrun {
            self.running = step == PipelinedTick::Started;
        }
        let before: Vec<i64> = (0..self.axes()).map(|k| self.position(k)).collect();
        self.chips_run(u64::from(TICK_US) * 1000);
        if skip {
            // A skipped tick is a whole period of late time.
            for k in 0..self.axes() {
                if braking[k] {
                    self.late_distance[k] += (self.position(k) - before[k]).abs();
                }
            }
        }
        if late_us > 0 {
            let before: Vec<i64> = (0..self.axes()).map(|k| self.position(k)).collect();
            self.chips_run(late_us * 1000);
            for k in 0..self.axes() {
                if braking[k] {
                    self.late_distance[k] += (self.position(k) - before[k]).abs();
                }
            }
        }
    }

    /// The filed move on every axis.
    fn start_move(&mut self) {
        for k in 0..self.axes() {
            for req in [
                Request::SetMaxSpeed(LIMIT),
                Request::SetAcceleration(LIMIT),
                Request::SetDeceleration(LIMIT),
                Request::SetPosition(TARGET),
            ] {
                self.bridge.request(k, req).expect("accepted");
            }
            self.peak[k] = self.position(k);
            self.late_distance[k] = 0;
        }
    }

    /// Ticks on time until every axis has landed; each chip on its target.
    fn land(&mut self, cap_ms: u64) {
        for _ in 0..cap_ms {
            if all_settled(&self.bridge) {
                for k in 0..self.axes() {
                    assert_eq!(self.position(k), target_microsteps(), "axis {k} landed");
                }
                return;
            }
            self.tick(0, false);
        }
        panic!("not landed after {cap_ms} ms");
    }

    /// Microsteps axis `k` passed its target by, beyond its late distance.
    fn excess(&self, k: usize) -> i64 {
        self.peak[k] - target_microsteps() - self.late_distance[k] - LANDING_TOLERANCE
    }
}

/// The filed move with `ticks` ticks in a row late by `late_us` each (or
/// skipped), starting `at_ms` after the target: (passed by, late distance)
/// in microsteps.
fn disturbed_move(at_ms: u64, ticks: u64, late_us: u64, skip: bool) -> (i64, i64, i64) {
    let mut l = Late::new(1);
    l.start_move();
    for _ in 0..at_ms {
        l.tick(0, false);
    }
    for _ in 0..ticks {
        l.tick(late_us, skip);
    }
    l.land(20_000);
    (
        l.peak[0] - target_microsteps(),
        l.late_distance[0],
        l.excess(0),
    )
}

/// Sweep a disturbance over the whole move (acceleration, cruise, the final
/// braking and the landing); every case that passed the target by more
/// than it ran in late time, as text.
fn sweep(ticks: u64, late_us: u64, skip: bool) -> Vec<String> {
    let mut bad = Vec::new();
    for at in (0..MOVE_MS).step_by(23).chain(MOVE_MS - 400..MOVE_MS) {
        let (past, late, excess) = disturbed_move(at, ticks, late_us, skip);
        if excess > 0 {
            bad.push(format!(
                "{ticks} tick(s) {} at {at} ms: passed the target by {past} microsteps, \
                 {late} of them in late time",
                if skip {
                    "skipped".to_string()
                } else {
                    format!("{late_us} us late")
                },
            ));
        }
    }
    bad
}

fn assert_none(bad: &[String]) {
    assert!(
        bad.is_empty(),
        "{} cases passed the target by more than they ran in late time, e.g.:\n{}",
        bad.len(),
        bad.iter().take(8).cloned().collect::<Vec<_>>().join("\n")
    );
}

#[test]
fn a_late_tick_never_carries_an_axis_past_its_target_by_more_than_it_ran_in_the_late_time() {
    let mut bad = Vec::new();
    for late_us in [700, 3_000, 6_000] {
        bad.extend(sweep(1, late_us, false));
    }
    assert_none(&bad);
}

#[test]
fn skipped_ticks_never_carry_an_axis_past_its_target_by_more_than_it_ran_in_them() {
    let mut bad = Vec::new();
    for ticks in [1, 3, 8] {
        bad.extend(sweep(ticks, 0, true));
    }
    assert_none(&bad);
}

/// Ticks as the QEMU image on a busy host had them: every one a little
/// late, some by milliseconds, some skipped, so the profile falls behind
/// the chips' time all through the move.
#[test]
fn ticks_that_keep_coming_late_never_carry_an_axis_past_its_target_by_more_than_it_ran_late_braking(
) {
    let mut rng = Rng(0x1A7E_71C5);
    let mut bad = Vec::new();
    let mut worst = 0;
    for run in 0..12 {
        let mut l = Late::new(4);
        // Chip oscillators a few % off, as a powerSTEP01's are.
        for (k, ppm) in [0, 30_000, -30_000, 12_000].into_iter().enumerate() {
            l.bridge
                .chain_mut()
                .bus_mut()
                .device_mut(k)
                .expect("chip")
                .set_clock_error_ppm(ppm);
        }
        l.start_move();
        for _ in 0..MOVE_MS {
            let late = if rng.below(50) == 0 {
                rng.below(6_000)
            } else {
                rng.below(300)
            };
            l.tick(late, rng.below(200) == 0);
        }
        l.land(40_000);
        for k in 0..4 {
            let past = l.peak[k] - target_microsteps();
            worst = worst.max(past);
            if l.excess(k) > 0 {
                bad.push(format!(
                    "run {run}, axis {k}: passed the target by {past} microsteps, {} of them in \
                     late time while braking",
                    l.late_distance[k]
                ));
            }
        }
    }
    println!("late ticks all through the move: passed a target by {worst} microsteps at most");
    assert_none(&bad);
}
