//! Motion truth: what a user of the box sees, checked against the simulated
//! chips and not against the bridge's own idea of where the axes are.
//!
//! The bridge is driven only through PoStep60 requests (the same entry point
//! every bus uses) on chains of 1, 4 and 8 chips. An independent oracle in
//! this file keeps, per axis, where the last accepted command says the axis
//! must end up, in PoStep60 coordinates; after every sequence the chip's
//! ABS_POS (22-bit, compared modulo 2²²) and the reported position must say
//! exactly that. While an undisturbed move runs, the chip must never pass
//! its target; while the axis streams, the chip must follow the profile.

#![allow(clippy::needless_range_loop)] // axes are addressed by chain index

use bridge_logic::bridge::Bridge;
use bridge_logic::motion::axis::{logical_to_physical, physical_to_logical};
use bridge_logic::motion::AxisState;
use bridge_logic::postep60::{PowerStage, Query, Request, Settings, Value};
use bridge_logic::powerstep::registers::{sign_extend_22, wrap_22, Register};
use bridge_logic::powerstep::Command;
use host_tests::clock::SimClock;
use host_tests::rng::Rng;
use host_tests::sim_bridge::Breakable;
use host_tests::sim_bridge::{chip, chip_mut, new_bridge_at, TICK_US};
use stepbridge_sim::{Fault, SimChain};

const BOARD: PowerStage = PowerStage::REFERENCE;
/// Microsteps per full step on the reference board's chips (1/128).
const MICRO: f64 = 128.0;

/// xorshift64*: deterministic, seedable, no dependency.
/// Where the last accepted command says an axis ends up.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Expect {
    /// Exactly on this PoStep60 position (logical steps of `mode`).
    At { target: i64, mode: u8 },
    /// Stopped wherever the stop caught it.
    Held,
}

/// A move issued from rest and not retargeted: it must never pass its target.
#[derive(Clone, Copy, Debug)]
struct Clean {
    /// Target in chip microsteps (wide).
    target: i64,
    /// +1 forward, −1 reverse.
    dir: i64,
}

/// The chip's position unwrapped from its 22-bit ABS_POS tick by tick, in
/// the PoStep60 frame (chip microsteps): re-based where the chip's log shows
/// ResetPos (to 0) or an ABS_POS write (to the wide value nearest the
/// position before the chip's last reset).
#[derive(Clone, Copy, Debug, Default)]
struct Wide {
    pos: i64,
    raw: u32,
    seen: u64,
    /// Position before an injected reset (the bridge re-bases near it).
    anchor: Option<i64>,
}

/// `TRUTH_TRACE=axis,from_ms,to_ms` prints that axis tick by tick (a
/// debugging aid for a failing sequence).
fn trace_on(k: usize, now_ms: u64) -> bool {
    let Ok(spec) = std::env::var("TRUTH_TRACE") else {
        return false;
    };
    let v: Vec<u64> = spec.split(',').filter_map(|x| x.parse().ok()).collect();
    matches!(v[..], [a, from, to] if a == k as u64 && (from..=to).contains(&now_ms))
}

/// The value ≡ `raw` (mod 2²²) nearest to `near`.
fn nearest(raw: u32, near: i64) -> i64 {
    near + i64::from(sign_extend_22(
        raw.wrapping_sub(wrap_22(near as i32)) & 0x3F_FFFF,
    ))
}

/// Bridge + simulated chips + virtual clock + the oracle.
struct Truth {
    bridge: Bridge<SimChain>,
    clock: SimClock,
    expect: Vec<Expect>,
    mode: Vec<u8>,
    clean: Vec<Option<Clean>>,
    wide: Vec<Wide>,
    /// Worst passing of a clean move's target, microsteps.
    overshoot: i64,
    /// Worst |profile − chip| while streaming, microsteps.
    following: i64,
    moves: u64,
    lost: Vec<String>,
    /// Each axis's profile position one tick ago: where the chip must be
    /// now with the overlapped tick, whose profiles run one tick ahead of
    /// the batch on the bus.
    ahead: Vec<i64>,
    /// Ticks each axis has been settled for: with the overlapped tick,
    /// what the plan that settled it sent (a setup's last write, a Set
    /// zero's ResetPos) is on the chip one tick later.
    settled_ticks: Vec<u32>,
}

impl Truth {
    fn new(n: usize, settings: Settings) -> Truth {
        Truth::at(n, settings, TICK_US)
    }

