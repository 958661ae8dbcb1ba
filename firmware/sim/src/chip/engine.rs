//! The motion engine: speed and position integrated per 250 ns chip tick in
//! closed form, exactly, independent of how time is sliced.

// The motion engine's arithmetic is on register-bounded values in u64/u128
// (speeds ≤ 20 bits, ACC/DEC ≤ 12 bits, tick counts): no sum or product
// comes near the type's range; every divisor is checked non-zero first (a
// chip with ACC or DEC 0 cruises) and subtractions follow the comparison
// that orders them.
#![allow(clippy::arithmetic_side_effects)]

use super::*;

/// Distance in microsteps from `from` to `to` going in `dir` (22-bit wrap).
pub(super) fn dist_in_dir(dir: Direction, from: u32, to: u32) -> u64 {
    let d = match dir {
        Direction::Forward => to.wrapping_sub(from),
        Direction::Reverse => from.wrapping_sub(to),
    };
    u64::from(d & POS_MASK)
}

/// Full-step distance (2⁻⁴⁰ step) of `j` ticks accelerating by `a` from `v`.
pub(super) fn s_up(v: u64, a: u64, j: u64) -> u128 {
    let (v, a, j) = (u128::from(v), u128::from(a), u128::from(j));
    j * v + a * (j * (j + 1) / 2)
}

/// Full-step distance of `j` ticks decelerating by `d` from `v` (`j·d ≤ v`).
pub(super) fn s_down(v: u64, d: u64, j: u64) -> u128 {
    let (v, d, j) = (u128::from(v), u128::from(d), u128::from(j));
    (j * v).saturating_sub(d * (j * (j + 1) / 2))
}

/// Discrete braking distance from `v` down to the floor `vf` at `d` per tick
/// (full-step units). `None` = infinite (no deceleration available).
pub(super) fn brake_dist(v: u64, vf: u64, d: u64) -> Option<u128> {
    if v <= vf {
        return Some(0);
    }
    if d == 0 {
        return None;
    }
    let n1 = (v - vf) / d;
    let mut s = s_down(v, d, n1);
    // One more tick clamps the speed to the floor if it did not land on it.
    if v - n1 * d > vf {
        s += u128::from(vf);
    }
    Some(s)
}

