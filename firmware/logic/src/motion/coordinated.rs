//! A coordinated move running: one [`Line`] led tick by tick through the
//! axes of a group ([`CoordRun`], kept by [`crate::motion::AxisGroup`]).
//!
//! # What it guarantees
//!
//! * **One start, one arrival.** Every member starts as any move from rest
//!   (its chip's ramps are written first), and the line waits, every
//!   member held where it is, until all of them stream: then the shared
//!   profile runs and every member's profile is set to its point of the
//!   line each tick ([`Axis::lead`]), so all of them start in the same tick
//!   and their profiles reach their targets in the same tick; each lands
//!   there exactly as a single move does (SoftStop, GoTo).
//! * **Within its limits.** The line's limits are each member's streaming
//!   limits scaled by its share ([`Line`]): no member is led faster, or
//!   with more acceleration or deceleration, than it could move alone.
//! * **Stops keep the line.** A stop of the group, or a soft stop asked of
//!   any member (a bus's SoftStop, the communication watchdog's soft stop),
//!   brakes the shared profile with the line's deceleration: every member
//!   stops on the line, and holds where its chip stops. A member that
//!   leaves the line at once — a Stop, an end switch, sleep, a fault, a
//!   chip reset, a chain error (or a command the bridge's members refuse:
//!   a move of its own, Set zero, a step-mode change) — stops every other
//!   member at once too (HardStop: as close to the line as the chips
//!   allow), and the group reports which member and why. Members with no
//!   distance to go are led where they are (the line waits only for the
//!   others to stream), and the same holds for them: their soft stop
//!   brakes the group, anything taking them off the line stops it at
//!   once; in a path they may move in a later segment. After any of them
//!   every member rests until a new motion command.
//! * **Paths.** Waypoints queued behind the move ([`CoordRun::append`])
//!   run on from its target without stopping where the look-ahead allows
//!   ([`crate::motion::coord::PathQueue`]): each segment's profile runs
//!   through its end at no more than the planned speed
//!   ([`Line::aim_at`]), and in the tick that crosses it the next
//!   segment takes over with the same path speed ([`Line::advance`]); the
//!   last waypoint is landed on exactly, as a line's target. A stop brakes
//!   on along the path, segment by segment, each with its own
//!   deceleration.

use super::axis::{Axis, AxisFault};
use super::coord::{CoordError, Line, PathQueue, Queued, MAX_AXES};
use super::divisor::mul_wide;
use super::profile::{braking_distance, round_fine, Limits, POS_FRAC};

/// Junctions one tick may pass at most (the queue's length and one).
const PATH_QUEUE_STEPS: usize = crate::motion::coord::PATH_QUEUE + 1;

/// No path limit of its own.
const ANY_PATH: Limits = Limits {
    max_speed: u32::MAX,
    acc: u32::MAX,
    dec: u32::MAX,
};

/// What a coordinated move is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CoordState {
    /// None started since boot.
    Idle,
    /// Members writing their ramps; the line waits for all of them.
    Starting,
    /// The line runs.
    Running,
    /// Braking along the line (a stop).
    Stopping,
    /// The line is over: members landing on their targets, or stopping.
    Settling,
    /// Every member landed on its target.
    Done,
    /// Stopped before the targets ([`CoordRun::abort`] says why).
    Aborted,
}

/// Why a coordinated move ended before its targets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AbortReason {
    /// The group's stop, or a soft stop asked of a member.
    Stopped,
    /// A member stopped at once on its own (a Stop, an end switch, sleep).
    MemberStopped,
    /// A member's chip failed: its fault.
    Fault(AxisFault),
}

/// Why a coordinated move was not started.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StartError {
    /// A move is running: stop it first.
    Busy,
    /// A member named twice or past the chain.
    BadAxis,
    /// This member is not at rest, asleep, homing, or off for a fault.
    NotReady(u8),
    /// The line itself (no axis, too many, a component too long).
    Line(CoordError),
}

/// Why a waypoint was not queued behind a coordinated move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AppendError {
    /// No move is starting or running (a path that has ended, or is
    /// stopping, takes no more waypoints: start a new move).
    NotRunning,
    /// The queue holds [`crate::motion::coord::PATH_QUEUE`] waypoints.
    Full,
    /// The segment itself (a target per member, no component too long).
    Line(CoordError),
}