    /// Ticked every `tick_us` µs (a divisor of 1000).
    fn at(n: usize, settings: Settings, tick_us: u32) -> Truth {
        Truth::ticked(
            n,
            settings,
            tick_us,
            host_tests::sim_bridge::overlapped_from_env(),
        )
    }

    /// [`Truth::at`], the bridge's tick overlapped or not.
    fn ticked(n: usize, settings: Settings, tick_us: u32, overlapped: bool) -> Truth {
        let mut bridge = host_tests::sim_bridge::overlapped_in(false, || {
            new_bridge_at(n, settings, BOARD, tick_us)
        });
        if overlapped {
            host_tests::sim_bridge::tick_overlapped(&mut bridge, n, tick_us);
        }
        let mut t = Truth {
            bridge,
            clock: SimClock::new(tick_us),
            expect: vec![
                Expect::At {
                    target: 0,
                    mode: settings.axes[0].step_mode
                };
                n
            ],
            mode: settings.axes.iter().take(n).map(|a| a.step_mode).collect(),
            clean: vec![None; n],
            wide: vec![Wide::default(); n],
            overshoot: 0,
            following: 0,
            moves: 0,
            lost: Vec::new(),
            ahead: vec![0; n],
            settled_ticks: vec![0; n],
        };
        t.run(30);
        t
    }

    fn axes(&self) -> usize {
        self.bridge.axes()
    }

    fn run(&mut self, ms: u64) {
        for _ in 0..ms * 1000 / u64::from(self.clock.tick_us()) {
            self.clock.tick(&mut self.bridge);
            self.observe();
        }
    }

    fn observe(&mut self) {
        for k in 0..self.axes() {
            let c = chip(&self.bridge, k);
            let raw = wrap_22(c.abs_pos());
            let w = &mut self.wide[k];
            let new = (c.received_count() - w.seen).min(32) as usize;
            let skip = c.received().count().saturating_sub(new);
            let mut rebase = None;
            for cmd in c.received().skip(skip) {
                match cmd {
                    Command::ResetPos => rebase = Some(0),
                    Command::SetParam(Register::AbsPos, v) => {
                        rebase = Some(nearest(*v, w.anchor.take().unwrap_or(w.pos)))
                    }
                    _ => {}
                }
            }
            w.seen = c.received_count();
            w.pos = match rebase {
                Some(base) => nearest(raw, base),
                None => nearest(raw, w.pos),
            };
            w.raw = raw;
            let wide = w.pos;
            // An injected reset the bridge has not re-based yet: nothing to follow.
            let reset = w.anchor.is_some();
            if let Some(c) = self.clean[k] {
                let past = (wide - c.target) * c.dir;
                self.overshoot = self.overshoot.max(past);
            }
            let axis = self.bridge.axis(k).expect("axis");
            if trace_on(k, self.clock.now_ms()) {
                let c = chip(&self.bridge, k);
                println!(
                    "t={} axis {k}: {:?} profile {} v={} chip {wide} speed {} error {} last {:?}",
                    self.clock.now_ms(),
                    axis.state(),
                    axis.profile_physical(),
                    axis.profile().velocity(),
                    c.speed_reg(),
                    axis.following_error(),
                    c.received().last()
                );
            }
            self.settled_ticks[k] = if axis.is_settled() {
                self.settled_ticks[k].saturating_add(1)
            } else {
                0
            };
            let profile = axis.profile_physical();
            let now = if self.bridge.is_overlapped() {
                std::mem::replace(&mut self.ahead[k], profile)
            } else {
                profile
            };
            if axis.state() == AxisState::Streaming && !reset {
                let e = now - wide;
                self.following = self.following.max(e.abs());
            }
        }
    }

    fn settled(&self) -> bool {
        (0..self.axes()).all(|k| self.bridge.axis(k).is_some_and(|a| a.is_settled()))
    }

    fn settle(&mut self, cap: u64) {
        for _ in 0..cap {
            if self.settled() {
                return;
            }
            self.run(1);
        }
        let states: Vec<String> = (0..self.axes())
            .map(|k| {
                let a = self.bridge.axis(k).expect("axis");
                let last = host_tests::sim_bridge::last_received(&self.bridge, k, 6);
                format!(
                    "axis {k}: {:?} {:?} v={} limits {:?} chip {} last {last:?}",
                    a.state(),
                    a.profile().mode(),
                    a.profile().velocity(),
                    a.profile().limits(),
                    self.wide[k].pos
                )
            })
            .collect();
        panic!("not settled after {cap} ms: {states:?}");
    }

