//! Coordinated moves, the pure parts: the shared profile of a straight-line
//! move of several axes ([`Line`]), the speed through a junction of two
//! segments ([`junction_speed`], [`path_junction`]), the look-ahead over
//! queued segments ([`PathQueue`]; [`plan_speeds`] is its continuous
//! reference) and a queued segment's precomputed geometry ([`Queued`]). A
//! [`Line`] and the path behind it run on the chips through
//! [`crate::motion::coordinated`] (extension 0x08nn).
//!
//! * **Paths.** Every queued segment's planned entry speed can be braked
//!   from, in the profile's own discrete kinematics, down to its end's
//!   planned speed within its length (less the travel of the tick that
//!   enters it), and the last waypoint's speed is 0: a path that is given
//!   nothing more stops exactly on its last waypoint. No segment is
//!   entered faster than its junction ([`path_junction`]) or either
//!   neighbour's max speed allows.
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

use super::profile::{
    acc_to_internal, braking_distance, round_fine, speed_to_internal, Limits, Profile, POS_FRAC,
};
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

/// Waypoints a group's path queue holds beyond the segment running.
pub const PATH_QUEUE: usize = 16;

/// A queued segment of a path: where it goes from the waypoint before it
/// (its geometry), its path limits, and the speed the look-ahead plans at
/// its start ([`PathQueue`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Queued {
    pub(super) delta: [i64; MAX_AXES],
    pub(super) ratio: [i64; MAX_AXES],
    pub(super) inv: u64,
    pub(super) shift: u32,
    /// `L`, steps of its farthest axis (≥ 1).
    pub(super) length: i64,
    /// Its path limits ([`Line`]'s rule for its own components), and them
    /// in the profile's units ([`Profile::internal_of`]).
    pub(super) limits: Limits,
    pub(super) internal: (i64, i64, i64),
    /// The deceleration of the segment before it, 2⁻³² steps/tick² (its
    /// own is `internal.2`).
    dec_before: i64,
    /// The highest speed at its start, 2⁻³² steps/tick: its junction's
    /// ([`path_junction`]) and both segments' max speeds.
    cap: i64,
    /// The speed planned at its start, 2⁻³² steps/tick ([`PathQueue`]).
    pub(super) entry: i64,
    /// Its junction's speed, path steps/s (for the status).
    pub(super) junction: u32,
}

const NO_SEGMENT: Queued = Queued {
    delta: [0; MAX_AXES],
    ratio: [0; MAX_AXES],
    inv: 0,
    shift: 0,
    length: 0,
    limits: Limits {
        max_speed: 1,
        acc: 1,
        dec: 1,
    },
    internal: (1, 1, 1),
    dec_before: 1,
    cap: 0,
    entry: 0,
    junction: 0,
};

/// The time whose worth of acceleration a path's junction may change an
/// axis's velocity by at once, µs ([`path_junction`]).
pub const JUNCTION_US: u32 = 500;

/// The speed through a path's junction: [`junction_speed`] over
/// [`JUNCTION_US`] instead of a tick, whatever the tick: no axis's velocity
/// jumps by more than half a millisecond of the smaller of its
/// acceleration and deceleration. Its chip follows the jump with its own
/// ramp (its ACC and DEC registers are the axis's limits) within 0.5 ms,
/// behind the line by at most `acc · (0.5 ms)² / 2` (0.025 steps at
/// 200 000 steps/s²), and the tick that crosses the junction changes the
/// velocity by that and the path's own change in the tick (at most one
/// tick of the axis's acceleration, by the segment's scaling). The same
/// corners at every tick rate. (`d_in`, `d_out` the segments' components,
/// `limits` the members'.)
pub fn path_junction(d_in: &[i64], d_out: &[i64], limits: &[Limits]) -> Result<u32, CoordError> {
    junction_speed(d_in, d_out, limits, JUNCTION_US)
}