/// The coordinated move of a group (at most one at a time).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CoordRun {
    state: CoordState,
    line: Option<Line>,
    /// Chain indices of the members, in the line's order.
    members: [u8; MAX_AXES],
    n: usize,
    /// Bit i: member i has distance to go in the first segment (the line
    /// waits until these stream; the others are led where they are). Every
    /// member follows the line when any has ([`CoordRun::moving_members`]).
    first: u8,
    abort: Option<(u8, AbortReason)>,
    /// Ticks the line has run.
    ticks: u32,
    /// The waypoints queued behind the segment running (a path).
    queue: PathQueue,
    /// The last waypoint: the targets of the last queued segment, or of
    /// the one running (line order).
    last: [i64; MAX_AXES],
    /// The path limits asked at the start (every segment's cap).
    path: Limits,
    /// Waypoints the path has passed.
    passed: u32,
}

impl Default for CoordRun {
    fn default() -> CoordRun {
        CoordRun::new()
    }
}

impl CoordRun {
    pub const fn new() -> CoordRun {
        CoordRun {
            state: CoordState::Idle,
            line: None,
            members: [0; MAX_AXES],
            n: 0,
            first: 0,
            abort: None,
            ticks: 0,
            queue: PathQueue::new(),
            last: [0; MAX_AXES],
            path: ANY_PATH,
            passed: 0,
        }
    }

    pub fn state(&self) -> CoordState {
        self.state
    }

    /// Which member ended the move early and why (`None` while it runs or
    /// when it arrived).
    pub fn abort(&self) -> Option<(u8, AbortReason)> {
        self.abort
    }

    /// Ticks the line has run (its duration once it is over).
    pub fn ticks(&self) -> u32 {
        self.ticks
    }

    /// The line running, or the last one.
    pub fn line(&self) -> Option<&Line> {
        self.line.as_ref()
    }

    /// The move is under way (starting, running, stopping or settling):
    /// its members take no motion command of their own.
    pub fn is_active(&self) -> bool {
        matches!(
            self.state,
            CoordState::Starting
                | CoordState::Running
                | CoordState::Stopping
                | CoordState::Settling
        )
    }

    /// Axis `k` (chain index) is a member of the move under way.
    pub fn is_member(&self, k: usize) -> bool {
        self.is_active() && self.member_list().iter().any(|&m| usize::from(m) == k)
    }

    fn member_list(&self) -> &[u8] {
        self.members.get(..self.n).unwrap_or(&[])
    }

