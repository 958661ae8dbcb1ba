//! Coordinated moves, the pure parts: the shared profile of a straight-line
//! move of several axes ([`Line`]), the speed through a junction of two
//! segments ([`junction_speed`]) and the look-ahead over queued segments
//! ([`plan_speeds`]). A [`Line`] runs on the chips through
//! [`crate::motion::coordinated`] (extension 0x08nn); the path queue that
//! would run segments with their exit speeds is not built yet (listed as
//! missing in the README).
//!
//! # What it guarantees
//!
//! * **One profile, one line.** A [`Line`] from `start` to `target` runs one
//!   trapezoidal [`Profile`] over the path parameter `s ∈ [0, L]`, where
//!   `L = maxᵢ |targetᵢ − startᵢ|` (the distance of the axis that travels
//!   farthest: path speeds are that axis's steps/s). Axis `i` is at
//!   `startᵢ + dᵢ · λ` every tick, `λ = s / L` in Q62 (one multiply by a
//!   normalised reciprocal of `L`, at most two units of 2⁻⁶² below the
//!   exact quotient, the same for every axis), so every axis is within
//!   2⁻²⁹ steps of its point of the straight line through the two points,
//!   and every axis lands exactly on its target in the same tick (the
//!   profile lands exactly on `L`, where `λ` is exactly 1).
//! * **No axis exceeds its own limits.** The path's limits are the smallest
//!   of the requested path limits and, for every moving axis,
//!   `⌊limitᵢ · L / |dᵢ|⌋`: axis `i` moves at `|dᵢ| / L` of the path's speed,
//!   acceleration and deceleration, so it never exceeds its max speed,
//!   acceleration or deceleration (the most constrained axis sets the pace).
//!   The profile's own one-quantum minimum acceleration (2⁻³² steps/tick²)
//!   is the only exception, as for a single axis.
//! * **Integers.** Components are `i64` steps, the path parameter is the
//!   profile's `i128` in 2⁻³³ steps (below 2⁶⁵), `λ` below 2⁶²;
//!   `|dᵢ| ≤ 2³²` keeps every product below 2⁹⁵. A longer component is
//!   refused ([`CoordError::TooLong`]).

use super::profile::{round_fine, Limits, Profile, POS_FRAC};
use crate::powerstep::chain::MAX_DEVICES;

/// Axes in one coordinated move: a chain's most.
pub const MAX_AXES: usize = MAX_DEVICES;

/// Longest component of a coordinated move, steps (2³²).
pub const MAX_COMPONENT: u64 = 1 << 32;

/// Why a coordinated move, a junction or a look-ahead was not planned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CoordError {
    /// No axis named.
    NoAxes,
    /// More than [`MAX_AXES`] axes.
    TooManyAxes,
    /// Two lists that name the axes have different lengths.
    LengthMismatch,
    /// A component longer than [`MAX_COMPONENT`] steps.
    TooLong,
    /// The path cannot stop on its last waypoint from the speed it has now
    /// (a look-ahead asked too late, or faster than the first segment's max
    /// speed); the caller stops it as it can.
    CannotStop,
    /// The output of [`plan_speeds`] holds fewer than `segments + 1` speeds.
    OutputTooShort,
}

/// The distance of the axis that travels farthest, after the checks every
/// group passes: 1..=[`MAX_AXES`] axes, `others` of the same length, no
/// component over [`MAX_COMPONENT`].
fn checked_length(deltas: &[i64], others: &[usize]) -> Result<u64, CoordError> {
    let n = deltas.len();
    if n == 0 {
        return Err(CoordError::NoAxes);
    }
    if n > MAX_AXES {
        return Err(CoordError::TooManyAxes);
    }
    if others.iter().any(|&m| m != n) {
        return Err(CoordError::LengthMismatch);
    }
    let length = deltas.iter().map(|d| d.unsigned_abs()).max().unwrap_or(0);
    if length > MAX_COMPONENT {
        return Err(CoordError::TooLong);
    }
    Ok(length)
}

/// A coordinated move in progress (module doc).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Line {
    pub(super) n: usize,
    pub(super) start: [i64; MAX_AXES],
    pub(super) delta: [i64; MAX_AXES],
    /// Where each axis is beyond `start`, 2⁻³³ steps (|offset| ≤ ½ step:
    /// an axis held between two of its steps), shrunk to 0 along the line
    /// ([`Line::with_offsets`]).
    pub(super) offset: [i64; MAX_AXES],
    /// `(dₖ − offsetₖ) · 2⁶² / L`, toward zero (below 1.5 · 2⁶²): axis
    /// k's share of the path's velocity, in Q62.
    pub(super) ratio: [i64; MAX_AXES],
    /// `⌊2^(62 + z) / L⌋` for `2^(z − 1) ≤ L < 2^z` (0 for a line of no
    /// length): `s / L` in Q62 is `s · inv >> shift` ([`Line::lambda`]).
    pub(super) inv: u64,
    /// `33 + z`.
    pub(super) shift: u32,
    /// `L`, steps (0: nothing moves).
    pub(super) length: i64,
    pub(super) path: Profile,
}

