//! A coordinated straight-line move of several axes: the shared profile of
//! issue 23's coordinated moves, on its own. Not reachable from any bus yet
//! (the group's per-tick streaming, the path queue with its junction rule,
//! group stops and the register block are the next steps, listed as
//! missing in the README).
//!
//! # What it guarantees
//!
//! * **One profile, one line.** A [`Line`] from `start` to `target` runs one
//!   trapezoidal [`Profile`] over the path parameter `s ∈ [0, L]`, where
//!   `L = maxᵢ |targetᵢ − startᵢ|` (the distance of the axis that travels
//!   farthest: path speeds are that axis's steps/s). Axis `i` is at
//!   `startᵢ + dᵢ · s / L` every tick, exactly (2⁻³³ steps), so the rounded
//!   position of every axis is within half a step of the straight line
//!   through the two points, and every axis lands exactly on its target in
//!   the same tick (the profile lands exactly on `L`).
//! * **No axis exceeds its own limits.** The path's limits are the smallest
//!   of the requested path limits and, for every moving axis,
//!   `⌊limitᵢ · L / |dᵢ|⌋`: axis `i` moves at `|dᵢ| / L` of the path's speed,
//!   acceleration and deceleration, so it never exceeds its max speed,
//!   acceleration or deceleration (the most constrained axis sets the pace).
//!   The profile's own one-quantum minimum acceleration (2⁻³² steps/tick²)
//!   is the only exception, as for a single axis.
//! * **Exact integers.** Offsets are `i64` steps, the path parameter is the
//!   profile's `i128` in 2⁻³³ steps; `|dᵢ| ≤ 2³²` keeps `dᵢ · s` below 2⁹⁸.
//!   A longer component is refused ([`CoordError::TooLong`]).

// Exact integer maths on bounded values: components ≤ 2³² steps (checked in
// `Line::new`), so every product below fits its i128/u128.
#![allow(clippy::arithmetic_side_effects)]

use super::profile::{Limits, Profile};

/// Axes in one coordinated move: a chain's most.
pub const MAX_AXES: usize = 8;

/// Longest component of a coordinated move, steps (2³²).
pub const MAX_COMPONENT: u64 = 1 << 32;

/// 2⁻³³ steps per step (the profile's position unit).
const POS_FRAC: u32 = 33;

/// Why a coordinated move was not planned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CoordError {
    /// No axis named.
    NoAxes,
    /// More than [`MAX_AXES`] axes.
    TooManyAxes,
    /// `start`, `target` and `limits` name different numbers of axes.
    LengthMismatch,
    /// A component longer than [`MAX_COMPONENT`] steps.
    TooLong,
    /// The path cannot stop on its last waypoint from the speed it has now
    /// (a look-ahead asked too late); the caller stops it as it can.
    CannotStop,
}

/// A coordinated move in progress (module doc).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Line {
    n: usize,
    start: [i64; MAX_AXES],
    delta: [i64; MAX_AXES],
    /// `L`, steps (0: nothing moves).
    length: i64,
    path: Profile,
}

/// `⌊limit · L / |d|⌋`, at most `u32::MAX` (the path limit axis `d` allows).
fn scaled(limit: u32, length: u64, d: u64) -> u32 {
    if d == 0 {
        return u32::MAX;
    }
    let q = u128::from(limit.max(1)) * u128::from(length) / u128::from(d);
    u32::try_from(q).unwrap_or(u32::MAX)
}

/// The path's limits: `path` capped by every moving axis's scaled limits.
pub fn path_limits(deltas: &[i64], limits: &[Limits], path: Limits) -> Limits {
    let length = deltas.iter().map(|d| d.unsigned_abs()).max().unwrap_or(0);
    let mut out = Limits {
        max_speed: path.max_speed.max(1),
        acc: path.acc.max(1),
        dec: path.dec.max(1),
    };
    for (d, l) in deltas.iter().zip(limits) {
        let d = d.unsigned_abs();
        out.max_speed = out.max_speed.min(scaled(l.max_speed, length, d));
        out.acc = out.acc.min(scaled(l.acc, length, d));
        out.dec = out.dec.min(scaled(l.dec, length, d));
    }
    out
}

