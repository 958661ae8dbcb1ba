//! Trapezoidal profile generator: the single source of truth for where an
//! axis should be, tick by tick.
//!
//! # What it guarantees
//!
//! * **Units.** Positions are logical steps (PoStep60 step mode), speeds are
//!   steps/s, accelerations steps/s². Internally the position is kept in
//!   2⁻³³ steps (`i128`) and the velocity in 2⁻³² steps per tick (`i64`), so
//!   every update is exact integer arithmetic and host and target agree bit for
//!   bit. The tick period is passed in; the generator never reads a clock.
//! * **Kinematics.** Each tick the velocity changes linearly from `v` to `v'`
//!   and the position advances by `(v + v') / 2` — the exact integral of a
//!   linear ramp, which is what a powerSTEP01 executing `Run` at a matching
//!   ACC/DEC does between two setpoints.
//! * **Limits.** `|v'| ≤ max_speed` (quantised down), a speed-up per tick is
//!   at most `acc` and a slow-down at most `dec` (quantised down). When
//!   `max_speed` is lowered mid-move the axis slows down at `dec`. A velocity
//!   never changes sign within one tick: it passes through zero.
//! * **Lower limits never make a target unreachable.** A deceleration lowered
//!   while the axis moves toward a target it could still stop on applies at
//!   once only as far as the axis can still stop on that target: the
//!   generator brakes with the smallest deceleration between the new and the
//!   old one that still lands exactly, until the axis next comes to rest.
//! * **Exact landing.** In position mode the axis brakes on the discrete
//!   braking curve, so a move to a target it can still reach ends with the
//!   position *exactly* on the target and velocity zero, without overshoot.
//!   A target inside the current braking distance (possible only after a
//!   retarget) is passed at full `dec` braking and approached from the other
//!   side — the only physically possible answer.
//! * **Retarget.** New target, new limits, or a switch between position and
//!   velocity mode take effect at the next tick, from the current state,
//!   without a stop.
//!
//! The discrete braking distance from velocity `v = m·dec + r` (`0 ≤ r < dec`)
//! is `D(v) = (m + ½)·v − dec·m(m+1)/2`: `m` full-`dec` ticks and one last
//! partial tick from `r` to zero. It exceeds the continuous `v²/2dec` by at
//! most `dec/8`, so move times match the analytic trapezoid within a tick.

// Exact integer kinematics on bounded state: positions in i128, velocities and
// limits in i64 clamped to the chip's caps; the bounds are in the module doc
// and the property tests run the extremes.
#![allow(clippy::arithmetic_side_effects)]

use super::divisor::{div_u128_by_u32, Divisor};

/// Velocity and acceleration fraction bits (2⁻³² steps per tick).
const VEL_FRAC: u32 = 32;
/// Position fraction bits (2⁻³³ steps: half a velocity quantum, so `(v+v')/2` is exact).
pub(crate) const POS_FRAC: u32 = 33;
const ONE_STEP: i128 = 1 << POS_FRAC;

/// A position in 2⁻³³ steps rounded to the nearest step (halves away
/// from zero).
#[inline]
pub(crate) fn round_fine(fine: i128) -> i128 {
    let half = ONE_STEP / 2;
    if fine >= 0 {
        (fine + half) >> POS_FRAC
    } else {
        -((-fine + half) >> POS_FRAC)
    }
}

/// Motion limits in logical steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Limits {
    /// Steps/s (0 is treated as 1).
    pub max_speed: u32,
    /// Steps/s² (0 is treated as 1).
    pub acc: u32,
    /// Steps/s² (0 is treated as 1).
    pub dec: u32,
}

/// What the generator is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mode {
    /// At rest on an integer step, nothing to do.
    Hold,
    /// Moving to (or sitting on) a target position, in steps.
    Position(i64),
    /// Running at a signed target speed (internal units, 2⁻³² steps/tick).
    Velocity(i64),
}

/// Limits in internal units: (vmax, acc, dec).
type Internal = (i64, i64, i64);