    /// Start the move of the axes `members` (chain indices) to `targets`
    /// (each in its axis's logical steps), at most at the `path` limits
    /// (steps of the axis that travels farthest; `u32::MAX` for none).
    pub fn start(
        &mut self,
        axes: &mut [Axis],
        members: &[usize],
        targets: &[i64],
        path: Limits,
    ) -> Result<(), StartError> {
        if self.is_active() {
            return Err(StartError::Busy);
        }
        let n = members.len();
        if n == 0 {
            return Err(StartError::Line(CoordError::NoAxes));
        }
        if n > MAX_AXES {
            return Err(StartError::Line(CoordError::TooManyAxes));
        }
        if targets.len() != n {
            return Err(StartError::Line(CoordError::LengthMismatch));
        }
        let mut ids = [0u8; MAX_AXES];
        let mut starts = [0i64; MAX_AXES];
        let mut offsets = [0i64; MAX_AXES];
        let mut limits = [Limits {
            max_speed: 1,
            acc: 1,
            dec: 1,
        }; MAX_AXES];
        let mut tick_us = 1000;
        for (i, &k) in members.iter().enumerate() {
            let twice = members.get(..i).is_some_and(|m| m.contains(&k));
            let id = u8::try_from(k).map_err(|_| StartError::BadAxis)?;
            let axis = axes
                .get_mut(k)
                .filter(|_| !twice)
                .ok_or(StartError::BadAxis)?;
            if !axis.can_follow() {
                return Err(StartError::NotReady(id));
            }
            let fine = axis.profile().position_fine();
            let whole = round_fine(fine);
            let (Some(d), Some(s), Some(o), Some(l)) = (
                ids.get_mut(i),
                starts.get_mut(i),
                offsets.get_mut(i),
                limits.get_mut(i),
            ) else {
                return Err(StartError::Line(CoordError::TooManyAxes));
            };
            *d = id;
            *s = i64::try_from(whole).map_err(|_| StartError::Line(CoordError::TooLong))?;
            // Within half a step of the nearest one.
            *o = i64::try_from(fine.wrapping_sub(whole << POS_FRAC)).unwrap_or(0);
            *l = axis.streaming_limits();
            tick_us = axis.config().tick_us;
        }
        let (starts, offsets, limits) = (
            starts.get(..n).unwrap_or(&[]),
            offsets.get(..n).unwrap_or(&[]),
            limits.get(..n).unwrap_or(&[]),
        );
        let line = Line::with_offsets(tick_us, starts, offsets, targets, limits, path)
            .map_err(StartError::Line)?;
        // Members with distance to go; when any has, every member follows
        // the line (one with none is led where it is, and may move in a
        // later segment of a path); when none has, the move is done.
        let mut first = 0u8;
        for (i, ((&target, &s), &o)) in targets.iter().zip(starts).zip(offsets).enumerate() {
            if target != s || o != 0 {
                first |= 1 << i;
            }
        }
        if first != 0 {
            for (&k, &target) in members.iter().zip(targets) {
                if let Some(axis) = axes.get_mut(k) {
                    axis.follow(target);
                }
            }
        }
        let mut last = [0i64; MAX_AXES];
        if let Some(dst) = last.get_mut(..n) {
            dst.copy_from_slice(targets);
        }
        *self = CoordRun {
            state: if first == 0 {
                CoordState::Done
            } else {
                CoordState::Starting
            },
            line: Some(line),
            members: ids,
            n,
            first,
            abort: None,
            ticks: 0,
            queue: PathQueue::new(),
            last,
            path,
            passed: 0,
        };
        Ok(())
    }

    /// Queue a waypoint behind the move (a path): `targets`, one per
    /// member in the line's order, logical steps. The path runs on from
    /// the last waypoint to it without stopping where the look-ahead
    /// allows ([`PathQueue`]); a waypoint equal to the last one queues
    /// nothing. Only while the move starts or runs.
    pub fn append(&mut self, axes: &mut [Axis], targets: &[i64]) -> Result<(), AppendError> {
        if !matches!(self.state, CoordState::Starting | CoordState::Running) {
            return Err(AppendError::NotRunning);
        }
        if targets.len() != self.n {
            return Err(AppendError::Line(CoordError::LengthMismatch));
        }
        if self.queue.free() == 0 {
            return Err(AppendError::Full);
        }
        let mut delta = [0i64; MAX_AXES];
        let mut limits = [ANY_PATH; MAX_AXES];
        for (i, (&t, &k)) in targets.iter().zip(self.member_list()).enumerate() {
            let from = self.last.get(i).copied().unwrap_or(0);
            let d =
                i64::try_from(i128::from(t).saturating_sub(i128::from(from))).unwrap_or(i64::MAX);
            let axis = axes.get_mut(usize::from(k));
            if let (Some(dd), Some(l), Some(a)) = (delta.get_mut(i), limits.get_mut(i), axis) {
                *dd = d;
                *l = a.streaming_limits();
            }
        }
        let n = self.n;
        let Some(line) = self.line.as_ref() else {
            return Err(AppendError::NotRunning);
        };
        let tick_us = line.path.tick_us();
        let before = match self.queue.last() {
            Some(q) => (q.delta, q.limits),
            None => (line.delta, line.path_limits()),
        };
        let q = Queued::plan(
            tick_us,
            (before.0.get(..n).unwrap_or(&[]), before.1),
            delta.get(..n).unwrap_or(&[]),
            limits.get(..n).unwrap_or(&[]),
            self.path,
        )
        .map_err(AppendError::Line)?;
        let Some(q) = q else {
            return Ok(());
        };
        if !self.queue.push(q) {
            return Err(AppendError::Full);
        }
        if let Some(dst) = self.last.get_mut(..n) {
            dst.copy_from_slice(targets);
        }
        self.mark_through(axes);
        // The segment running now leaves at the new plan's speed.
        if self.state == CoordState::Running {
            self.aim();
        }
        Ok(())
    }