/// The highest speed through the junction of two segments with components
/// `d_in` then `d_out` (the same axes, each segment's path speed in steps/s
/// of its farthest axis, as for a [`Line`]) at which no axis's velocity
/// jumps by more than the smaller of its acceleration and deceleration
/// allows in one tick of `tick_us`:
/// with `u = d_in / L_in`, `w = d_out / L_out` and the speed `v` on both
/// sides, axis `i` jumps by `v · |uᵢ − wᵢ|`, so
/// `v ≤ min_i accᵢ · tick / |uᵢ − wᵢ|` (rounded down). A chip sees one
/// velocity per tick: a jump no larger than one tick's acceleration is what
/// it does between any two ticks anyway. `u32::MAX` for a straight
/// continuation (the segments' own limits cap it), 0 for mismatched or
/// empty groups. (The rule of the path queue to come; DECISIONS.md.)
pub fn junction_speed(d_in: &[i64], d_out: &[i64], limits: &[Limits], tick_us: u32) -> u32 {
    let n = d_in.len();
    if n == 0 || d_out.len() != n || limits.len() != n {
        return 0;
    }
    let l_in = u128::from(d_in.iter().map(|d| d.unsigned_abs()).max().unwrap_or(0));
    let l_out = u128::from(d_out.iter().map(|d| d.unsigned_abs()).max().unwrap_or(0));
    if l_in == 0
        || l_out == 0
        || l_in > u128::from(MAX_COMPONENT)
        || l_out > u128::from(MAX_COMPONENT)
    {
        // A zero-length segment is a stop; an over-long one is refused.
        return 0;
    }
    let mut v = u32::MAX;
    for ((a, b), lim) in d_in.iter().zip(d_out).zip(limits) {
        // |uᵢ − wᵢ| = |aᵢ·L_out − bᵢ·L_in| / (L_in·L_out); both terms < 2⁶⁵.
        let x = i128::from(*a) * l_out as i128 - i128::from(*b) * l_in as i128;
        let jump = x.unsigned_abs();
        if jump == 0 {
            continue;
        }
        // acc · tick · L_in · L_out / (10⁶ · jump): < 2³² · 2³² · 2⁶⁴ = 2¹²⁸.
        let num = u128::from(lim.acc.max(1).min(lim.dec.max(1)))
            .saturating_mul(u128::from(tick_us))
            .saturating_mul(l_in)
            .saturating_mul(l_out);
        let q = num / jump.saturating_mul(1_000_000);
        v = v.min(u32::try_from(q).unwrap_or(u32::MAX));
    }
    v
}

/// One segment of a path as the look-ahead sees it: its length (steps of
/// its farthest axis), its path limits, and the highest speed through the
/// junction at its start ([`junction_speed`] with the segment before).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Segment {
    pub length: u64,
    pub limits: Limits,
    pub junction: u32,
}

/// ⌊√x⌋ (Newton's method from above; exact).
fn isqrt(x: u128) -> u128 {
    if x < 2 {
        return x;
    }
    let mut r = 1u128 << (128 - x.leading_zeros()).div_ceil(2);
    loop {
        let next = (r + x / r) / 2;
        if next >= r {
            return r;
        }
        r = next;
    }
}

/// The speed reachable over `length` steps from `v` at `rate` steps/s²
/// (up or down, continuous kinematics: `√(v² + 2·rate·length)`), rounded
/// down and at most `u32::MAX`.
fn over(v: u32, rate: u32, length: u64) -> u32 {
    let v2 = u128::from(v) * u128::from(v);
    let s = 2 * u128::from(rate.max(1)) * u128::from(length);
    u32::try_from(isqrt(v2 + s)).unwrap_or(u32::MAX)
}