/// The trapezoidal profile generator of one axis.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Profile {
    tick_us: u32,
    /// 2⁻³³ steps.
    pos: i128,
    /// 2⁻³² steps/tick, signed.
    vel: i64,
    mode: Mode,
    limits: Limits,
    vmax: i64,
    acc: i64,
    /// Deceleration in use: `dec_limit`, or more while a lowered limit would
    /// otherwise pass the target (see the module doc).
    dec: i64,
    /// Deceleration of `limits`.
    dec_limit: i64,
    /// `dec` as a divisor (the braking distance every tick needs `v / dec`).
    dec_div: Divisor,
    /// The last braking distance computed at `dec`: (speed, distance). While
    /// cruising the same one is asked for every tick.
    memo: (i64, i128),
    /// The internal limits (vmax, acc, dec) of the last two limits set
    /// (a move's start and its stop alternate between two; the
    /// conversions are 128-bit divisions).
    conv: [Option<(Limits, Internal)>; 2],
    /// The divisor of the deceleration used before `dec_div`.
    prev_div: Divisor,
    /// Ticks still known to cruise: at the last full step the axis ran at
    /// `vmax` toward a target so far beyond its braking distance that this
    /// many more ticks at `vmax` keep it beyond (a lower bound). Each of
    /// them is the full step's result without its arithmetic
    /// ([`Profile::tick`]); anything that changes the mode, the limits or
    /// the position sets it to 0.
    coast: u32,
    /// The next tick's position (2⁻³³ steps) and velocity, given from
    /// outside ([`Profile::lead`]: a coordinated move's line), taken by
    /// that tick instead of the profile's own step.
    led: Option<(i128, i64)>,
    /// In position mode, how far (2⁻³³ steps, ≥ 0) beyond the target the
    /// profile brakes to rest ([`Profile::move_through`]): 0 but for a
    /// path's segment, which it leaves at a speed. (64 bits: a braking
    /// distance beyond 2³⁰ steps is cut to it, which only brakes sooner.)
    beyond: i64,
}

/// Steps/s → 2⁻³² steps/tick, rounded down (never above the limit).
pub const fn speed_to_internal(steps_per_s: u32, tick_us: u32) -> i64 {
    // ≤ 2³² · 2³² · 2³² / 10⁶ < 2⁷⁷: divide in u128, then it fits i64 for any
    // tick up to 2 s (u32 steps/s · 2 s ≪ 2³¹ steps per tick).
    let q = (((steps_per_s as u128) * (tick_us as u128)) << VEL_FRAC) / 1_000_000;
    if q > i64::MAX as u128 {
        i64::MAX
    } else {
        q as i64
    }
}

/// Steps/s² → 2⁻³² steps/tick², rounded down, at least one quantum.
pub const fn acc_to_internal(steps_per_s2: u32, tick_us: u32) -> i64 {
    let t = tick_us as u128;
    let q = (((steps_per_s2 as u128) * t * t) << VEL_FRAC) / 1_000_000_000_000;
    if q == 0 {
        1
    } else if q > i64::MAX as u128 {
        i64::MAX
    } else {
        q as i64
    }
}

/// 2⁻³² steps/tick → steps/s, rounded to nearest (so a speed set in
/// steps/s reads back as the same number).
pub const fn speed_from_internal(v: i64, tick_us: u32) -> i64 {
    if tick_us == 0 {
        return 0;
    }
    // (v · 10⁶) / tick_us toward zero, by 32-bit limbs (an i128 division
    // is a long loop on the Cortex-M4; the control tick asks while the
    // profile is above a lowered max speed).
    let m = div_u128_by_u32(v.unsigned_abs() as u128 * 1_000_000, tick_us) as i128;
    let x = if v < 0 { -m } else { m };
    let half = 1i128 << (VEL_FRAC - 1);
    if x >= 0 {
        ((x + half) >> VEL_FRAC) as i64
    } else {
        -((-x + half) >> VEL_FRAC) as i64
    }
}

/// Twice the discrete braking distance from speed `v ≥ 0` at deceleration
/// `dec > 0`, in 2⁻³³ steps: `(2m+1)·v − dec·m(m+1)` with `m = ⌊v/dec⌋`.
pub fn braking_distance(v: i64, dec: i64) -> i128 {
    if v <= 0 || dec <= 0 {
        return 0;
    }
    braking_with(v, dec, v / dec)
}

/// [`braking_distance`] given `m = ⌊v/dec⌋` (`v, dec > 0`).
fn braking_with(v: i64, dec: i64, m: i64) -> i128 {
    // In 64 bits when (2m+1)·v fits (always while cruising): dec·m ≤ v, so
    // dec·m·(m+1) ≤ (m+1)·v ≤ (2m+1)·v fits too and the result is the same.
    let (uv, ud, um) = (v.unsigned_abs(), dec.unsigned_abs(), m.unsigned_abs());
    if v > 0 && dec > 0 && m >= 0 {
        if let Some(a) = um
            .checked_mul(2)
            .and_then(|t| t.checked_add(1))
            .and_then(|t| t.checked_mul(uv))
        {
            let b = ud * um * (um + 1);
            return i128::from(a - b);
        }
    }
    let m = i128::from(m);
    (2 * m + 1) * i128::from(v) - i128::from(dec) * m * (m + 1)
}

/// `num / d` (rounded toward zero, as `/`): by the 32-bit divide where
/// both fit ([`divisor::div_u64_by_u32`]; the braking fit's `num` is below
/// 2⁶⁴ and its `d` = 2k + 2 below 2³² but for extreme limits), else as
/// `i128` (a 128-step loop on the Cortex-M4).
fn quotient(num: i128, d: i64) -> i128 {
    match (u64::try_from(num), u32::try_from(d)) {
        (Ok(n), Ok(dd)) if dd > 0 => i128::from(super::divisor::div_u64_by_u32(n, dd)),
        _ => num / i128::from(d),
    }
}