    fn position(&self, k: usize) -> i64 {
        match self.bridge.query(k, Query::Position) {
            Some(Value::I32(p)) => i64::from(p),
            other => panic!("position of axis {k}: {other:?}"),
        }
    }

    /// Send a request; update the oracle if it was accepted.
    fn request(&mut self, k: usize, req: Request) -> bool {
        let at_rest = self.bridge.axis(k).is_some_and(|a| a.is_settled())
            && (self.settled_ticks[k] >= 2 || !self.bridge.is_overlapped());
        let ok = self.bridge.request(k, req).is_ok();

        if !ok {
            return false;
        }
        match req {
            Request::SetPosition(t) => {
                self.moves += 1;
                let mode = self.mode[k];
                self.expect[k] = Expect::At {
                    target: i64::from(t),
                    mode,
                };
                let target = logical_to_physical(i64::from(t), mode, BOARD.step);
                let delta = target - self.wide[k].pos;
                self.clean[k] = (at_rest && delta != 0).then_some(Clean {
                    target,
                    dir: delta.signum(),
                });
            }
            Request::SetZero => {
                self.expect[k] = Expect::At {
                    target: 0,
                    mode: self.mode[k],
                };
                self.clean[k] = None;
                // Acknowledged: every later read says 0 (the product rules (`docs/PRODUCT.md`)).
                let p = self.position(k);
                if p != 0 {
                    self.lost
                        .push(format!("axis {k}: position {p} read right after Set zero"));
                }
            }
            Request::Stop | Request::SoftStop => {
                self.expect[k] = Expect::Held;
                self.clean[k] = None;
            }
            Request::SetStepMode(m) => {
                if m != self.mode[k] {
                    self.expect[k] = Expect::Held;
                    self.clean[k] = None;
                }
                self.mode[k] = m;
            }
            _ => {}
        }
        true
    }

    /// Every axis is where the oracle says; record what is not.
    fn check(&mut self, seq: usize) {
        for k in 0..self.axes() {
            let Expect::At { target, mode } = self.expect[k] else {
                continue;
            };
            let phys = logical_to_physical(target, mode, BOARD.step);
            let abs = chip(&self.bridge, k).abs_pos();
            let want = sign_extend_22(wrap_22(phys as i32));
            let reported = self.position(k);
            let want_reported = physical_to_logical(phys, mode, BOARD.step);
            let wide = self.wide[k].pos;
            if abs != want || wide != phys || reported != want_reported {
                self.lost.push(format!(
                    "sequence {seq}, axis {k}: target {target} (mode {mode}): chip ABS_POS {abs} \
                     (want {want}), unwrapped {wide} (want {phys}), reported {reported} \
                     (want {want_reported})"
                ));
                // Re-anchor the oracle so one loss is reported once.
                self.expect[k] = Expect::Held;
            }
        }
        for c in self.clean.iter_mut() {
            *c = None;
        }
    }
}

/// A new max speed, acceleration or deceleration: the highest a PoStep60
/// register holds (beyond the chip in coarse step modes), or a value from
/// 100 full steps/s (500 full steps/s²) up, in the axis's step mode.
fn limits_request(rng: &mut Rng, mode: u8) -> Request {
    let scaled = |full: i64| (full << mode).min(65_535) as u32;
    let high = rng.below(3) == 0;
    match rng.below(3) {
        0 => Request::SetMaxSpeed(if high {
            65_535
        } else {
            scaled(rng.range(100, 8000))
        }),
        1 => Request::SetAcceleration(if high {
            65_535
        } else {
            scaled(rng.range(500, 40_000))
        }),
        _ => Request::SetDeceleration(if high {
            65_535
        } else {
            scaled(rng.range(500, 40_000))
        }),
    }
}