/// Smallest `j` in `lo..=hi` with `pred(j)` for a monotone predicate.
pub(super) fn first_true(lo: u64, hi: u64, pred: impl Fn(u64) -> bool) -> Option<u64> {
    if lo > hi || !pred(hi) {
        return None;
    }
    let (mut lo, mut hi) = (lo, hi);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if pred(mid) {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    Some(lo)
}

/// A position move's facts for one step of the engine: where to, how far
/// in whole microsteps and in 2⁻⁴⁰ microsteps (`r`), and a full step in
/// 2⁻⁴⁰ microsteps at this step mode (`ms`).
#[derive(Clone, Copy)]
struct Leg {
    dir: Direction,
    target: u32,
    remaining: u64,
    r: u128,
    ms: u128,
}

impl Leg {
    /// Whether `dist` (full-step units) reaches the target.
    fn reaches(&self, dist: u128) -> bool {
        dist.saturating_mul(self.ms) >= self.r
    }
}

impl Powerstep01 {
    // ---------------------------------------------------------- motion ----

    /// Let `dt_ns` nanoseconds pass (exact; see the module docs).
    pub fn advance(&mut self, dt_ns: u64) {
        // In chip time: dt · (10⁶ + ppm), in units of 10⁻⁶ ns (the remainder
        // carries over, so no time is lost at any error).
        let rate = u128::from((1_000_000 + i64::from(self.clock_ppm)).max(1) as u64);
        let unit = u128::from(TICK_NS) * 1_000_000;
        let total = u128::from(self.ns_rem) + u128::from(dt_ns) * rate;
        let ticks = u64::try_from(total / unit).unwrap_or(u64::MAX);
        self.ns_rem = (total % unit) as u64;
        if self.dead.is_some() {
            return;
        }
        self.run_engine(ticks);
        self.apply_cam();
    }

    /// The oscillator's error, ppm (clamped to ±50 %): the chip's time runs
    /// `1 + ppm/10⁶` as fast as [`Powerstep01::advance`]'s. The powerSTEP01's
    /// internal oscillator is a few % off its 16 MHz.
    pub fn set_clock_error_ppm(&mut self, ppm: i32) {
        self.clock_ppm = ppm.clamp(-500_000, 500_000);
    }

    pub(super) fn run_engine(&mut self, mut avail: u64) {
        let mut instant = 0u32;
        while let Some(used) = self.step(avail) {
            avail = avail.saturating_sub(used);
            if used == 0 {
                instant += 1;
                if instant > MAX_INSTANT_STEPS {
                    break;
                }
            } else {
                instant = 0;
            }
        }
    }

    /// Move `steps` microsteps in `dir` (ABS_POS and EL_POS wrap).
    pub(super) fn apply_steps(&mut self, dir: Direction, steps: u128) {
        let s22 = (steps & u128::from(POS_MASK)) as u32;
        let pos = self.abs_raw();
        let pos = match dir {
            Direction::Forward => pos.wrapping_add(s22),
            Direction::Reverse => pos.wrapping_sub(s22),
        };
        self.set_reg(addr::ABS_POS, pos);
        // EL_POS counts 1/128 steps: one microstep = 2^(7 − STEP_SEL).
        let unit = 1u32 << (7u32.saturating_sub(self.step_shift()));
        let el_steps = ((steps & u128::from(fields::EL_POS)) as u32).wrapping_mul(unit);
        let el = self.reg(addr::EL_POS);
        let el = match dir {
            Direction::Forward => el.wrapping_add(el_steps),
            Direction::Reverse => el.wrapping_sub(el_steps),
        };
        self.set_reg(addr::EL_POS, el);
        // The shaft turns whatever ABS_POS says (1/128 steps).
        let turned = i64::try_from(steps.saturating_mul(u128::from(unit))).unwrap_or(i64::MAX);
        self.shaft = match dir {
            Direction::Forward => self.shaft.saturating_add(turned),
            Direction::Reverse => self.shaft.saturating_sub(turned),
        };
    }

    /// Move by `dist` full-step units (2⁻⁴⁰ step) in the current direction.
    /// Returns the number of whole microsteps taken.
    pub(super) fn move_full(&mut self, dist: u128) -> u128 {
        let micro = dist << self.step_shift();
        let total = u128::from(self.frac) + micro;
        let steps = total >> FRAC_BITS;
        self.frac = (total & FRAC_MASK) as u64;
        if steps > 0 {
            self.apply_steps(self.dir, steps);
        }
        steps
    }

    pub(super) fn cruise(&mut self, avail: u64) -> Option<u64> {
        if avail == 0 || self.v == 0 {
            return None;
        }
        self.move_full(u128::from(self.v) * u128::from(avail));
        Some(avail)
    }

    pub(super) fn ramp_up(&mut self, a: u64, n: u64) -> u128 {
        let dist = s_up(self.v, a, n);
        self.v = self.v.saturating_add(a.saturating_mul(n));
        self.move_full(dist)
    }

    pub(super) fn ramp_down(&mut self, d: u64, n: u64) -> u128 {
        let dist = s_down(self.v, d, n);
        self.v = self.v.saturating_sub(d.saturating_mul(n));
        self.move_full(dist)
    }

    /// Decelerate to the floor speed, then stop.
    pub(super) fn decel_to_stop(&mut self, avail: u64) -> Ph {
        let vf = self.floor();
        let d = self.dec();
        if self.v <= vf {
            self.v = 0;
            return Ph::Done;
        }
        if d == 0 {
            return match self.cruise(avail) {
                Some(n) => Ph::Used(n),
                None => Ph::Wait,
            };
        }
        match self.ramp_ticks(self.v - vf, d, 0, avail) {
            Ok(n) => {
                self.ramp_down(d, n);
                Ph::Used(n)
            }
            Err(Some(_)) => Ph::Done,
            Err(None) => Ph::Wait,
        }
    }

    /// One phase of the engine: `Some(ticks used)` (0 for an instant state
    /// change) or `None` when nothing more happens within `avail` ticks.
    pub(super) fn step(&mut self, avail: u64) -> Option<u64> {
        match self.motion {
            Motion::Idle => None,
            Motion::Stopping { hiz } => self.stop_then(avail, |e| {
                e.motion = Motion::Idle;
                if hiz {
                    e.hiz = true;
                }
            }),
            Motion::Speed { dir, spd, .. } => self.step_speed(dir, spd, avail),
            Motion::Position {
                dir,
                target,
                remaining,
                braking,
            } => self.step_position(dir, target, remaining, braking, avail),
        }
    }

    pub(super) fn flip(&mut self, dir: Direction) {
        self.dir = dir;
        self.frac = 0;
    }

    /// Whole ticks of a ramp of `rate` per tick over the speed gap `gap`
    /// that ends at `to`, at most `avail`. `Err` is the step's result when
    /// none is left: less than one tick of the rate (the speed is set to
    /// `to`, `Some(0)`) or no time (`None`).
    fn ramp_ticks(&mut self, gap: u64, rate: u64, to: u64, avail: u64) -> Result<u64, Option<u64>> {
        let whole = gap / rate.max(1);
        if whole == 0 {
            self.v = to;
            return Err(Some(0));
        }
        if avail == 0 {
            return Err(None);
        }
        Ok(whole.min(avail))
    }

    /// Brake to a stop (DEC to the floor, then 0), then `done`: the step's
    /// result (ticks used, `None` waiting, `Some(0)` once stopped).
    fn stop_then(&mut self, avail: u64, done: impl FnOnce(&mut Self)) -> Option<u64> {
        match self.decel_to_stop(avail) {
            Ph::Used(n) => Some(n),
            Ph::Wait => None,
            Ph::Done => {
                done(self);
                Some(0)
            }
        }
    }

    pub(super) fn step_speed(&mut self, dir: Direction, spd: u64, avail: u64) -> Option<u64> {
        if self.dir != dir {
            return self.stop_then(avail, |e| e.flip(dir));
        }
        let vt = self.speed_target(spd);
        let v = self.v;
        if v == 0 && vt > 0 {
            let start = self.floor().min(vt);
            if start > 0 {
                self.v = start;
                return Some(0);
            }
        }
        if v == vt {
            return self.cruise(avail);
        }
        // Towards the target speed with ACC (up) or DEC (down), whole ticks
        // of the rate, then the remainder in one step.
        let up = v < vt;
        let rate = if up { self.acc() } else { self.dec() };
        if rate == 0 {
            return self.cruise(avail);
        }
        let n = match self.ramp_ticks(v.abs_diff(vt), rate, vt, avail) {
            Ok(n) => n,
            Err(step) => return step,
        };
        if up {
            self.ramp_up(rate, n);
        } else {
            self.ramp_down(rate, n);
        }
        Some(n)
    }

    /// Finish a positioning command: `remaining` microsteps in `dir` land
    /// exactly on the target.
    pub(super) fn land(&mut self, dir: Direction, remaining: u64) {
        self.apply_steps(dir, u128::from(remaining));
        self.frac = 0;
        self.v = 0;
        self.motion = Motion::Idle;
    }

    pub(super) fn set_position_state(
        &mut self,
        dir: Direction,
        target: u32,
        remaining: u64,
        braking: bool,
    ) {
        self.motion = Motion::Position {
            dir,
            target,
            remaining,
            braking,
        };
    }

    pub(super) fn step_position(
        &mut self,
        dir: Direction,
        target: u32,
        remaining: u64,
        braking: bool,
        avail: u64,
    ) -> Option<u64> {
        if self.dir != dir {
            return self.stop_then(avail, |e| {
                e.flip(dir);
                let rem = dist_in_dir(dir, e.abs_raw(), target);
                e.set_position_state(dir, target, rem, false);
            });
        }
        if remaining == 0 {
            self.land(dir, 0);
            return Some(0);
        }
        let leg = Leg {
            dir,
            target,
            remaining,
            // Remaining distance in 2⁻⁴⁰ microsteps (> 0: remaining ≥ 1, frac < 1).
            r: (u128::from(remaining) << FRAC_BITS).saturating_sub(u128::from(self.frac)),
            ms: 1u128 << self.step_shift(),
        };
        let v = self.v;
        let vf = self.floor();
        let vmax = self.vmax();
        let d = self.dec();

        if braking {
            if v > vf && d > 0 {
                return self.ramp_down_position(leg, vf, true, avail);
            }
            if v == 0 {
                // Braked to a standstill short of the target (floor 0): go on.
                self.set_position_state(dir, target, remaining, false);
                return Some(0);
            }
            return self.cruise_position(leg, None, avail);
        }

        // Start braking once the remaining distance is within the braking distance.
        let b = brake_dist(v, vf, d);
        if b.is_none_or(|dist| leg.reaches(dist)) && v > 0 {
            self.set_position_state(dir, target, remaining, true);
            return Some(0);
        }
        if v == 0 && vf > 0 {
            self.v = vf;
            return Some(0);
        }
        if v > vmax {
            // Over speed (MAX_SPEED lowered): d > 0 here, else b would be None.
            return self.ramp_down_position(leg, vmax, false, avail);
        }
        if v < vmax {
            return self.accelerate_position(leg, b, avail);
        }
        self.cruise_position(leg, b, avail)
    }

    /// Down by DEC towards `to` (the floor while braking, MAX_SPEED when over
    /// it), landing if the target comes first; `braking` is the state after
    /// the ramp. DEC > 0 (the callers checked).
    fn ramp_down_position(&mut self, leg: Leg, to: u64, braking: bool, avail: u64) -> Option<u64> {
        let v = self.v;
        let d = self.dec();
        let n = match self.ramp_ticks(v - to, d, to, avail) {
            Ok(n) => n,
            Err(step) => return step,
        };
        if let Some(j) = first_true(1, n, |j| leg.reaches(s_down(v, d, j))) {
            self.land(leg.dir, leg.remaining);
            return Some(j);
        }
        let steps = self.ramp_down(d, n);
        self.continue_leg(leg, steps, braking);
        Some(n)
    }

    /// `leg` goes on after `steps` more steps (`braking`: the state it
    /// goes on in).
    fn continue_leg(&mut self, leg: Leg, steps: u128, braking: bool) {
        let rem = leg
            .remaining
            .saturating_sub(u64::try_from(steps).unwrap_or(u64::MAX));
        self.set_position_state(leg.dir, leg.target, rem, braking);
    }

    /// Up by ACC towards MAX_SPEED, braking starts where the distance run
    /// plus the braking distance reaches the target. `b`: the braking
    /// distance at the present speed (for a cruise when ACC is 0).
    fn accelerate_position(&mut self, leg: Leg, b: Option<u128>, avail: u64) -> Option<u64> {
        let v = self.v;
        let vf = self.floor();
        let vmax = self.vmax();
        let d = self.dec();
        let a = self.acc();
        if a == 0 {
            return self.cruise_position(leg, b, avail);
        }
        let n = match self.ramp_ticks(vmax - v, a, vmax, avail) {
            Ok(n) => n,
            Err(step) => return step,
        };
        let trigger = |j: u64| {
            let moved = s_up(v, a, j);
            match brake_dist(v + a * j, vf, d) {
                None => true,
                Some(bd) => leg.reaches(moved.saturating_add(bd)),
            }
        };
        if let Some(j) = first_true(1, n, trigger) {
            if leg.reaches(s_up(v, a, j)) {
                self.land(leg.dir, leg.remaining);
            } else {
                let steps = self.ramp_up(a, j);
                self.continue_leg(leg, steps, true);
            }
            return Some(j);
        }
        let steps = self.ramp_up(a, n);
        self.continue_leg(leg, steps, false);
        Some(n)
    }

    /// Constant speed towards the target. `brake`: braking distance at this
    /// speed when braking has not started yet (`None` when already braking
    /// or no braking applies): the phase ends where braking must start.
    fn cruise_position(&mut self, leg: Leg, brake: Option<u128>, avail: u64) -> Option<u64> {
        let v = self.v;
        if v == 0 || avail == 0 {
            return None;
        }
        let per = u128::from(v) << self.step_shift();
        let bs = brake.unwrap_or(0).saturating_mul(leg.ms);
        let braking = matches!(self.motion, Motion::Position { braking: true, .. });
        // First tick after which r − j·per ≤ bs (bs < r: not yet triggered).
        let gap = leg.r.saturating_sub(bs);
        let j = gap.div_ceil(per).max(1);
        if j <= u128::from(avail) {
            let j64 = u64::try_from(j).unwrap_or(avail);
            if per.saturating_mul(j) >= leg.r {
                self.land(leg.dir, leg.remaining);
            } else {
                let steps = self.move_full(u128::from(v) * j);
                self.continue_leg(leg, steps, true);
            }
            return Some(j64);
        }
        let steps = self.move_full(u128::from(v) * u128::from(avail));
        self.continue_leg(leg, steps, braking);
        Some(avail)
    }
}