/// Ticks at speed `v > 0` (2⁻³² steps/tick, so 2·`v` 2⁻³³ steps a tick)
/// that keep a `slack` of distance beyond the braking point non-negative:
/// `⌊slack / 2v⌋ + 1` for `slack ≥ 0`, rounded down to a shift (a lower
/// bound, division-free; the cruise is checked again when it runs out).
fn cruise_ticks(slack: i128, v: i64) -> u32 {
    if slack < 0 || v <= 0 {
        return 0;
    }
    // 2^b ≥ 2v.
    let b = 65 - (v.unsigned_abs() - 1).leading_zeros();
    let n = (slack as u128) >> b;
    u32::try_from(n).unwrap_or(u32::MAX - 1) + 1
}

/// Position travelled (2⁻³³ steps) if the next velocity is `w` after `v`, then
/// braking to zero: `v + w + 2·D(w)`. Increasing in `w`.
fn reach(v: i64, w: i64, dec: i64) -> i128 {
    i128::from(v) + i128::from(w) + braking_distance(w, dec)
}

impl Profile {
    /// A generator at rest at position 0, ticking every `tick_us` µs.
    pub fn new(tick_us: u32, limits: Limits) -> Profile {
        let mut p = Profile {
            tick_us: tick_us.max(1),
            pos: 0,
            vel: 0,
            mode: Mode::Hold,
            limits,
            vmax: 1,
            acc: 1,
            dec: 1,
            dec_limit: 1,
            dec_div: Divisor::new(1),
            memo: (0, 0),
            conv: [None, None],
            prev_div: Divisor::new(1),
            coast: 0,
            led: None,
            beyond: 0,
        };
        p.set_limits(limits);
        p
    }

    pub fn tick_us(&self) -> u32 {
        self.tick_us
    }

    /// The deceleration in use, with its divisor (only when it changes: the
    /// reciprocal costs a division).
    fn set_dec(&mut self, dec: i64) {
        if dec != self.dec || self.dec_div.get() != dec.unsigned_abs() {
            self.dec = dec;
            let d = dec.unsigned_abs();
            let old = self.dec_div;
            self.dec_div = if self.prev_div.get() == d {
                self.prev_div
            } else {
                Divisor::new(d)
            };
            self.prev_div = old;
            self.memo = (0, 0);
            self.coast = 0;
        }
    }

    /// [`braking_distance`] at the deceleration in use, division-free.
    fn braking(&mut self, v: i64) -> i128 {
        if v <= 0 {
            return 0;
        }
        if self.memo.0 == v {
            return self.memo.1;
        }
        let d = braking_with(v, self.dec, self.dec_div.div(v.unsigned_abs()) as i64);
        self.memo = (v, d);
        d
    }

    /// [`reach`] at the deceleration in use, division-free.
    fn reach(&mut self, v: i64, w: i64) -> i128 {
        i128::from(v) + i128::from(w) + self.braking(w)
    }

    /// New max speed / acceleration / deceleration; effective at the next
    /// tick. A lower deceleration never lets a reachable target be passed
    /// (module doc).
    pub fn set_limits(&mut self, limits: Limits) {
        self.coast = 0;
        self.limits = limits;
        let (vmax, acc, dec) = self.internal(limits);
        self.vmax = vmax;
        self.acc = acc;
        let d = if dec < self.dec {
            self.stoppable_dec(dec)
        } else {
            dec
        };
        self.set_dec(d);
        self.dec_limit = dec;
    }

    /// Work out `limits`' internal units now, for a later
    /// [`Profile::set_limits`] (remembered with the last ones), and the
    /// divisor of their deceleration (kept beside the one in use): nothing
    /// else changes.
    pub fn prepare_limits(&mut self, limits: Limits) {
        let (_, _, dec) = self.internal(limits);
        let d = dec.unsigned_abs();
        if self.dec_div.get() != d && self.prev_div.get() != d {
            self.prev_div = Divisor::new(d);
        }
    }

    /// Remember `limits`' internal units `v` (vmax, acc, dec, as
    /// [`Profile::set_limits`] works them out) for a later `set_limits`:
    /// worked out beforehand where a tick has no time for the divisions (a
    /// path's next segment).
    pub fn remember_limits(&mut self, limits: Limits, v: (i64, i64, i64)) {
        let [last, _] = self.conv;
        self.conv = [Some((limits, v)), last];
    }