/// The largest speed `v` (2⁻³² steps/tick) whose discrete braking distance
/// at `dec` is at most `room` (2⁻³³ steps): `D(v) ≤ v²/dec + dec/4`
/// (profile's module doc), so `v = ⌊√((room − ⌊dec/4⌋) · dec)⌋` never
/// needs more (and is within `dec²/8v + 1` of the largest).
fn top_speed(room: i128, dec: i64) -> i64 {
    let quarter = i128::from(dec.max(1) / 4);
    let Some(r) = room.checked_sub(quarter).filter(|r| *r > 0) else {
        return 0;
    };
    // A saturated product only lowers the speed.
    let p = (r as u128).saturating_mul(u128::from(dec.max(1).unsigned_abs()));
    i64::try_from(p.isqrt()).unwrap_or(i64::MAX)
}

impl Queued {
    /// The segment `delta` (each member's component) after a segment
    /// `before` (its components and path limits), for members with
    /// `limits` (as a [`Line`] scales them) and the group's `path` limits,
    /// ticked every `tick_us` µs. `Ok(None)` for a segment of no length.
    pub fn plan(
        tick_us: u32,
        before: (&[i64], Limits),
        delta: &[i64],
        limits: &[Limits],
        path: Limits,
    ) -> Result<Option<Queued>, CoordError> {
        let n = delta.len();
        let length = checked_length(delta, &[limits.len(), before.0.len()])?;
        if length == 0 {
            return Ok(None);
        }
        let own = path_limits(delta, length, limits, path);
        let junction = path_junction(before.0, delta, limits)?;
        let (ratio, inv, shift) = geometry(delta, &[], length);
        let mut d = [0i64; MAX_AXES];
        if let Some(dst) = d.get_mut(..n) {
            dst.copy_from_slice(delta);
        }
        let top = own.max_speed.min(before.1.max_speed).min(junction);
        Ok(Some(Queued {
            delta: d,
            ratio,
            inv,
            shift,
            // checked_length: ≤ 2³².
            length: length as i64,
            limits: own,
            internal: Profile::internal_of(tick_us, own),
            dec_before: acc_to_internal(before.1.dec.max(1), tick_us),
            cap: if top == 0 {
                0
            } else {
                speed_to_internal(top, tick_us)
            },
            entry: 0,
            junction,
        }))
    }

    /// Its junction's speed ([`path_junction`]), path steps/s.
    pub fn junction(&self) -> u32 {
        self.junction
    }

    /// The speed the look-ahead plans at its start, 2⁻³² steps/tick.
    pub fn entry(&self) -> i64 {
        self.entry
    }

    /// Its length, steps of its farthest axis.
    pub fn length(&self) -> i64 {
        self.length
    }

    /// The highest speed at the segment's start from which the path still
    /// leaves it at no more than `exit` (its end's planned speed), braking
    /// with its deceleration, however the tick that enters it falls: it
    /// enters up to `2·v + dec_before` past its start (one tick's travel
    /// from a speed at most one tick of braking above `v`). At most `cap`.
    // Bounded: length ≤ 2³² (· 2³³ < 2⁶⁶), braking distances below 2¹²⁷.
    #[allow(clippy::arithmetic_side_effects)]
    fn entry_speed(&self, exit: i64) -> i64 {
        let dec = self.internal.2;
        let room = (i128::from(self.length) << POS_FRAC) + braking_distance(exit, dec)
            - i128::from(self.dec_before);
        let first = top_speed(room, dec);
        let v = top_speed(room - 2 * i128::from(first), dec);
        v.min(self.cap)
    }
}

/// The segments queued behind the one a path runs (a ring of
/// [`PATH_QUEUE`]) with the look-ahead's speeds: every segment's planned
/// entry is the highest from which the path can still stop on the last
/// queued waypoint braking with each segment's deceleration, within every
/// junction's speed ([`path_junction`]) and each segment's max speed
/// (the backward pass of [`plan_speeds`], in the profile's own discrete
/// units and with a tick's margin at every junction). Appending can only
/// raise the planned speeds, so a path that could stop on its old last
/// waypoint can still meet the new plan; the pass stops at the first
/// segment whose speed does not change.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PathQueue {
    items: [Queued; PATH_QUEUE],
    head: usize,
    len: usize,
}