/// The look-ahead: the speed at every waypoint of the queued `segments`,
/// starting at `speed` (the path's speed now, at the start of the first
/// segment), such that the path always stops on its last waypoint. Writes
/// `segments.len() + 1` speeds to `out` (the first is `speed`, the last 0)
/// and returns how many. Each is the highest that (backward) still brakes to
/// every later waypoint's speed with each segment's deceleration and
/// (forward) is reached from the one before with its acceleration, and no
/// waypoint is faster than its junction or either segment's max speed.
/// Continuous kinematics, as grbl's planner; the tick-exact execution is the
/// profile's. [`CoordError::CannotStop`] when `speed` is above what the
/// first segment can still brake from, [`CoordError::TooManyAxes`] when
/// `out` is too short.
pub fn plan_speeds(speed: u32, segments: &[Segment], out: &mut [u32]) -> Result<usize, CoordError> {
    let n = segments.len();
    let Some(speeds) = out.get_mut(..=n) else {
        return Err(CoordError::TooManyAxes);
    };
    // Backward: the highest speed at each waypoint that still stops at the end.
    let mut later = 0u32;
    if let Some(last) = speeds.last_mut() {
        *last = 0;
    }
    for k in (0..n).rev() {
        let (Some(seg), Some(slot)) = (segments.get(k), speeds.get_mut(k)) else {
            break;
        };
        let mut cap = over(later, seg.limits.dec, seg.length).min(seg.limits.max_speed.max(1));
        if k > 0 {
            let before = segments
                .get(k - 1)
                .map_or(u32::MAX, |b| b.limits.max_speed.max(1));
            cap = cap.min(seg.junction).min(before);
        }
        *slot = cap;
        later = cap;
    }
    // Forward: from `speed`, as fast as each segment's acceleration allows.
    let first = speeds.first().copied().unwrap_or(0);
    if n > 0 && speed > first {
        return Err(CoordError::CannotStop);
    }
    let mut now = speed;
    for k in 0..=n {
        let Some(slot) = speeds.get_mut(k) else {
            break;
        };
        if k == 0 {
            *slot = speed;
        } else {
            let reach = segments
                .get(k - 1)
                .map_or(0, |s| over(now, s.limits.acc, s.length));
            *slot = (*slot).min(reach);
        }
        now = *slot;
    }
    Ok(n + 1)
}

impl Line {
    /// Plan the move of the axes at `start` to `target` (logical steps),
    /// each within its `limits`, at most at the `path` limits (in steps of
    /// the axis that travels farthest), ticked every `tick_us` µs.
    pub fn new(
        tick_us: u32,
        start: &[i64],
        target: &[i64],
        limits: &[Limits],
        path: Limits,
    ) -> Result<Line, CoordError> {
        let n = start.len();
        if n == 0 {
            return Err(CoordError::NoAxes);
        }
        if n > MAX_AXES {
            return Err(CoordError::TooManyAxes);
        }
        if target.len() != n || limits.len() != n {
            return Err(CoordError::LengthMismatch);
        }
        let mut s = [0i64; MAX_AXES];
        let mut delta = [0i64; MAX_AXES];
        for (k, (a, b)) in start.iter().zip(target).enumerate() {
            let d = i128::from(*b) - i128::from(*a);
            if d.unsigned_abs() > u128::from(MAX_COMPONENT) {
                return Err(CoordError::TooLong);
            }
            if let (Some(sk), Some(dk)) = (s.get_mut(k), delta.get_mut(k)) {
                *sk = *a;
                // |d| ≤ 2³²: fits.
                *dk = d as i64;
            }
        }
        let deltas = delta.get(..n).unwrap_or(&[]);
        let length = deltas.iter().map(|d| d.unsigned_abs()).max().unwrap_or(0);
        let mut profile = Profile::new(tick_us, path_limits(deltas, limits, path));
        // length ≤ 2³²: fits i64.
        profile.move_to(length as i64);
        Ok(Line {
            n,
            start: s,
            delta,
            length: length as i64,
            path: profile,
        })
    }