    /// Waypoints that can still be queued (0 when no move runs).
    pub fn queue_free(&self) -> usize {
        if matches!(self.state, CoordState::Starting | CoordState::Running) {
            self.queue.free()
        } else {
            0
        }
    }

    /// Waypoints the path has passed (without stopping on them).
    pub fn passed(&self) -> u32 {
        self.passed
    }

    /// The queue (the look-ahead's speeds).
    pub fn queue(&self) -> &PathQueue {
        &self.queue
    }

    /// The segment running ends at the speed the look-ahead plans for its
    /// end ([`Line::aim`]).
    fn aim(&mut self) {
        let exit = self.queue.exit_speed();
        if let Some(line) = self.line.as_mut() {
            line.aim(exit);
        }
    }

    /// After the tick: a path that reached its segment's end goes on to
    /// the next queued one (its members retargeted to the new waypoint; a
    /// stop brakes on along the path with each segment's deceleration).
    fn next_segments(&mut self, axes: &mut [Axis]) {
        // A tick passes at most one junction when the plan holds; the
        // bound keeps a tick's work bounded whatever happens.
        for _ in 0..PATH_QUEUE_STEPS {
            let at_end = self.line.as_ref().is_some_and(|l| l.at_end());
            if !at_end {
                return;
            }
            let Some(q) = self.queue.pop() else {
                return;
            };
            let exit = self.queue.exit_speed();
            let stopping = self.state == CoordState::Stopping;
            let Some(line) = self.line.as_mut() else {
                return;
            };
            line.advance(&q);
            line.path.remember_limits(q.limits, q.internal);
            if stopping {
                // Brake on with this segment's deceleration: its stop
                // point again (a lower deceleration may take it further).
                line.path.run_at(0);
                line.path.set_limits(q.limits);
                line.path.soft_stop();
            } else {
                line.aim_at(exit, q.internal.2);
                line.path.set_limits(q.limits);
            }
            self.passed = self.passed.saturating_add(1);
            for (i, k) in self.moving_members() {
                let target = self.line.as_ref().and_then(|l| l.target(i));
                if let (Some(a), Some(t)) = (axes.get_mut(k), target) {
                    a.retarget_lead(t);
                }
            }
            self.mark_through(axes);
        }
    }

    /// Tell the members whether the path goes on beyond the segment
    /// running (a waypoint queued) or stops at its end.
    fn mark_through(&self, axes: &mut [Axis]) {
        let through = self.queue.get(0).is_some();
        for (_, k) in self.moving_members() {
            if let Some(a) = axes.get_mut(k) {
                a.lead_through(through);
            }
        }
    }

    /// Stop along the line (the group's stop): the shared profile brakes
    /// with the line's deceleration. A move not yet started holds where it
    /// is.
    pub fn stop(&mut self, axes: &mut [Axis]) {
        self.stop_for(axes, None);
    }

    fn stop_for(&mut self, axes: &mut [Axis], by: Option<u8>) {
        match self.state {
            CoordState::Starting => {
                // Nothing has moved: every member holds where it is.
                self.queue.clear();
                self.abort = Some((by.unwrap_or(u8::MAX), AbortReason::Stopped));
                self.hold_all(axes);
                self.state = CoordState::Settling;
            }
            CoordState::Running => {
                self.abort = Some((by.unwrap_or(u8::MAX), AbortReason::Stopped));
                if let Some(l) = self.line.as_mut() {
                    l.stop();
                }
                self.state = CoordState::Stopping;
            }
            _ => {}
        }
    }

    /// Every moving member holds at its point of the line now.
    fn hold_all(&mut self, axes: &mut [Axis]) {
        let Some(line) = self.line.as_ref() else {
            return;
        };
        let lambda = line.lambda();
        for (i, k) in self.moving_members() {
            let pos = line.point(i, lambda).map(|(p, _)| p);
            if let (Some(axis), Some(pos)) = (axes.get_mut(k), pos) {
                axis.hold_led(pos);
            }
        }
    }

    /// (line index, chain index) of the members following the line: all
    /// of them, unless nothing moves.
    fn moving_members(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.members_in(if self.first == 0 { 0 } else { u8::MAX })
    }