/// One random sequence on every axis: a move, disturbances while it runs,
/// then settle and check.
fn sequence(t: &mut Truth, rng: &mut Rng, seq: usize, counts: &mut [u64; 6]) {
    let n = t.axes();
    for k in 0..n {
        let here = t.position(k);
        let scale = 1i64 << t.mode[k];
        let span = if rng.below(12) == 0 {
            20_000 * scale // beyond 2²¹ chip microsteps
        } else {
            rng.range(10, 3000) * scale
        };
        let target = (here + rng.range(-span, span)).clamp(-(1 << 30), 1 << 30);
        t.request(k, Request::SetPosition(target as i32));
    }
    t.run(rng.below(400));
    for k in 0..n {
        let scale = 1i64 << t.mode[k];
        match rng.below(10) {
            0 => {
                // Limits raised or lowered mid-move.
                counts[0] += 1;
                for _ in 0..=rng.below(3) {
                    let r = limits_request(rng, t.mode[k]);
                    t.request(k, r);
                }
            }
            1 => {
                // Stop, then a new target 0..=3 ms later.
                counts[1] += 1;
                t.request(k, Request::Stop);
                t.run(rng.below(4));
                let here = t.position(k);
                t.request(
                    k,
                    Request::SetPosition((here + rng.range(-500, 500) * scale) as i32),
                );
            }
            2 => {
                // Set zero, then a new target 0..=5 ms later.
                counts[2] += 1;
                t.request(k, Request::SetZero);
                t.run(rng.below(6));
                t.request(
                    k,
                    Request::SetPosition((rng.range(-800, 800) * scale) as i32),
                );
            }
            3 => {
                // Step mode change with high limits, then a move in the new unit.
                counts[3] += 1;
                t.request(k, Request::SetMaxSpeed(65_535));
                t.request(k, Request::SetAcceleration(65_535));
                t.request(k, Request::SetDeceleration(65_535));
                let m = rng.below(9) as u8;
                t.request(k, Request::SetStepMode(m));
                t.run(rng.below(3));
                let here = t.position(k);
                t.request(
                    k,
                    Request::SetPosition((here + (rng.range(-400, 400) << m)) as i32),
                );
            }
            4 => {
                // Soft stop, then a new target.
                t.request(k, Request::SoftStop);
                t.run(rng.below(30));
                let here = t.position(k);
                t.request(
                    k,
                    Request::SetPosition((here + rng.range(-500, 500) * scale) as i32),
                );
            }
            5 if rng.below(4) == 0 => {
                // A chip reset: the axis stops and latches UVLO; reset faults.
                counts[4] += 1;
                t.expect[k] = Expect::Held;
                t.clean[k] = None;
                t.wide[k].anchor = Some(t.wide[k].pos);
                chip_mut(&mut t.bridge, k).inject(Fault::PowerCycle);
                t.run(rng.range(5, 20) as u64);
                t.request(k, Request::ResetFaults);
                let here = t.position(k);
                t.request(
                    k,
                    Request::SetPosition((here + rng.range(-500, 500) * scale) as i32),
                );
            }
            6 => {
                // Retarget mid-move.
                counts[5] += 1;
                let here = t.position(k);
                t.request(
                    k,
                    Request::SetPosition((here + rng.range(-3000, 3000) * scale) as i32),
                );
                t.clean[k] = None;
            }
            _ => {}
        }
    }
    t.settle(400_000);
    t.check(seq);
    // Back to moderate limits now and then so moves stay short.
    if rng.below(4) == 0 {
        for k in 0..n {
            let s = 1u32 << t.mode[k];
            let v = (2000 * s).min(65_535);
            t.request(k, Request::SetMaxSpeed(v));
            t.request(k, Request::SetAcceleration((20_000 * s).min(65_535)));
            t.request(k, Request::SetDeceleration((20_000 * s).min(65_535)));
        }
    }
}

fn random_run(n: usize, sequences: usize, seed: u64) -> Truth {
    random_run_at(n, sequences, seed, TICK_US)
}

fn random_run_at(n: usize, sequences: usize, seed: u64, tick_us: u32) -> Truth {
    random_run_with(n, sequences, seed, tick_us, 0)
}

/// Chip k's oscillator `ppm` off, fast and slow in turn.
fn random_run_with(n: usize, sequences: usize, seed: u64, tick_us: u32, ppm: i32) -> Truth {
    let overlapped = host_tests::sim_bridge::overlapped_from_env();
    random_run_ticked(n, sequences, seed, tick_us, ppm, overlapped)
}