impl Default for PathQueue {
    fn default() -> PathQueue {
        PathQueue::new()
    }
}

impl PathQueue {
    pub const fn new() -> PathQueue {
        PathQueue {
            items: [NO_SEGMENT; PATH_QUEUE],
            head: 0,
            len: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Segments that can still be queued.
    pub fn free(&self) -> usize {
        PATH_QUEUE.saturating_sub(self.len)
    }

    pub fn clear(&mut self) {
        self.len = 0;
    }

    fn slot(&self, i: usize) -> usize {
        self.head.wrapping_add(i) % PATH_QUEUE
    }

    /// The `i`-th queued segment (0: the next to run).
    pub fn get(&self, i: usize) -> Option<&Queued> {
        if i >= self.len {
            return None;
        }
        self.items.get(self.slot(i))
    }

    /// The last queued segment.
    pub fn last(&self) -> Option<&Queued> {
        self.get(self.len.checked_sub(1)?)
    }

    /// Queue `q` behind the others and plan again; `false` (nothing
    /// queued) when the queue is full.
    pub fn push(&mut self, q: Queued) -> bool {
        if self.len >= PATH_QUEUE {
            return false;
        }
        let at = self.slot(self.len);
        if let Some(slot) = self.items.get_mut(at) {
            *slot = q;
        }
        self.len = self.len.saturating_add(1);
        self.plan();
        true
    }

    /// The next segment to run, out of the queue.
    pub fn pop(&mut self) -> Option<Queued> {
        let q = *self.get(0)?;
        self.head = self.slot(1);
        self.len = self.len.saturating_sub(1);
        Some(q)
    }

    /// The speed planned at the end of the segment running (the first
    /// queued one's entry; 0 with none queued), 2⁻³² steps/tick.
    pub fn exit_speed(&self) -> i64 {
        self.get(0).map_or(0, |q| q.entry)
    }

    /// The backward pass (the type's doc).
    fn plan(&mut self) {
        let mut exit = 0i64;
        for i in (0..self.len).rev() {
            let at = self.slot(i);
            let Some(q) = self.items.get_mut(at) else {
                break;
            };
            let entry = q.entry_speed(exit);
            if i.saturating_add(1) < self.len && entry == q.entry {
                break;
            }
            q.entry = entry;
            exit = entry;
        }
    }
}

/// A segment's shares of the path (module doc): `(dₖ − offsetₖ) · 2⁶² / L`
/// for every axis, toward zero, and `L`'s normalised reciprocal with its
/// shift (`s / L` in Q62 is `s · inv >> shift`).
// L ≤ 2³² (checked_length) bounds z ≤ 33 and 62 + z ≤ 95; 33 + z ≤ 66.
#[allow(clippy::arithmetic_side_effects)]
fn geometry(deltas: &[i64], offsets: &[i64], length: u64) -> ([i64; MAX_AXES], u64, u32) {
    // s / L in Q62 by a multiply: a reciprocal normalised to L's bits
    // (2^(62 + z) / L with 2^(z − 1) ≤ L < 2^z: in (2⁶², 2⁶³]), so
    // λ = s · inv / 2^(33 + z) is at most one unit below ⌊s · 2⁶² / L⌋.
    let z = u64::BITS - length.leading_zeros();
    let inv = (1u128 << (62 + z))
        .checked_div(u128::from(length))
        .map_or(0, |q| u64::try_from(q).unwrap_or(u64::MAX));
    let mut ratio = [0i64; MAX_AXES];
    for (k, (r, d)) in ratio.iter_mut().zip(deltas).enumerate() {
        let o = offsets.get(k).copied().unwrap_or(0);
        // The distance axis k travels, 2⁻³³ steps: |dₖ · 2³³ − oₖ| ≤
        // 2⁶⁵ + 2³², so · 2²⁹ < 2⁹⁵; the quotient by L < 1.5 · 2⁶².
        let fine = (i128::from(*d) << POS_FRAC).saturating_sub(i128::from(o));
        let q = (fine.unsigned_abs() << (62 - POS_FRAC))
            .checked_div(u128::from(length))
            .map_or(0, |q| i64::try_from(q).unwrap_or(i64::MAX));
        *r = if fine < 0 { q.wrapping_neg() } else { q };
    }
    (ratio, inv, POS_FRAC + z)
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
        let (ratio, inv, shift) = geometry(deltas, offset.get(..n).unwrap_or(&[]), length);
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
            shift,
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
    fn a_path_corner_allows_half_a_millisecond_of_acceleration_at_any_tick() {
        // X then Y: each axis's velocity jumps by v; 50 000 steps/s² · 0.5 ms.
        assert_eq!(path_junction(&[100, 0], &[0, 300], &[LIM; 2]), Ok(25));
        assert_eq!(
            path_junction(&[100, 50], &[40, 20], &[LIM; 2]),
            Ok(u32::MAX)
        );
    }

    #[test]
    fn the_top_speed_never_brakes_longer_than_its_room_and_is_near_the_largest() {
        for dec in [1i64, 3, 1000, 858_993_459, 1 << 40] {
            for room in [0i128, 1, 7, 1 << 20, 1 << 33, 1 << 50, 1 << 66] {
                let v = top_speed(room, dec);
                assert!(
                    braking_distance(v, dec) <= room,
                    "dec {dec} room {room}: {v}"
                );
                // Within dec²/8v + 1 of the largest: two more quanta (or one
                // more tick of dec for a slow one) brake longer.
                let slack = (i128::from(dec) * i128::from(dec) / (8 * i128::from(v.max(1))))
                    .min(i128::from(dec)) as i64;
                let more = v + 2 + slack;
                assert!(
                    braking_distance(more, dec) > room || more > (1 << 62),
                    "dec {dec} room {room}: {v} is not near the largest"
                );
            }
        }
    }

    fn segment(before: &[i64], delta: &[i64]) -> Queued {
        Queued::plan(1000, (before, LIM), delta, &[LIM; 2], FAST)
            .unwrap()
            .unwrap()
    }

    #[test]
    fn a_queue_plans_to_rest_on_its_last_waypoint_and_appending_only_raises_speeds() {
        let mut q = PathQueue::new();
        let a = segment(&[1000, 0], &[1000, 100]);
        assert!(q.push(a));
        // One segment: it ends at rest; its start as fast as its junction.
        let first = q.exit_speed();
        assert!(first > 0);
        assert_eq!(first, a.entry_speed(0));
        assert!(first <= a.cap);
        assert!(q.push(segment(&[1000, 100], &[1000, 200])));
        let second = q.exit_speed();
        assert!(second >= first, "{second} < {first}");
        assert_eq!(
            q.get(1).map(|s| s.entry),
            Some(q.get(1).unwrap().entry_speed(0))
        );
        assert_eq!(q.len(), 2);
        assert_eq!(q.free(), PATH_QUEUE - 2);
    }

    #[test]
    fn a_full_queue_takes_no_more_and_pops_in_order() {
        let mut q = PathQueue::new();
        for k in 0..PATH_QUEUE {
            let s = segment(&[10, 0], &[10, k as i64]);
            assert!(q.push(s));
        }
        assert!(!q.push(segment(&[10, 0], &[10, 0])));
        assert_eq!(q.free(), 0);
        for k in 0..PATH_QUEUE {
            assert_eq!(q.pop().map(|s| s.delta[1]), Some(k as i64));
        }
        assert_eq!(q.pop(), None);
        assert_eq!(q.exit_speed(), 0);
    }

    #[test]
    fn a_segment_of_no_length_queues_nothing_and_a_reversal_is_slow() {
        assert_eq!(
            Queued::plan(1000, (&[5, 5], LIM), &[0, 0], &[LIM; 2], FAST),
            Ok(None)
        );
        // Straight back: every axis's velocity flips, 2·v ≤ 25 steps/s.
        let back = segment(&[100, 0], &[-100, 0]);
        assert_eq!(back.junction(), 12);
    }

    #[test]
    fn past_the_last_axis_there_is_no_position() {
        let line = Line::new(1000, &[0], &[10], &[LIM], FAST).unwrap();
        assert_eq!(line.position(1), None);
    }
}