    /// (line index, chain index) of the members whose bit `mask` has.
    fn members_in(&self, mask: u8) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.member_list()
            .iter()
            .enumerate()
            .filter(move |(i, _)| mask & (1 << i) != 0)
            .map(|(i, &k)| (i, usize::from(k)))
    }

    /// One control tick, before the axes plan: lead every member to its
    /// point of the line (module doc).
    pub fn step(&mut self, axes: &mut [Axis]) {
        match self.state {
            CoordState::Starting | CoordState::Running | CoordState::Stopping => {
                self.lead_step(axes)
            }
            CoordState::Settling => self.settle(axes),
            CoordState::Idle | CoordState::Done | CoordState::Aborted => {}
        }
    }

    /// The line is over: once every member rests (checked again after the
    /// axes planned, when a landing has just been confirmed), the move is
    /// done, or aborted if it was stopped or a member missed its target.
    pub fn settle(&mut self, axes: &[Axis]) {
        if self.state != CoordState::Settling {
            return;
        }
        let rest = self
            .member_list()
            .iter()
            .all(|&k| axes.get(usize::from(k)).is_none_or(|a| a.is_at_rest()));
        if !rest {
            return;
        }
        if self.abort.is_none() {
            self.abort = self.missed(axes);
        }
        self.state = if self.abort.is_some() {
            CoordState::Aborted
        } else {
            CoordState::Done
        };
    }

    fn lead_step(&mut self, axes: &mut [Axis]) {
        // A member that left the line stops the others at once.
        let left = self
            .moving_members()
            .find(|&(_, k)| axes.get(k).is_none_or(|a| !a.is_following()));
        if let Some((_, k)) = left {
            self.halt(axes, k);
            return;
        }
        let mut asked = None;
        for (_, k) in self.moving_members() {
            if let Some(a) = axes.get_mut(k) {
                if a.take_stop_request() && asked.is_none() {
                    asked = u8::try_from(k).ok();
                }
            }
        }
        if asked.is_some() {
            self.stop_for(axes, asked);
            if self.state == CoordState::Settling {
                return;
            }
        }
        if self.state == CoordState::Starting {
            let all = self
                .members_in(self.first)
                .all(|(_, k)| axes.get(k).is_some_and(|a| a.is_streaming()));
            if !all {
                // Held where they are until every member streams.
                self.lead_all(axes);
                return;
            }
            self.state = CoordState::Running;
            if !self.queue.is_empty() {
                self.aim();
            }
        }
        let Some(line) = self.line.as_mut() else {
            return;
        };
        line.tick();
        self.ticks = self.ticks.saturating_add(1);
        if !self.queue.is_empty() {
            self.next_segments(axes);
        }
        let Some(line) = self.line.as_ref() else {
            return;
        };
        let done = line.is_done();
        let on_last = self.queue.is_empty() && line.at_end();
        if done && self.state == CoordState::Stopping && !on_last {
            self.queue.clear();
            self.hold_all(axes);
            self.state = CoordState::Settling;
            return;
        }
        if done {
            // On the last waypoint (a stop whose braking point was exactly
            // there arrived too).
            self.abort = None;
        }
        self.lead_all(axes);
        if done {
            // Every member is on its target at rest: each lands by itself.
            for (_, k) in self.moving_members() {
                if let Some(a) = axes.get_mut(k) {
                    a.unlead();
                }
            }
            self.state = CoordState::Settling;
        }
    }

    /// Every moving member's setpoint for this tick: its point of the line.
    fn lead_all(&self, axes: &mut [Axis]) {
        let Some(line) = self.line.as_ref() else {
            return;
        };
        let lambda = line.lambda();
        for (i, k) in self.moving_members() {
            let Some((pos, vel)) = line.point(i, lambda) else {
                continue;
            };
            if let Some(a) = axes.get_mut(k) {
                a.lead(pos, vel);
            }
        }
    }

    /// Member `k` left the line: every other member stops at once.
    fn halt(&mut self, axes: &mut [Axis], k: usize) {
        self.queue.clear();
        let reason = match axes.get(k).and_then(|a| a.fault()) {
            Some(f) => AbortReason::Fault(f),
            None => AbortReason::MemberStopped,
        };
        self.abort = Some((u8::try_from(k).unwrap_or(u8::MAX), reason));
        for (_, j) in self.moving_members() {
            if let Some(a) = axes.get_mut(j) {
                if a.is_following() {
                    a.unlead();
                    a.stop_now();
                } else {
                    a.unlead();
                }
            }
        }
        self.state = CoordState::Settling;
    }

    /// The first moving member that did not end on its target (a fault or
    /// a stop while it landed), and why.
    fn missed(&self, axes: &[Axis]) -> Option<(u8, AbortReason)> {
        self.moving_members().find_map(|(i, k)| {
            let a = axes.get(k)?;
            let target = self.target(i)?;
            if a.required_position() == target {
                return None;
            }
            let reason = a
                .fault()
                .map_or(AbortReason::MemberStopped, AbortReason::Fault);
            Some((u8::try_from(k).unwrap_or(u8::MAX), reason))
        })
    }

    /// Member `i`'s target (line order).
    pub fn target(&self, i: usize) -> Option<i64> {
        self.line.as_ref()?.target(i)
    }

    /// The members' chain indices, in the line's order.
    pub fn members(&self) -> &[u8] {
        self.member_list()
    }
}