/// [`random_run_with`], the bridge's tick overlapped or not.
fn random_run_ticked(
    n: usize,
    sequences: usize,
    seed: u64,
    tick_us: u32,
    ppm: i32,
    overlapped: bool,
) -> Truth {
    let mut settings = Settings::FACTORY;
    for a in settings.axes.iter_mut() {
        a.max_speed = 16_000;
        a.acc = 60_000;
        a.dec = 60_000;
    }
    let mut t = Truth::ticked(n, settings, tick_us, overlapped);
    for k in 0..n {
        let e = if k % 2 == 0 { ppm } else { -ppm };
        chip_mut(&mut t.bridge, k).set_clock_error_ppm(e);
    }
    let mut rng = Rng(seed);
    let mut counts = [0u64; 6];
    for seq in 0..sequences {
        sequence(&mut t, &mut rng, seq, &mut counts);
    }
    println!(
        "{n} chips at {} Hz{}, {sequences} sequences, {} moves, {} ms: lost {}, max overshoot {:.3} full steps, \
         max following error {:.3} full steps; limit changes {}, stop+move {}, zero+move {}, \
         step-mode changes {}, chip resets {}, retargets {}",
        1_000_000 / tick_us,
        if overlapped { " (overlapped)" } else { "" },
        t.moves,
        t.clock.now_ms(),
        t.lost.len(),
        t.overshoot as f64 / MICRO,
        t.following as f64 / MICRO,
        counts[0],
        counts[1],
        counts[2],
        counts[3],
        counts[4],
        counts[5],
    );
    for l in t.lost.iter().take(10) {
        println!("  {l}");
    }
    t
}

/// Landing tolerance: the chip may pass a target by one microstep (the
/// read-back resolution) before it lands on it exactly.
const LANDING_TOLERANCE: i64 = 1;

fn assert_truth(t: &Truth) {
    assert_arrives_within(t, 16);
}

/// Every accepted move arrived, none passed its target by more than the
/// landing tolerance, and the following error stayed within
/// `following_max` microsteps.
fn assert_arrives_within(t: &Truth, following_max: i64) {
    assert!(
        t.lost.is_empty(),
        "{} accepted moves did not arrive: {:?}",
        t.lost.len(),
        &t.lost[..t.lost.len().min(5)]
    );
    assert!(
        t.overshoot <= LANDING_TOLERANCE,
        "a move passed its target by {} microsteps",
        t.overshoot
    );
    assert!(
        t.following <= following_max,
        "following error {} microsteps (> {following_max})",
        t.following
    );
}

#[test]
fn every_accepted_move_arrives_on_one_chip() {
    let t = random_run(1, 400, 0x00DD_BA11_5EED);
    assert_truth(&t);
}

#[test]
fn every_accepted_move_arrives_on_four_chips() {
    let t = random_run(4, 250, 0xC0FF_EE00_1234);
    assert_truth(&t);
}

#[test]
fn every_accepted_move_arrives_on_eight_chips() {
    let t = random_run(8, 120, 0x0BAD_C0DE_7777);
    assert_truth(&t);
}

/// The powerSTEP01's internal oscillator is a few % off: every move still
/// arrives and never passes its target by more than the landing tolerance.
/// The following error is larger until the axis has cruised once (the
/// clock rate is learned while cruising) and at the highest speeds (an
/// estimate a few tenths of a % off is a few tenths of a full step at 4 000
/// full steps/s), so it is held to two full steps here.
#[test]
fn every_accepted_move_arrives_with_chip_oscillators_5_percent_off() {
    let t = random_run_with(4, 150, 0x05C1_11A7_0005, TICK_US, 50_000);
    assert_arrives_within(&t, 256);
}

#[test]
fn a_chip_oscillator_5_percent_off_is_learned_while_cruising_and_followed_exactly() {
    let mut settings = Settings::FACTORY;
    for a in settings.axes.iter_mut() {
        a.max_speed = 16_000;
        a.acc = 60_000;
        a.dec = 60_000;
    }
    let mut t = Truth::new(2, settings);
    chip_mut(&mut t.bridge, 0).set_clock_error_ppm(50_000);
    chip_mut(&mut t.bridge, 1).set_clock_error_ppm(-50_000);
    t.request(0, Request::SetPosition(20_000));
    t.request(1, Request::SetPosition(-20_000));
    t.run(500);
    let ratio = |t: &Truth, k: usize| t.bridge.axis(k).expect("axis").clock_ratio_q16();
    // 1.05 and 0.95 in Q16 are 68 813 and 62 259; a window resolves one
    // microstep, so the estimate dithers by ~0.1 % (64 in Q16).
    assert!(
        (ratio(&t, 0) as i64 - 68_813).abs() <= 80,
        "{}",
        ratio(&t, 0)
    );
    assert!(
        (ratio(&t, 1) as i64 - 62_259).abs() <= 80,
        "{}",
        ratio(&t, 1)
    );
    for _ in 0..800 {
        t.run(1);
        for k in 0..2 {
            let e = t.bridge.axis(k).expect("axis").following_error();
            assert!(
                e.abs() <= 2,
                "axis {k}: following error {e} microsteps once learned"
            );
        }
    }
    t.settle(10_000);
    assert_eq!(t.position(0), 20_000);
    assert_eq!(t.position(1), -20_000);
    assert!(t.overshoot <= LANDING_TOLERANCE);
}