    /// `limits` in internal units, as [`Profile::set_limits`] uses them.
    pub fn internal_of(tick_us: u32, limits: Limits) -> (i64, i64, i64) {
        (
            speed_to_internal(limits.max_speed.max(1), tick_us.max(1)).max(1),
            acc_to_internal(limits.acc.max(1), tick_us.max(1)),
            acc_to_internal(limits.dec.max(1), tick_us.max(1)),
        )
    }

    /// `limits` in internal units: (vmax, acc, dec), remembered for the last
    /// two limits (module doc of [`Profile`]'s fields).
    fn internal(&mut self, limits: Limits) -> Internal {
        let [last, before] = self.conv;
        for (l, v) in [last, before].into_iter().flatten() {
            if l == limits {
                return v;
            }
        }
        let v = Profile::internal_of(self.tick_us, limits);
        self.conv = [Some((limits, v)), last];
        v
    }

    /// The smallest deceleration in `[lower, self.dec]` with which the axis
    /// still stops on its target, if it is moving toward one it can stop on
    /// now; `lower` otherwise.
    fn stoppable_dec(&self, lower: i64) -> i64 {
        let Mode::Position(target) = self.mode else {
            return lower;
        };
        let rem = (i128::from(target) << POS_FRAC) + i128::from(self.beyond) - self.pos;
        let (r, v) = if self.vel > 0 {
            (rem, self.vel)
        } else {
            (-rem, -self.vel)
        };
        // Braking as hard as `d` allows from here: v, then max(v − d, 0) …
        let stops = |d: i64| reach(v, (v - d).max(0), d) <= r;
        if v <= 0 || r <= 0 || stops(lower) || !stops(self.dec) {
            return lower;
        }
        // reach(v, v − d, d) does not increase with d: bisect.
        let (mut lo, mut hi) = (lower, self.dec);
        while hi - lo > 1 {
            let mid = lo + (hi - lo) / 2;
            if stops(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        hi
    }

    pub fn limits(&self) -> Limits {
        self.limits
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Move to `target` steps (position mode), from whatever the axis is doing.
    pub fn move_to(&mut self, target: i64) {
        self.coast = 0;
        self.led = None;
        self.mode = Mode::Position(target);
        self.beyond = 0;
    }

    /// Move toward `target` steps and pass it at no more than the speed
    /// whose braking distance is `beyond` (2⁻³³ steps, at the deceleration
    /// in use; ≥ 0): the profile runs as to a stop `beyond` past the
    /// target, so in the tick that reaches the target its speed is at most
    /// that one (a path's segment end, [`crate::motion::coordinated`]).
    /// Forward only (a target ahead of the position).
    pub fn move_through(&mut self, target: i64, beyond: i128) {
        self.coast = 0;
        self.led = None;
        self.mode = Mode::Position(target);
        self.beyond = i64::try_from(beyond.max(0)).unwrap_or(i64::MAX);
    }

    /// Run at a signed speed in steps/s (velocity mode), clamped to max speed
    /// at every tick (so lowering max speed slows a running axis down).
    pub fn run_at(&mut self, steps_per_s: i32) {
        let v = speed_to_internal(steps_per_s.unsigned_abs(), self.tick_us);
        self.coast = 0;
        self.led = None;
        self.mode = Mode::Velocity(if steps_per_s < 0 { -v } else { v });
        self.beyond = 0;
    }

    /// Stop at once (no ramp) on the nearest whole step.
    pub fn stop_now(&mut self) {
        let whole = self.position_round();
        self.set_position(whole);
    }

    /// Decelerate with `dec` to a stop on the first whole step at or beyond
    /// the braking point.
    pub fn soft_stop(&mut self) {
        self.coast = 0;
        self.led = None;
        self.beyond = 0;
        if self.vel == 0 {
            self.mode = Mode::Position(self.position_toward(self.pos, 0));
            return;
        }
        let d = self.braking(self.vel.abs());
        let stop = if self.vel > 0 {
            self.pos + d
        } else {
            self.pos - d
        };
        self.mode = Mode::Position(self.position_toward(stop, self.vel));
    }

    /// Define the current position as `steps` (the axis must be at rest; a
    /// moving axis is stopped first, as the PoStep60 does for Set zero).
    pub fn set_position(&mut self, steps: i64) {
        self.set_position_fine(i128::from(steps) << POS_FRAC);
    }

    /// Define the current position exactly, in 2⁻³³ steps (at rest, like
    /// [`Profile::set_position`]): for an axis held between two whole steps.
    pub fn set_position_fine(&mut self, fine: i128) {
        self.coast = 0;
        self.led = None;
        self.vel = 0;
        self.pos = fine;
        self.mode = Mode::Hold;
        self.beyond = 0;
        self.set_dec(self.dec_limit);
    }

    /// Re-base an axis at rest to `fine` (2⁻³³ steps) and keep what it was
    /// asked to do: a target or speed given while it was stopping is kept,
    /// in the new coordinates.
    pub fn rebase_fine(&mut self, fine: i128) {
        self.coast = 0;
        self.led = None;
        self.vel = 0;
        self.pos = fine;
        self.set_dec(self.dec_limit);
    }

    /// Move the position by `delta` (2⁻³³ steps) and keep the velocity: a
    /// path's parameter carried into its next segment (its own origin).
    /// The mode is the caller's to set next.
    pub fn shift_fine(&mut self, delta: i128) {
        self.coast = 0;
        self.led = None;
        self.pos += delta;
    }

    /// Position, rounded to the nearest step (halves away from zero).
    pub fn position_round(&self) -> i64 {
        round_fine(self.pos) as i64
    }

    /// Position in 2⁻³³ steps (exact).
    pub fn position_fine(&self) -> i128 {
        self.pos
    }

    /// Velocity in 2⁻³² steps per tick (exact, signed).
    pub fn velocity_internal(&self) -> i64 {
        self.vel
    }

    /// Velocity in steps/s (nearest).
    pub fn velocity(&self) -> i64 {
        speed_from_internal(self.vel, self.tick_us)
    }

    /// Limits in internal units: (vmax, acc, dec).
    pub fn internal_limits(&self) -> (i64, i64, i64) {
        (self.vmax, self.acc, self.dec)
    }

    /// At rest and nothing left to do.
    pub fn is_settled(&self) -> bool {
        self.vel == 0
            && match self.mode {
                Mode::Hold => true,
                Mode::Position(t) => self.pos == i128::from(t) << POS_FRAC,
                Mode::Velocity(v) => v == 0,
            }
    }

    /// Whole step at or beyond `fine` in the direction of `vel`.
    fn position_toward(&self, fine: i128, vel: i64) -> i64 {
        let floor = fine >> POS_FRAC;
        let exact = floor << POS_FRAC == fine;
        let step = if vel > 0 && !exact { floor + 1 } else { floor };
        let step = if vel == 0 {
            // nearest
            (fine + ONE_STEP / 2) >> POS_FRAC
        } else {
            step
        };
        step.clamp(i128::from(i64::MIN), i128::from(i64::MAX)) as i64
    }

    /// Advance one tick. Returns the new velocity (2⁻³² steps/tick).
    #[inline]
    pub fn tick(&mut self) -> i64 {
        if self.coast > 0 {
            // Cruising far from the target: the full step keeps the speed
            // (`coast`'s doc), and the position advances by it.
            self.coast -= 1;
            self.pos += 2 * i128::from(self.vel);
            return self.vel;
        }
        self.tick_full()
    }

    /// Lead the next tick: it ends at `pos` (2⁻³³ steps) with velocity
    /// `vel` (2⁻³² steps/tick) instead of the profile's own step (a
    /// coordinated move's line sets every axis of its group this way, every
    /// tick). The mode stays what it is: a tick without a lead steps on its
    /// own toward it, within the limits, from where the last lead left it.
    /// The leader keeps the limits; a lead given twice before a tick
    /// replaces the first.
    pub fn lead(&mut self, pos: i128, vel: i64) {
        self.coast = 0;
        self.led = Some((pos, vel));
    }

    /// The tick of a lead ([`Profile::lead`]): its position and velocity.
    #[inline(always)]
    fn take_lead(&mut self) -> i64 {
        let Some((pos, vel)) = self.led.take() else {
            return self.vel;
        };
        self.pos = pos;
        self.vel = vel;
        if vel == 0 {
            self.set_dec(self.dec_limit);
        }
        vel
    }

    /// A lead given and not yet taken by a tick.
    pub fn is_led(&self) -> bool {
        self.led.is_some()
    }

    /// [`Profile::tick`] worked out in full (what every tick computes
    /// outside a cruise; the tests compare the two).
    #[inline(never)]
    pub(crate) fn tick_full(&mut self) -> i64 {
        if self.led.is_some() {
            return self.take_lead();
        }
        let next = match self.mode {
            Mode::Hold => 0,
            Mode::Velocity(target) => self.velocity_step(target),
            Mode::Position(target) => self.position_step(target),
        };
        self.pos += i128::from(self.vel) + i128::from(next);
        self.vel = next;
        if next == 0 {
            // At rest the axis can stop anywhere: back to the limit's deceleration.
            self.set_dec(self.dec_limit);
        }
        if let Mode::Position(t) = self.mode {
            let goal = i128::from(t) << POS_FRAC;
            // Parity leftovers of the last braking tick are below 2⁻³² steps.
            if next == 0 && (goal - self.pos).abs() <= 2 {
                self.pos = goal;
            }
        }
        if let Mode::Velocity(0) = self.mode {
            if next == 0 {
                // Velocity mode with zero target has stopped: stay on a whole step.
                self.mode = Mode::Position(self.position_toward(self.pos, 0));
            }
        }
        next
    }

    fn velocity_step(&self, target: i64) -> i64 {
        let target = target.clamp(-self.vmax, self.vmax);
        let v = self.vel;
        if v >= 0 && target >= v {
            // Speeding up (or holding) forward.
            if target - v <= self.acc {
                target
            } else {
                v + self.acc
            }
        } else if v <= 0 && target <= v {
            // Speeding up (or holding) in reverse.
            if v - target <= self.acc {
                target
            } else {
                v - self.acc
            }
        } else if v > 0 {
            // Slowing down; never cross zero within a tick.
            (v - self.dec).max(target).max(0)
        } else {
            (v + self.dec).min(target).min(0)
        }
    }

    fn position_step(&mut self, target: i64) -> i64 {
        let goal = (i128::from(target) << POS_FRAC) + i128::from(self.beyond);
        let rem = goal - self.pos;
        // Mirror so that the target lies ahead (r ≥ 0).
        let (r, v, sign) = if rem > 0 || (rem == 0 && self.vel <= 0) {
            (rem, self.vel, 1i64)
        } else {
            (-rem, -self.vel, -1i64)
        };
        let w = if v < 0 {
            // Moving away from the target: brake at dec toward zero.
            (v + self.dec).min(0)
        } else {
            let upper = if v <= self.vmax {
                (v + self.acc).min(self.vmax)
            } else {
                (v - self.dec).max(self.vmax)
            };
            let lower = (v - self.dec).max(0);
            let k = self.reach(v, upper);
            if k <= r {
                if v == self.vmax {
                    self.coast = cruise_ticks(r - 2 * i128::from(v) - k, v);
                }
                upper
            } else if self.reach(v, lower) > r {
                // Inside the braking distance: brake as hard as allowed.
                lower
            } else {
                self.fit(r, v, lower, upper)
            }
        };
        w * sign
    }

    /// Largest `w` in `[lower, upper]` with `reach(v, w) ≤ r`, given that
    /// `reach(v, lower) ≤ r < reach(v, upper)`.
    fn fit(&self, r: i128, v: i64, lower: i64, upper: i64) -> i64 {
        let dec = self.dec;
        // reach at a segment boundary k·dec is v + dec·k(k+1); find the last
        // boundary in [lower, upper] that still fits.
        let boundary = |k: i64| i128::from(v) + i128::from(dec) * i128::from(k) * i128::from(k + 1);
        // lower, upper ≥ 0 here.
        let mut lo = self.dec_div.div(lower.unsigned_abs()) as i64; // boundary(lo) ≤ reach(lower) ≤ r
        let mut hi = self.dec_div.div(upper.unsigned_abs()) as i64 + 1; // boundary(hi) ≥ reach(upper) > r
        while hi - lo > 1 {
            let mid = lo + (hi - lo) / 2;
            if boundary(mid) <= r {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let k = lo;
        // Inside segment k: reach = v + (2k+2)·w − dec·k(k+1).
        let num = r - i128::from(v) + i128::from(dec) * i128::from(k) * i128::from(k + 1);
        let w = quotient(num, 2 * k + 2);
        let seg_top = i128::from(dec) * i128::from(k + 1) - 1;
        let w = w.min(seg_top).min(i128::from(upper)).max(i128::from(lower));
        w as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u32 = 1000;

    #[test]
    fn speeds_from_internal_equal_the_i128_division() {
        let by_i128 = |v: i64, t: u32| {
            let x = (i128::from(v) * 1_000_000) / i128::from(t);
            let half = 1i128 << (VEL_FRAC - 1);
            if x >= 0 {
                ((x + half) >> VEL_FRAC) as i64
            } else {
                -((-x + half) >> VEL_FRAC) as i64
            }
        };
        let vs = (-3_000i64..3_000)
            .chain((0..2_000).map(|k| k * 4_611_686_018_427_387))
            .chain((0..2_000).map(|k| -k * 4_611_686_018_427_387))
            .chain([
                i64::MIN,
                i64::MIN + 1,
                i64::MAX,
                1 << 32,
                -(1 << 32),
                400 << 32,
            ]);
        for v in vs {
            for t in [1u32, 7, 200, 250, 500, 1000, 2000, 65_535, u32::MAX] {
                assert_eq!(speed_from_internal(v, t), by_i128(v, t), "{v} {t}");
            }
        }
    }

    fn lim(max_speed: u32, acc: u32, dec: u32) -> Limits {
        Limits {
            max_speed,
            acc,
            dec,
        }
    }

    fn run_to_settle(p: &mut Profile, cap: u32) -> u32 {
        let mut n = 0;
        while !p.is_settled() {
            p.tick();
            n += 1;
            assert!(n < cap, "did not settle in {cap} ticks");
        }
        n
    }

    #[test]
    fn fast_logical_speeds_do_not_overflow() {
        // 3 000 000 logical steps/s (1/256 steps at ~11 700 full steps/s)
        assert_eq!(speed_to_internal(3_000_000, MS), 12_884_901_888_000);
        assert_eq!(speed_to_internal(u32::MAX, MS), 18_446_744_069_414_584);
        assert!(acc_to_internal(u32::MAX, MS) > 0);
    }

    #[test]
    fn speed_conversion_rounds_down() {
        // 1000 steps/s at 1 ms = 1 step/tick
        assert_eq!(speed_to_internal(1000, MS), 1 << 32);
        assert_eq!(speed_from_internal(1 << 32, MS), 1000);
        assert_eq!(speed_to_internal(1, MS), 4_294_967);
    }

    #[test]
    fn acceleration_conversion_rounds_down_but_never_to_zero() {
        // 1e6 steps/s² at 1 ms = 1 step/tick²
        assert_eq!(acc_to_internal(1_000_000, MS), 1 << 32);
        assert_eq!(acc_to_internal(1, MS), 4294);
        assert_eq!(acc_to_internal(0, 1), 1);
    }

    /// The formula in 128 bits, as the module doc writes it.
    fn braking_reference(v: i64, dec: i64) -> i128 {
        let m = i128::from(v / dec);
        (2 * m + 1) * i128::from(v) - i128::from(dec) * m * (m + 1)
    }

    proptest::proptest! {
        #[test]
        fn braking_in_64_bits_equals_the_128_bit_formula(
            v in 1i64..,
            dec in 1i64..,
        ) {
            proptest::prop_assert_eq!(braking_distance(v, dec), braking_reference(v, dec));
        }

        #[test]
        fn braking_with_small_decelerations_too(v in 1i64.., dec in 1i64..1_000_000) {
            proptest::prop_assert_eq!(braking_distance(v, dec), braking_reference(v, dec));
        }
    }

    #[test]
    fn braking_distance_of_whole_multiples_matches_continuous() {
        // v = 4 dec: ticks 4→3→2→1→0, distance (7+5+3+1)/2 = 8 dec = v²/(2 dec)
        assert_eq!(braking_distance(40, 10), 2 * 80);
        assert_eq!(braking_distance(0, 10), 0);
        // v = 5 (< dec): one tick, distance 5/2
        assert_eq!(braking_distance(5, 10), 5);
    }

    #[test]
    fn trapezoid_move_lands_exactly_on_target() {
        let mut p = Profile::new(MS, lim(2000, 10_000, 5_000));
        p.move_to(10_000);
        run_to_settle(&mut p, 100_000);
        assert_eq!(p.position_fine(), 10_000i128 << POS_FRAC);
        assert_eq!(p.velocity_internal(), 0);
    }

    #[test]
    fn triangle_move_lands_exactly_on_target() {
        let mut p = Profile::new(MS, lim(50_000, 1_000, 3_000));
        p.move_to(-137);
        run_to_settle(&mut p, 100_000);
        assert_eq!(p.position_round(), -137);
        assert_eq!(p.position_fine(), -137i128 << POS_FRAC);
    }

    #[test]
    fn trapezoid_time_matches_analytic_within_a_tick() {
        // d = 10000, v = 2000, a = 10000, dec = 5000:
        // T = d/v + v/2a + v/2dec = 5 + 0.1 + 0.2 = 5.3 s
        let mut p = Profile::new(MS, lim(2000, 10_000, 5_000));
        p.move_to(10_000);
        let n = run_to_settle(&mut p, 100_000);
        assert!((5299..=5301).contains(&n), "{n} ticks");
    }

    #[test]
    fn retarget_behind_reverses_without_exceeding_dec() {
        let mut p = Profile::new(MS, lim(1000, 2000, 2000));
        p.move_to(100_000);
        for _ in 0..800 {
            p.tick();
        }
        assert!(p.velocity() > 0);
        p.move_to(0);
        let (_, _, dec) = p.internal_limits();
        let mut prev = p.velocity_internal();
        let mut n = 0;
        while !p.is_settled() {
            let v = p.tick();
            assert!((v - prev).abs() <= dec.max(p.internal_limits().1));
            prev = v;
            n += 1;
            assert!(n < 100_000);
        }
        assert_eq!(p.position_fine(), 0);
    }

    #[test]
    fn velocity_mode_reaches_speed_and_soft_stop_ends_on_a_whole_step() {
        let mut p = Profile::new(MS, lim(5000, 10_000, 10_000));
        p.run_at(-3000);
        for _ in 0..1000 {
            p.tick();
        }
        assert_eq!(p.velocity(), -3000);
        p.soft_stop();
        run_to_settle(&mut p, 10_000);
        assert_eq!(p.position_fine() & ((1 << POS_FRAC) - 1), 0);
    }

    #[test]
    fn stop_now_zeroes_speed_on_the_nearest_step() {
        let mut p = Profile::new(MS, lim(5000, 10_000, 10_000));
        p.move_to(1_000_000);
        for _ in 0..333 {
            p.tick();
        }
        p.stop_now();
        assert_eq!(p.velocity_internal(), 0);
        assert!(p.is_settled());
        assert_eq!(p.position_fine() & ((1 << POS_FRAC) - 1), 0);
    }

    #[test]
    fn lowering_max_speed_mid_move_slows_down_at_dec() {
        let mut p = Profile::new(MS, lim(4000, 10_000, 1_000));
        p.move_to(1_000_000);
        for _ in 0..1000 {
            p.tick();
        }
        assert_eq!(p.velocity(), 4000);
        p.set_limits(lim(1000, 10_000, 1_000));
        let before = p.velocity_internal();
        let after = p.tick();
        assert_eq!(before - after, p.internal_limits().2);
        for _ in 0..4000 {
            p.tick();
        }
        assert_eq!(p.velocity(), 1000);
    }

    /// What a sequence of commands does to a profile.
    #[derive(Clone, Debug)]
    enum Op {
        Ticks(u16),
        MoveTo(i64),
        RunAt(i32),
        Limits(u32, u32, u32),
        SoftStop,
        StopNow,
        Rebase(i64),
    }

    fn op() -> impl proptest::strategy::Strategy<Value = Op> {
        use proptest::prelude::*;
        prop_oneof![
            4 => (1u16..3000).prop_map(Op::Ticks),
            2 => prop_oneof![-200i64..200, -3_000_000i64..3_000_000, proptest::num::i64::ANY.prop_map(|t| t >> 20)]
                .prop_map(Op::MoveTo),
            1 => (-400_000i32..400_000).prop_map(Op::RunAt),
            1 => (1u32..3_000_000, 1u32..10_000_000, 1u32..10_000_000)
                .prop_map(|(v, a, d)| Op::Limits(v, a, d)),
            1 => Just(Op::SoftStop),
            1 => Just(Op::StopNow),
            1 => (-1_000i64..1_000).prop_map(Op::Rebase),
        ]
    }

    proptest::proptest! {
        /// The cruise's shortcut ([`Profile::tick`] while `coast` counts)
        /// gives, tick by tick, what the full step gives: the same
        /// position, speed and mode, whatever came before.
        #[test]
        fn a_cruise_tick_is_the_full_step(
            tick_us in proptest::sample::select(vec![100u32, 200, 250, 500, 1000, 2000]),
            (v, a, d) in (1u32..3_000_000, 1u32..10_000_000, 1u32..10_000_000),
            ops in proptest::collection::vec(op(), 1..24),
        ) {
            let mut fast = Profile::new(tick_us, lim(v, a, d));
            let mut full = fast.clone();
            for op in ops {
                match op {
                    Op::Ticks(n) => {
                        for _ in 0..n {
                            proptest::prop_assert_eq!(fast.tick(), full.tick_full());
                            proptest::prop_assert_eq!(fast.position_fine(), full.position_fine());
                            proptest::prop_assert_eq!(fast.mode(), full.mode());
                        }
                    }
                    Op::MoveTo(t) => { fast.move_to(t); full.move_to(t); }
                    Op::RunAt(s) => { fast.run_at(s); full.run_at(s); }
                    Op::Limits(v, a, d) => {
                        fast.set_limits(lim(v, a, d));
                        full.set_limits(lim(v, a, d));
                    }
                    Op::SoftStop => { fast.soft_stop(); full.soft_stop(); }
                    Op::StopNow => { fast.stop_now(); full.stop_now(); }
                    Op::Rebase(x) => {
                        fast.rebase_fine(i128::from(x) << POS_FRAC);
                        full.rebase_fine(i128::from(x) << POS_FRAC);
                    }
                }
                proptest::prop_assert_eq!(fast.internal_limits(), full.internal_limits());
            }
        }
    }

    #[test]
    fn a_long_move_cruises_on_the_shortcut_and_lands_as_the_full_step_does() {
        let mut fast = Profile::new(MS, lim(20_000, 100_000, 50_000));
        let mut full = fast.clone();
        fast.move_to(5_000_000);
        full.move_to(5_000_000);
        let (mut coasted, mut ticks) = (0u32, 0u32);
        while !full.is_settled() {
            coasted += u32::from(fast.coast > 0);
            assert_eq!(fast.tick(), full.tick_full());
            assert_eq!(fast.position_fine(), full.position_fine());
            ticks += 1;
        }
        assert!(fast.is_settled());
        assert_eq!(fast.position_round(), 5_000_000);
        // 250 s of travel, nearly all of it at 20 000 steps/s: all but
        // the ramps and a tick per halving of the distance left coast.
        assert!(ticks > 250_000, "{ticks}");
        assert!(coasted > ticks - 1_000, "{coasted} of {ticks}");
    }
}