/// What a tick asks of a [`Line`] (here, not in `coord`, so that it runs
/// from SRAM with the rest of the tick while the line's planning stays in
/// flash: memory.x).
impl Line {
    /// Advance one tick.
    pub fn tick(&mut self) {
        self.path.tick();
    }

    /// Every axis on its target, at rest.
    pub fn is_done(&self) -> bool {
        self.path.is_settled()
    }

    /// How far along the line the path is, `s / L` in Q62 (2⁶² at the
    /// target, exactly): one multiply per tick, shared by every axis
    /// ([`Line::point`]).
    pub fn lambda(&self) -> u64 {
        let s = self.path.position_fine();
        let end = i128::from(self.length) << POS_FRAC;
        if s <= 0 && self.length != 0 {
            return 0;
        }
        if s >= end {
            return 1 << 62;
        }
        // 0 < s < L · 2³³ < 2^(33 + z) and inv ≤ 2^(62 + z) / L: the
        // product is below 2^(95 + z) ≤ 2¹²⁸ (z ≤ 33), the result below 2⁶².
        let s = s as u128;
        let lo = mul_wide(s as u64, self.inv);
        let hi = mul_wide((s >> 64) as u64, self.inv) << 64;
        (lo.wrapping_add(hi) >> self.shift) as u64
    }

    /// Axis `k`'s point of the line at `lambda` ([`Line::lambda`]): its
    /// position (2⁻³³ steps) and velocity (2⁻³² steps per tick, its share
    /// of the path's, never above it). Exact at both ends; in between
    /// within 2⁻²⁹ steps of `startₖ + offsetₖ · (1 − s/L) + dₖ · s/L`.
    /// `None` past the last axis.
    // |d| ≤ 2³², |offset| ≤ 2³², lambda ≤ 2⁶²: every product below 2⁹⁵.
    #[allow(clippy::arithmetic_side_effects)]
    pub fn point(&self, k: usize, lambda: u64) -> Option<(i128, i64)> {
        let (a, d) = (self.start.get(..self.n)?.get(k)?, self.delta.get(k)?);
        let o = self.offset.get(k).copied().unwrap_or(0);
        let r = self.ratio.get(k).copied().unwrap_or(0);
        let scaled = |x: i64, shift: u32| -> i128 {
            let m = (mul_wide(x.unsigned_abs(), lambda) >> shift) as i128;
            if x < 0 {
                -m
            } else {
                m
            }
        };
        // d · 2³³ · λ / 2⁶² and o · λ / 2⁶² (toward zero).
        let pos = (i128::from(*a) << POS_FRAC) + i128::from(o) - scaled(o, 62)
            + scaled(*d, 62 - POS_FRAC);
        let v = self.path.velocity_internal();
        let m = (mul_wide(v.unsigned_abs(), r.unsigned_abs()) >> 62) as i64;
        let vel = if (v < 0) != (r < 0) { -m } else { m };
        Some((pos, vel))
    }