#[test]
fn every_accepted_move_arrives_at_a_2_khz_tick() {
    let t = random_run_at(4, 120, 0x2222_0000_2000, 500);
    assert_truth(&t);
}

#[test]
fn every_accepted_move_arrives_at_a_5_khz_tick() {
    let t = random_run_at(4, 80, 0x5555_0000_5000, 200);
    assert_truth(&t);
}

#[test]
fn every_accepted_move_arrives_on_eight_chips_at_a_5_khz_tick() {
    let t = random_run_at(8, 120, 0x0BAD_C0DE_7777, 200);
    assert_truth(&t);
}

#[test]
fn every_accepted_move_arrives_with_the_overlapped_tick_at_1_khz() {
    let t = random_run_ticked(8, 120, 0x0E1A_0000_1000, 1000, 0, true);
    assert_truth(&t);
}

#[test]
fn every_accepted_move_arrives_with_the_overlapped_tick_at_2_khz() {
    let t = random_run_ticked(4, 120, 0x0E1A_0000_2000, 500, 0, true);
    assert_truth(&t);
}

#[test]
fn every_accepted_move_arrives_with_the_overlapped_tick_at_5_khz() {
    let t = random_run_ticked(8, 120, 0x0E1A_0000_5000, 200, 0, true);
    assert_truth(&t);
}

#[test]
fn every_accepted_move_arrives_with_the_overlapped_tick_and_chip_oscillators_5_percent_off() {
    let t = random_run_ticked(4, 150, 0x05C1_11A7_0005, TICK_US, 50_000, true);
    assert_arrives_within(&t, 256);
}

// ------------------------------------------------ one defect, one test ----

/// One chip at 1/16 (factory step mode), 1000 full steps/s, 1000 full steps/s².
fn one_axis() -> Truth {
    let mut settings = Settings::FACTORY;
    settings.axes[0].max_speed = 16_000;
    settings.axes[0].acc = 16_000;
    settings.axes[0].dec = 16_000;
    Truth::new(1, settings)
}

/// Run until the axis is in `state` (panics after `cap` ms).
fn run_until_state(t: &mut Truth, state: AxisState, cap: u64) {
    for _ in 0..cap {
        if t.bridge.axis(0).expect("axis").state() == state {
            return;
        }
        t.run(1);
    }
    panic!("axis never reached {state:?}");
}

fn assert_arrives(t: &mut Truth, what: &str) {
    t.settle(60_000);
    t.check(0);
    assert!(t.lost.is_empty(), "{what}: {:?}", t.lost);
}

#[test]
fn a_target_sent_in_any_phase_of_a_stop_arrives() {
    for d in 0..=12 {
        let mut t = one_axis();
        t.request(0, Request::SetPosition(40_000));
        t.run(300);
        assert!(t.request(0, Request::Stop));
        t.run(d);
        assert!(t.request(0, Request::SetPosition(-7_000)));
        assert_arrives(&mut t, &format!("target {d} ms after Stop"));
    }
}

#[test]
fn a_target_sent_in_any_phase_of_a_set_zero_arrives_in_the_new_coordinates() {
    for d in 0..=12 {
        let mut t = one_axis();
        t.request(0, Request::SetPosition(40_000));
        t.run(300);
        assert!(t.request(0, Request::SetZero));
        assert_eq!(t.position(0), 0, "read right after Set zero");
        t.run(d);
        assert_eq!(t.position(0), 0, "{d} ms after Set zero");
        assert!(t.request(0, Request::SetPosition(5_000)));
        assert_arrives(&mut t, &format!("target {d} ms after Set zero"));
    }
}