    /// Axes in the move.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Never true: a line has at least one axis.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// The limits the shared profile runs with (module doc).
    pub fn path_limits(&self) -> Limits {
        self.path.limits()
    }

    /// Advance one tick.
    pub fn tick(&mut self) {
        self.path.tick();
    }

    /// Every axis on its target, at rest.
    pub fn is_done(&self) -> bool {
        self.path.is_settled()
    }

    /// The path parameter `s`, 2⁻³³ steps of the farthest axis.
    pub fn path_fine(&self) -> i128 {
        self.path.position_fine()
    }

    /// Axis `k`'s position, 2⁻³³ steps, exact but for the division by `L`
    /// (rounded toward zero: under 2⁻³³ steps). `None` past the last axis.
    pub fn position_fine(&self, k: usize) -> Option<i128> {
        if k >= self.n {
            return None;
        }
        let a = i128::from(*self.start.get(k)?) << POS_FRAC;
        if self.length == 0 {
            return Some(a);
        }
        let d = i128::from(*self.delta.get(k)?);
        Some(a + d * self.path.position_fine() / i128::from(self.length))
    }

    /// Axis `k`'s position, nearest step (halves away from zero).
    pub fn position(&self, k: usize) -> Option<i64> {
        let f = self.position_fine(k)?;
        let half = 1i128 << (POS_FRAC - 1);
        let p = if f >= 0 {
            (f + half) >> POS_FRAC
        } else {
            -((-f + half) >> POS_FRAC)
        };
        i64::try_from(p).ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIM: Limits = Limits {
        max_speed: 10_000,
        acc: 50_000,
        dec: 50_000,
    };
    const FAST: Limits = Limits {
        max_speed: u32::MAX,
        acc: u32::MAX,
        dec: u32::MAX,
    };

    fn run(line: &mut Line, cap: u32) -> u32 {
        for t in 0..cap {
            if line.is_done() {
                return t;
            }
            line.tick();
        }
        panic!("not done in {cap} ticks");
    }

    #[test]
    fn every_axis_lands_on_its_target_in_the_same_tick() {
        let mut line = Line::new(1000, &[0, 100, -5], &[3000, -400, -5], &[LIM; 3], FAST).unwrap();
        run(&mut line, 10_000);
        assert_eq!(
            (line.position(0), line.position(1), line.position(2)),
            (Some(3000), Some(-400), Some(-5))
        );
    }

    #[test]
    fn the_slowest_axis_for_its_share_sets_the_path_speed() {
        // Axis 1 moves half as far as axis 0 at a quarter of its speed
        // limit: the path (axis 0's steps/s) may go at 2 × 2 500 = 5 000.
        let slow = Limits {
            max_speed: 2_500,
            ..LIM
        };
        let line = Line::new(1000, &[0, 0], &[2000, 1000], &[LIM, slow], FAST).unwrap();
        assert_eq!(line.path_limits().max_speed, 5_000);
        assert_eq!(line.path_limits().acc, 50_000);
    }

    #[test]
    fn the_requested_path_speed_caps_the_axes_limits() {
        let path = Limits {
            max_speed: 700,
            acc: 900,
            dec: 800,
        };
        let line = Line::new(1000, &[0, 0], &[2000, 1000], &[LIM; 2], path).unwrap();
        assert_eq!(line.path_limits(), path);
    }

    #[test]
    fn a_move_of_zero_length_is_done_at_once() {
        let line = Line::new(1000, &[7, -3], &[7, -3], &[LIM; 2], FAST).unwrap();
        assert!(line.is_done());
        assert_eq!(line.position(1), Some(-3));
    }

    #[test]
    fn bad_groups_are_refused() {
        assert_eq!(
            Line::new(1000, &[], &[], &[], FAST),
            Err(CoordError::NoAxes)
        );
        assert_eq!(
            Line::new(1000, &[0; 9], &[1; 9], &[LIM; 9], FAST),
            Err(CoordError::TooManyAxes)
        );
        assert_eq!(
            Line::new(1000, &[0, 0], &[1], &[LIM; 2], FAST),
            Err(CoordError::LengthMismatch)
        );
        assert_eq!(
            Line::new(1000, &[i64::MIN], &[i64::MAX], &[LIM], FAST),
            Err(CoordError::TooLong)
        );
        assert_eq!(line_of(-(1 << 32)).map(|l| l.len()), Ok(1));
        assert_eq!(line_of(-(1 << 32) - 1), Err(CoordError::TooLong));
    }

    fn line_of(d: i64) -> Result<Line, CoordError> {
        Line::new(1000, &[0], &[d], &[LIM], FAST)
    }

    #[test]
    fn a_straight_continuation_is_no_junction() {
        assert_eq!(
            junction_speed(&[100, 50], &[40, 20], &[LIM; 2], 1000),
            u32::MAX
        );
    }

    #[test]
    fn a_right_angle_allows_one_tick_of_the_smaller_acceleration() {
        // X then Y: each axis's velocity jumps by v; 50 000 steps/s² · 1 ms.
        let slow = Limits { acc: 20_000, ..LIM };
        assert_eq!(junction_speed(&[100, 0], &[0, 300], &[LIM, slow], 1000), 20);
    }

    #[test]
    fn a_reversal_allows_half_a_tick_of_acceleration() {
        assert_eq!(junction_speed(&[100], &[-7], &[LIM], 1000), 25);
    }

    #[test]
    fn a_zero_length_or_mismatched_segment_is_a_stop() {
        assert_eq!(junction_speed(&[0, 0], &[5, 5], &[LIM; 2], 1000), 0);
        assert_eq!(junction_speed(&[1, 0], &[5], &[LIM; 2], 1000), 0);
        assert_eq!(junction_speed(&[], &[], &[], 1000), 0);
    }

    #[test]
    fn integer_square_roots_are_exact() {
        for x in [
            0u128,
            1,
            2,
            3,
            4,
            15,
            16,
            17,
            1 << 64,
            (1 << 66) - 1,
            u128::MAX,
        ] {
            let r = isqrt(x);
            assert!(
                r * r <= x && (r + 1).checked_mul(r + 1).is_none_or(|s| s > x),
                "{x}"
            );
        }
    }

    #[test]
    fn a_single_segment_path_starts_at_its_speed_and_ends_at_rest() {
        let seg = Segment {
            length: 1000,
            limits: LIM,
            junction: u32::MAX,
        };
        let mut out = [7u32; 4];
        assert_eq!(plan_speeds(0, &[seg], &mut out), Ok(2));
        assert_eq!(&out[..2], &[0, 0]);
    }

    #[test]
    fn a_right_angle_slows_the_path_to_its_junction_speed() {
        let a = Segment {
            length: 100_000,
            limits: LIM,
            junction: u32::MAX,
        };
        let b = Segment { junction: 50, ..a };
        let mut out = [0u32; 3];
        plan_speeds(0, &[a, b], &mut out).unwrap();
        assert_eq!(out, [0, 50, 0]);
    }

    #[test]
    fn a_path_that_cannot_stop_in_time_is_refused() {
        // 10 steps at 50 000 steps/s² stop from at most √(2·50 000·10) = 1 000.
        let seg = Segment {
            length: 10,
            limits: LIM,
            junction: u32::MAX,
        };
        let mut out = [0u32; 2];
        assert_eq!(plan_speeds(1000, &[seg], &mut out), Ok(2));
        assert_eq!(
            plan_speeds(1001, &[seg], &mut out),
            Err(CoordError::CannotStop)
        );
        assert_eq!(
            plan_speeds(0, &[seg], &mut [0u32; 1]),
            Err(CoordError::TooManyAxes)
        );
    }

    #[test]
    fn past_the_last_axis_there_is_no_position() {
        let line = Line::new(1000, &[0], &[10], &[LIM], FAST).unwrap();
        assert_eq!(line.position(1), None);
    }
}