    /// Run this segment's path to its end and leave it at no more than
    /// `exit` (2⁻³² steps/tick): through the end as to a stop the braking
    /// distance from `exit` beyond it, at deceleration `dec` (2⁻³²
    /// steps/tick², the one the profile brakes with), so the tick that
    /// crosses the end is at most at `exit` ([`Profile::move_through`]).
    /// To a stop on the end for `exit` 0.
    pub fn aim_at(&mut self, exit: i64, dec: i64) {
        let beyond = braking_distance(exit, dec);
        self.path.move_through(self.length, beyond);
    }

    /// [`Line::aim_at`] at the deceleration in use.
    pub fn aim(&mut self, exit: i64) {
        let (_, _, dec) = self.path.internal_limits();
        self.aim_at(exit, dec);
    }

    /// The path has reached (or passed) this segment's end.
    pub fn at_end(&self) -> bool {
        self.path.position_fine() >= i128::from(self.length) << POS_FRAC
    }

    /// Go on to segment `q` from this segment's end (the next waypoint is
    /// this one's target): the path's parameter carries what it ran beyond
    /// the end into `q`, its velocity unchanged (the same path speed on
    /// both sides, [`crate::motion::coord::path_junction`]). The profile's
    /// target and limits are the caller's to set next.
    pub fn advance(&mut self, q: &Queued) {
        let end = i128::from(self.length) << POS_FRAC;
        for k in 0..self.n.min(MAX_AXES) {
            if let (Some(a), Some(d), Some(o), Some(r)) = (
                self.start.get_mut(k),
                self.delta.get_mut(k),
                self.offset.get_mut(k),
                self.ratio.get_mut(k),
            ) {
                *a = a.saturating_add(*d);
                *d = q.delta.get(k).copied().unwrap_or(0);
                *o = 0;
                *r = q.ratio.get(k).copied().unwrap_or(0);
            }
        }
        self.inv = q.inv;
        self.shift = q.shift;
        self.length = q.length;
        self.path.shift_fine(end.wrapping_neg());
    }

    /// Decelerate along the line with the path's deceleration to a stop on
    /// the first whole path step at or beyond the braking point (every
    /// axis between two of its steps, on the line).
    pub fn stop(&mut self) {
        self.path.soft_stop();
    }

    /// Axis `k`'s position, 2⁻³³ steps ([`Line::point`]). `None` past the
    /// last axis.
    pub fn position_fine(&self, k: usize) -> Option<i128> {
        self.point(k, self.lambda()).map(|(p, _)| p)
    }

    /// Axis `k`'s velocity, 2⁻³² steps per tick ([`Line::point`]).
    pub fn velocity_internal(&self, k: usize) -> Option<i64> {
        self.point(k, self.lambda()).map(|(_, v)| v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ANY: Limits = Limits {
        max_speed: u32::MAX,
        acc: u32::MAX,
        dec: u32::MAX,
    };

    #[test]
    fn lambda_is_within_two_units_of_the_exact_quotient_for_any_length() {
        for length in [
            1i64,
            3,
            1000,
            100_000,
            (3 << 30) + 1,
            (1 << 32) - 1,
            1 << 32,
        ] {
            let mut line = Line::new(1000, &[0], &[length], &[ANY], ANY).unwrap();
            let end = u128::from(length as u64) << POS_FRAC;
            for s in [1u128, end / 3, end / 2, end - 1] {
                line.path.set_position_fine(s as i128);
                // ⌊s · 2⁶² / (L · 2³³)⌋ = ⌊s · 2²⁹ / L⌋.
                let exact = ((s << 29) / u128::from(length as u64)) as u64;
                let l = line.lambda();
                assert!(
                    l <= exact && exact - l <= 2,
                    "L {length}, s {s}: {l} for {exact}"
                );
            }
            line.path.set_position_fine(end as i128);
            assert_eq!(
                line.lambda(),
                1 << 62,
                "L {length}: exactly 1 at the target"
            );
        }
    }

    #[test]
    fn a_line_of_no_length_is_at_its_end() {
        let line = Line::new(1000, &[5], &[5], &[ANY], ANY).unwrap();
        assert_eq!(line.lambda(), 1 << 62);
    }
}