/// `⌊limit · L / |d|⌋`, at most `u32::MAX` (the path limit axis `d` allows).
// Components ≤ 2³² (checked_length): the product fits u128.
#[allow(clippy::arithmetic_side_effects)]
fn scaled(limit: u32, length: u64, d: u64) -> u32 {
    if d == 0 {
        return u32::MAX;
    }
    let q = u128::from(limit.max(1)) * u128::from(length) / u128::from(d);
    u32::try_from(q).unwrap_or(u32::MAX)
}

/// The path's limits: `path` capped by every moving axis's scaled limits.
fn path_limits(deltas: &[i64], length: u64, limits: &[Limits], path: Limits) -> Limits {
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
/// allows in one tick of `tick_us`: with `u = d_in / L_in`,
/// `w = d_out / L_out` and the speed `v` on both sides, axis `i` jumps by
/// `v · |uᵢ − wᵢ|`, so `v ≤ minᵢ min(accᵢ, decᵢ) · tick / |uᵢ − wᵢ|`
/// (rounded down). A
/// chip sees one velocity per tick: a jump no larger than one tick's
/// acceleration is what it does between any two ticks anyway. `u32::MAX`
/// for a straight continuation (the segments' own limits cap it), 0 when
/// either segment has no length (a stop). (The rule of the path queue to
/// come; DECISIONS.md.)
// Components ≤ 2³² (checked_length): |aᵢ·L_out − bᵢ·L_in| < 2⁶⁵, and the
// numerator saturates.
#[allow(clippy::arithmetic_side_effects)]
pub fn junction_speed(
    d_in: &[i64],
    d_out: &[i64],
    limits: &[Limits],
    tick_us: u32,
) -> Result<u32, CoordError> {
    let l_in = u128::from(checked_length(d_in, &[d_out.len(), limits.len()])?);
    let l_out = u128::from(checked_length(d_out, &[])?);
    if l_in == 0 || l_out == 0 {
        return Ok(0);
    }
    let mut v = u32::MAX;
    for ((a, b), lim) in d_in.iter().zip(d_out).zip(limits) {
        let x = i128::from(*a) * l_out as i128 - i128::from(*b) * l_in as i128;
        let jump = x.unsigned_abs();
        if jump == 0 {
            continue;
        }
        let num = u128::from(lim.acc.max(1).min(lim.dec.max(1)))
            .saturating_mul(u128::from(tick_us))
            .saturating_mul(l_in)
            .saturating_mul(l_out);
        let q = num / jump.saturating_mul(1_000_000);
        v = v.min(u32::try_from(q).unwrap_or(u32::MAX));
    }
    Ok(v)
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

/// The speed reachable over `length` steps from `v` at `rate` steps/s²
/// (up or down, continuous kinematics: `√(v² + 2·rate·length)`), rounded
/// down and at most `u32::MAX`.
// Products of u32 and u64 values in u128: no overflow.
#[allow(clippy::arithmetic_side_effects)]
fn over(v: u32, rate: u32, length: u64) -> u32 {
    let v2 = u128::from(v) * u128::from(v);
    // rate < 2³², length < 2⁶⁴: below 2⁹⁷, and v² < 2⁶⁴.
    let s = u128::from(rate.max(1)) * u128::from(length) * 2;
    u32::try_from(v2.saturating_add(s).isqrt()).unwrap_or(u32::MAX)
}

/// The look-ahead: the speed at every waypoint of the queued `segments`,
/// starting at `speed` (the path's speed now, at the start of the first
/// segment), such that the path always stops on its last waypoint. Writes
/// `segments.len() + 1` speeds to the start of `out` (the first is `speed`,
/// the last 0). Each is the highest that (backward) still brakes to every
/// later waypoint's speed with each segment's deceleration and (forward) is
/// reached from the one before with its acceleration, and no waypoint is
/// faster than its junction or either segment's max speed. Continuous
/// kinematics, as grbl's planner; the tick-exact execution is the
/// profile's.
pub fn plan_speeds(speed: u32, segments: &[Segment], out: &mut [u32]) -> Result<(), CoordError> {
    let Some((first, rest)) = out
        .get_mut(..=segments.len())
        .and_then(|s| s.split_first_mut())
    else {
        return Err(CoordError::OutputTooShort);
    };
    // Backward, from rest at the last waypoint: rest[k] is the speed at the
    // end of segment k, capped by the junction after it and both segments'
    // max speeds; `later` the speed at the end of the segment being looked at.
    let mut later = 0u32;
    for (k, seg) in segments.iter().enumerate().rev() {
        let entry = over(later, seg.limits.dec, seg.length).min(seg.limits.max_speed.max(1));
        if let Some(end) = rest.get_mut(k) {
            *end = later;
        }
        later = match k.checked_sub(1).and_then(|j| segments.get(j)) {
            Some(before) => entry.min(seg.junction).min(before.limits.max_speed.max(1)),
            None => entry,
        };
    }
    // `later` is now the highest speed the path may have at its start.
    if speed > later {
        return Err(CoordError::CannotStop);
    }
    // Forward, from `speed`: as fast as each segment's acceleration allows.
    *first = speed;
    let mut now = speed;
    for (end, seg) in rest.iter_mut().zip(segments) {
        *end = (*end).min(over(now, seg.limits.acc, seg.length));
        now = *end;
    }
    Ok(())
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
        let offsets = [0i64; MAX_AXES];
        let offsets = offsets.get(..start.len()).unwrap_or(&offsets);
        Line::with_offsets(tick_us, start, offsets, target, limits, path)
    }

    /// [`Line::new`] for axes that are `offsets` (2⁻³³ steps, at most half
    /// a step either way, else [`CoordError::TooLong`]) beyond their
    /// `start`: axis `k` runs from `startₖ + offsetₖ` to its target, at
    /// `startₖ + offsetₖ · (1 − s/L) + dₖ · s/L` (an axis held between two
    /// of its steps starts where it is, without a jump, and lands exactly).
    /// Its limits are scaled by `|dₖ| + 1` where it has an offset: it may
    /// travel up to half a step more than `|dₖ|`.
    // L ≤ 2³² (checked_length) bounds z ≤ 33 and 62 + z ≤ 95; 33 + z ≤ 66.
    #[allow(clippy::arithmetic_side_effects)]
    pub fn with_offsets(
        tick_us: u32,
        start: &[i64],
        offsets: &[i64],
        target: &[i64],
        limits: &[Limits],
        path: Limits,
    ) -> Result<Line, CoordError> {
        const HALF: i64 = 1 << (POS_FRAC - 1);
        let mut s = [0i64; MAX_AXES];
        let mut delta = [0i64; MAX_AXES];
        let mut offset = [0i64; MAX_AXES];
        let mut spans = [0i64; MAX_AXES];
        if start.len() > MAX_AXES {
            return Err(CoordError::TooManyAxes);
        }
        if offsets.len() != start.len() {
            return Err(CoordError::LengthMismatch);
        }
        for (k, ((a, b), f)) in start.iter().zip(target).zip(offsets).enumerate() {
            if !(-HALF..=HALF).contains(f) {
                return Err(CoordError::TooLong);
            }
            let d = i128::from(*b).saturating_sub(i128::from(*a));
            // Beyond i64 is beyond MAX_COMPONENT: checked_length refuses it.
            let d = i64::try_from(d).unwrap_or(i64::MAX);
            let fields = (
                s.get_mut(k),
                delta.get_mut(k),
                offset.get_mut(k),
                spans.get_mut(k),
            );
            if let (Some(sk), Some(dk), Some(ok), Some(wk)) = fields {
                *sk = *a;
                *dk = d;
                *ok = *f;
                // (A magnitude: path_limits takes |span|.)
                *wk = if *f == 0 {
                    d
                } else {
                    d.saturating_abs().saturating_add(1)
                };
            }
        }
        let n = start.len();
        let deltas = delta.get(..n).unwrap_or(&[]);
        let length = checked_length(deltas, &[target.len(), limits.len()])?;
        let spans = spans.get(..n).unwrap_or(&[]);
        let mut profile = Profile::new(tick_us, path_limits(spans, length, limits, path));
        // s / L in Q62 by a multiply: a reciprocal normalised to L's bits
        // (2^(62 + z) / L with 2^(z − 1) ≤ L < 2^z: in (2⁶², 2⁶³]), so
        // λ = s · inv / 2^(33 + z) is at most one unit below ⌊s · 2⁶² / L⌋.
        let z = u64::BITS - length.leading_zeros();
        let inv = (1u128 << (62 + z))
            .checked_div(u128::from(length))
            .map_or(0, |q| u64::try_from(q).unwrap_or(u64::MAX));
        let mut ratio = [0i64; MAX_AXES];
        for ((r, d), o) in ratio.iter_mut().zip(deltas).zip(&offset) {
            // The distance axis k travels, 2⁻³³ steps: |dₖ · 2³³ − oₖ| ≤
            // 2⁶⁵ + 2³², so · 2²⁹ < 2⁹⁵; the quotient by L < 1.5 · 2⁶².
            let fine = (i128::from(*d) << POS_FRAC).saturating_sub(i128::from(*o));
            let q = (fine.unsigned_abs() << (62 - POS_FRAC))
                .checked_div(u128::from(length))
                .map_or(0, |q| i64::try_from(q).unwrap_or(i64::MAX));
            *r = if fine < 0 { q.wrapping_neg() } else { q };
        }
        // length ≤ 2³²: fits i64.
        let length = length as i64;
        profile.move_to(length);
        Ok(Line {
            n,
            start: s,
            delta,
            offset,
            ratio,
            inv,
            shift: POS_FRAC + z,
            length,
            path: profile,
        })
    }

    /// Axis `k`'s target (its start and component), `None` past the last
    /// axis.
    pub fn target(&self, k: usize) -> Option<i64> {
        let a = self.start.get(..self.n)?.get(k)?;
        a.checked_add(*self.delta.get(k)?)
    }

    /// Axes in the move.
    pub fn axes(&self) -> usize {
        self.n
    }

    /// The limits the shared profile runs with (module doc).
    pub fn path_limits(&self) -> Limits {
        self.path.limits()
    }

    /// The path parameter `s`, 2⁻³³ steps of the farthest axis.
    pub fn path_fine(&self) -> i128 {
        self.path.position_fine()
    }

    /// The path's velocity, 2⁻³² steps of the farthest axis per tick.
    pub fn path_velocity_internal(&self) -> i64 {
        self.path.velocity_internal()
    }

    /// Axis `k`'s position, nearest step (halves away from zero).
    pub fn position(&self, k: usize) -> Option<i64> {
        i64::try_from(round_fine(self.position_fine(k)?)).ok()
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
        assert_eq!(line_of(-(1 << 32)).map(|l| l.axes()), Ok(1));
        assert_eq!(line_of(-(1 << 32) - 1), Err(CoordError::TooLong));
    }

    fn line_of(d: i64) -> Result<Line, CoordError> {
        Line::new(1000, &[0], &[d], &[LIM], FAST)
    }

    #[test]
    fn a_straight_continuation_is_no_junction() {
        assert_eq!(
            junction_speed(&[100, 50], &[40, 20], &[LIM; 2], 1000),
            Ok(u32::MAX)
        );
    }

    #[test]
    fn a_right_angle_allows_one_tick_of_the_smaller_acceleration() {
        // X then Y: each axis's velocity jumps by v; 50 000 steps/s² · 1 ms.
        let slow = Limits { acc: 20_000, ..LIM };
        assert_eq!(
            junction_speed(&[100, 0], &[0, 300], &[LIM, slow], 1000),
            Ok(20)
        );
    }

    #[test]
    fn a_reversal_allows_half_a_tick_of_acceleration() {
        assert_eq!(junction_speed(&[100], &[-7], &[LIM], 1000), Ok(25));
    }

    #[test]
    fn a_zero_length_or_mismatched_segment_is_a_stop() {
        assert_eq!(junction_speed(&[0, 0], &[5, 5], &[LIM; 2], 1000), Ok(0));
        assert_eq!(
            junction_speed(&[1, 0], &[5], &[LIM; 2], 1000),
            Err(CoordError::LengthMismatch)
        );
        assert_eq!(junction_speed(&[], &[], &[], 1000), Err(CoordError::NoAxes));
    }

    #[test]
    fn a_single_segment_path_starts_at_its_speed_and_ends_at_rest() {
        let seg = Segment {
            length: 1000,
            limits: LIM,
            junction: u32::MAX,
        };
        let mut out = [7u32; 4];
        assert_eq!(plan_speeds(0, &[seg], &mut out), Ok(()));
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
        assert_eq!(plan_speeds(1000, &[seg], &mut out), Ok(()));
        assert_eq!(
            plan_speeds(1001, &[seg], &mut out),
            Err(CoordError::CannotStop)
        );
        assert_eq!(
            plan_speeds(0, &[seg], &mut [0u32; 1]),
            Err(CoordError::OutputTooShort)
        );
    }

    #[test]
    fn an_empty_path_only_plans_a_path_at_rest() {
        let mut out = [9u32; 1];
        assert_eq!(plan_speeds(0, &[], &mut out), Ok(()));
        assert_eq!(out, [0]);
        assert_eq!(plan_speeds(1, &[], &mut out), Err(CoordError::CannotStop));
    }

    #[test]
    fn past_the_last_axis_there_is_no_position() {
        let line = Line::new(1000, &[0], &[10], &[LIM], FAST).unwrap();
        assert_eq!(line.position(1), None);
    }
}