#[test]
fn a_target_sent_in_any_phase_of_a_soft_stop_arrives() {
    // 1000 full steps/s at 1000 full steps/s² brake in 1 s.
    for d in (0..=1050).step_by(25) {
        let mut t = one_axis();
        t.request(0, Request::SetPosition(60_000));
        t.run(1500);
        assert!(t.request(0, Request::SoftStop));
        t.run(d);
        assert!(t.request(0, Request::SetPosition(20_000)));
        assert_arrives(&mut t, &format!("target {d} ms after soft stop"));
    }
}

#[test]
fn a_target_sent_in_any_phase_of_a_landing_arrives() {
    for d in 0..=8 {
        let mut t = one_axis();
        t.request(0, Request::SetPosition(3_001));
        run_until_state(&mut t, AxisState::Stopping, 10_000);
        t.run(d);
        assert!(t.request(0, Request::SetPosition(-2_999)));
        assert_arrives(&mut t, &format!("target {d} ms after the end-of-move stop"));
    }
}

#[test]
fn stop_then_set_zero_then_a_target_all_take_effect_in_order() {
    let mut t = one_axis();
    t.request(0, Request::SetPosition(40_000));
    t.run(300);
    t.request(0, Request::Stop);
    t.request(0, Request::SetZero);
    t.request(0, Request::SetPosition(1_000));
    t.run(1);
    t.request(0, Request::Stop);
    assert_eq!(t.position(0), 0, "Stop does not undo the zero");
    t.request(0, Request::SetPosition(-1_000));
    assert_arrives(&mut t, "zero kept through a later Stop");
}

/// Every register the bridge configures, as the chip holds it.
fn configured_registers(t: &Truth) -> Vec<(Register, u32)> {
    let c = chip(&t.bridge, 0);
    [
        Register::StepMode,
        Register::Config,
        Register::KvalHold,
        Register::KvalRun,
        Register::KvalAcc,
        Register::KvalDec,
        Register::MaxSpeed,
        Register::Acc,
        Register::Dec,
        Register::AbsPos,
    ]
    .into_iter()
    .map(|r| (r, c.register(r)))
    .collect()
}

#[test]
fn after_a_chip_reset_every_configured_register_is_written_again() {
    let mut t = one_axis();
    t.request(
        0,
        Request::SetFullScaleCurrent(bridge_logic::postep60::Current::from_milliamps(2500)),
    );
    t.request(0, Request::SetPosition(12_345));
    t.settle(30_000);
    t.run(20);
    let before = configured_registers(&t);
    assert_ne!(
        before[2].1, 0x29,
        "a configured hold current, not the reset value"
    );
    chip_mut(&mut t.bridge, 0).inject(Fault::PowerCycle);
    assert_eq!(chip(&t.bridge, 0).register(Register::KvalRun), 0x29);
    t.run(30);
    assert!(t.bridge.axis(0).expect("axis").is_configured());
    assert_eq!(configured_registers(&t), before);
    // Visible: UVLO latched in the faults, counted in the diagnostics.
    assert_eq!(
        t.bridge.query(0, Query::Faults),
        Some(Value::U8(bridge_logic::postep60::device::fault::UVLO))
    );
    assert_eq!(t.bridge.diag.chip_resets, 1);
}

#[test]
fn a_reset_in_the_middle_of_the_setup_runs_the_whole_setup_again() {
    let mut t = one_axis();
    t.request(0, Request::SetPosition(2_000));
    t.settle(30_000);
    t.run(20);
    let before = configured_registers(&t);
    chip_mut(&mut t.bridge, 0).inject(Fault::PowerCycle);
    t.run(4); // detected, setup under way
    assert!(!t.bridge.axis(0).expect("axis").is_configured());
    chip_mut(&mut t.bridge, 0).inject(Fault::PowerCycle);
    t.run(40);
    assert_eq!(configured_registers(&t), before);
    assert_eq!(t.bridge.diag.chip_resets, 2);
}

#[test]
fn raising_acceleration_and_deceleration_mid_move_never_passes_the_target() {
    for at in [100, 300, 500, 700, 900] {
        let mut t = one_axis();
        t.request(0, Request::SetPosition(8_000)); // 500 full steps
        t.run(at);
        // Four times the ramps the chip was programmed with at the start.
        t.request(0, Request::SetAcceleration(65_535));
        t.request(0, Request::SetDeceleration(65_535));
        t.clean[0] = Some(Clean {
            target: 8_000 * 8,
            dir: 1,
        });
        assert_arrives(&mut t, "limits raised mid-move");
        assert!(
            t.overshoot <= LANDING_TOLERANCE,
            "passed by {} microsteps",
            t.overshoot
        );
    }
}

#[test]
fn higher_ramps_take_effect_at_the_next_start() {
    let mut t = one_axis();
    t.request(0, Request::SetPosition(8_000));
    t.run(100);
    t.request(0, Request::SetDeceleration(60_000));
    let l = t.bridge.axis(0).expect("axis").profile().limits();
    assert!(
        (16_000..17_000).contains(&l.dec),
        "the chip's DEC still rules this move: {}",
        l.dec
    );
    t.settle(30_000);
    t.request(0, Request::SetPosition(0));
    t.run(5);
    let l = t.bridge.axis(0).expect("axis").profile().limits();
    assert_eq!(l.dec, 60_000, "rewritten at the start from rest");
}

#[test]
fn limits_beyond_the_chip_are_clamped_visibly_and_counted() {
    let mut t = one_axis();
    // 16 000 full steps/s in full steps: beyond MAX_SPEED's 15 610.
    t.request(0, Request::SetStepMode(0));
    assert_eq!(t.bridge.query(0, Query::MaxSpeed), Some(Value::U16(12_481)));
    assert_eq!(t.bridge.diag.limit_clamps, 1);
    // 65 535 full steps/s and steps/s²: beyond MAX_SPEED and ACC/DEC.
    for r in [
        Request::SetMaxSpeed(65_535),
        Request::SetAcceleration(65_535),
        Request::SetDeceleration(65_535),
    ] {
        assert!(t.request(0, r));
    }
    assert_eq!(t.bridge.query(0, Query::MaxSpeed), Some(Value::U16(12_481)));
    assert_eq!(
        t.bridge.query(0, Query::Acceleration),
        Some(Value::U16(39_712))
    );
    assert_eq!(
        t.bridge.query(0, Query::Deceleration),
        Some(Value::U16(39_712))
    );
    assert_eq!(t.bridge.diag.limit_clamps, 4);
    // The same numbers at 1/256 are 256 full steps/s: nothing to clamp;
    // back to full steps they are clamped again.
    t.request(0, Request::SetStepMode(8));
    t.request(0, Request::SetMaxSpeed(65_535));
    assert_eq!(t.bridge.query(0, Query::MaxSpeed), Some(Value::U16(65_535)));
    t.request(0, Request::SetStepMode(0));
    assert_eq!(t.bridge.query(0, Query::MaxSpeed), Some(Value::U16(12_481)));
    assert_eq!(t.bridge.diag.limit_clamps, 5);
    // A move at the clamped limits follows within 1/8 full step.
    t.request(0, Request::SetPosition(30_000));
    assert_arrives(&mut t, "move at the clamped limits");
    assert!(
        t.following <= 16,
        "following error {} microsteps",
        t.following
    );
}

#[test]
fn current_speed_reads_every_speed_up_to_65535() {
    let mut t = one_axis();
    t.request(0, Request::SetStepMode(8)); // 60 000 steps/s = 234 full steps/s
    t.request(0, Request::SetMaxSpeed(60_000));
    t.request(0, Request::SetAcceleration(65_535));
    t.request(0, Request::SetPosition(2_000_000));
    t.run(1500);
    assert_eq!(
        t.bridge.query(0, Query::CurrentSpeed),
        Some(Value::U16(60_000))
    );
    // Back: 3.75 s braking at 16 000 steps/s², 0.9 s up to speed again.
    t.request(0, Request::SetPosition(-2_000_000));
    t.run(5000);
    assert_eq!(
        t.bridge.query(0, Query::CurrentSpeed),
        Some(Value::U16(60_000))
    );
}

#[test]
fn ten_failed_ticks_in_a_row_declare_the_chain_dead() {
    let mut b = Bridge::new(
        Breakable::new(2),
        BOARD,
        Settings::FACTORY,
        bridge_logic::bridge::SettingsSource::Stored,
        TICK_US,
    );
    for now in 1..=20 {
        b.tick(now);
    }
    b.chain_mut().bus_mut().broken = true;
    for now in 21..=29 {
        b.tick(now);
        assert!(!b.chain_dead(), "{} failed ticks", now - 20);
    }
    b.tick(30);
    assert!(b.chain_dead());
    assert_eq!(b.diag.chain_errors, 10);
    // One good tick ends it.
    b.chain_mut().bus_mut().broken = false;
    b.tick(31);
    assert!(!b.chain_dead());
}
