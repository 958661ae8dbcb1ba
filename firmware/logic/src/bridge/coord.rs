//! The coordinated-move block of the extension space (0x08nn,
//! [`crate::ext_space::coord`]): the move's description as a master
//! writes it, its start and stop, and its state.

use super::{Bridge, Bus};
use crate::ext_space::{coord, ExtError};
use crate::motion::coord::CoordError;
use crate::motion::coordinated::AppendError;
use crate::motion::{AbortReason, AxisFault, CoordState, Limits, StartError};
use crate::postep60::settings::DriverMode;
use crate::powerstep::chain::{ChainBus, MAX_DEVICES};

/// The move as the block describes it (not persisted).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct CoordRegs {
    /// Bit k: chain axis k is a member.
    members: u8,
    /// Targets of chain axes 0..8, logical steps.
    targets: [i32; MAX_DEVICES],
    /// Path max speed, acceleration, deceleration (0 = none).
    path: [u32; 3],
    /// Why the last start or waypoint was refused ([`coord::REFUSAL`]).
    refusal: u16,
    /// The waypoint being written (chain axes 0..8; the last one queued
    /// once it is; the targets at a start).
    waypoint: [i32; MAX_DEVICES],
}

fn state_code(s: CoordState) -> u16 {
    match s {
        CoordState::Idle => 0,
        CoordState::Starting => 1,
        CoordState::Running => 2,
        CoordState::Stopping => 3,
        CoordState::Settling => 4,
        CoordState::Done => 5,
        CoordState::Aborted => 6,
    }
}

fn abort_code(abort: Option<(u8, AbortReason)>) -> u16 {
    let Some((k, why)) = abort else {
        return 0;
    };
    let reason = match why {
        AbortReason::Stopped => 1,
        AbortReason::MemberStopped => 2,
        AbortReason::Fault(AxisFault::Overcurrent) => 3,
        AbortReason::Fault(AxisFault::Thermal) => 4,
        AbortReason::Fault(AxisFault::ChipReset) => 5,
        AbortReason::Fault(AxisFault::ChainError) => 6,
    };
    u16::from(k) << 8 | reason
}

fn append_code(e: AppendError) -> u16 {
    match e {
        AppendError::Full => 5,
        AppendError::NotRunning => 6,
        AppendError::Line(_) => 4,
    }
}

fn refusal_code(e: StartError) -> u16 {
    match e {
        StartError::Busy => 1,
        StartError::BadAxis | StartError::Line(CoordError::NoAxes) => 2,
        StartError::NotReady(k) => u16::from(k) << 8 | 3,
        StartError::Line(_) => 4,
    }
}

/// `regs[at..at + 2] = v`, high word first.
fn put32(regs: &mut [u16], at: usize, v: u32) {
    if let Some(s) = regs.get_mut(at..at.saturating_add(2)) {
        s.copy_from_slice(&[(v >> 16) as u16, v as u16]);
    }
}

impl<B: ChainBus> Bridge<B> {
    /// The block as read now.
    pub(super) fn coord_block(&self) -> [u16; coord::LEN] {
        let mut r = [0u16; coord::LEN];
        let run = self.group.coord();
        let c = &self.coord;
        let words = [
            (coord::COMMAND, state_code(run.state())),
            (coord::ABORT, abort_code(run.abort())),
            (coord::MEMBERS, u16::from(c.members)),
            (coord::REFUSAL, c.refusal),
        ];
        for (at, v) in words {
            if let Some(slot) = r.get_mut(usize::from(at)) {
                *slot = v;
            }
        }
        for (i, v) in c.path.iter().enumerate() {
            put32(&mut r, word(coord::PATH_SPEED, i), *v);
        }
        put32(&mut r, usize::from(coord::TICKS), run.ticks());
        let queue = [
            (coord::QUEUE_FREE, run.queue_free() as u16),
            (
                coord::PASSED,
                u16::try_from(run.passed()).unwrap_or(u16::MAX),
            ),
        ];
        for (at, v) in queue {
            if let Some(slot) = r.get_mut(usize::from(at)) {
                *slot = v;
            }
        }
        for (k, t) in c.targets.iter().enumerate() {
            put32(&mut r, word(coord::TARGETS, k), *t as u32);
        }
        for (k, t) in c.waypoint.iter().enumerate() {
            put32(&mut r, word(coord::WAYPOINT, k), *t as u32);
        }
        r
    }

    /// A write of `data` at `offset` of the block: the description (not
    /// while a move is under way), or the command.
    pub(super) fn coord_write(&mut self, offset: u8, data: &[u16]) -> Result<(), ExtError> {
        let end = usize::from(offset).saturating_add(data.len());
        if data.is_empty() || end > coord::LEN {
            return Err(ExtError::IllegalAddress);
        }
        if offset >= coord::WAYPOINT {
            return self.coord_waypoint(offset, data);
        }
        if offset == coord::QUEUE {
            return match data {
                [1] => self.coord_queue(),
                [_] => Err(ExtError::IllegalValue),
                _ => Err(ExtError::IllegalAddress),
            };
        }
        if offset == coord::COMMAND {
            // One register: the description is written before it.
            return match data {
                [0] => {
                    self.group.coord_stop();
                    Ok(())
                }
                [1] => self.coord_start(),
                [_] => Err(ExtError::IllegalValue),
                _ => Err(ExtError::IllegalAddress),
            };
        }
        self.coord_describe(offset, data)
    }

    /// Registers `offset..` of the description written with `data`.
    fn coord_describe(&mut self, offset: u8, data: &[u16]) -> Result<(), ExtError> {
        if self.group.coord().is_active() {
            return Err(ExtError::Refused);
        }
        // Read-only: the state words and the tick count.
        let ro = |a: usize| {
            a == usize::from(coord::ABORT)
                || a == usize::from(coord::REFUSAL)
                || (usize::from(coord::TICKS)..usize::from(coord::TICKS) + 2).contains(&a)
                || (0x0C..usize::from(coord::TARGETS)).contains(&a)
        };
        let start = usize::from(offset);
        let range = start..start.saturating_add(data.len());
        if range.clone().any(ro) || range.end > usize::from(coord::WAYPOINT) {
            return Err(ExtError::IllegalAddress);
        }
        // Every 32-bit value whole.
        let pairs = usize::from(coord::PATH_SPEED)..usize::from(coord::TICKS);
        let targets = usize::from(coord::TARGETS)..coord::LEN;
        let split = |a: usize| (pairs.contains(&a) || targets.contains(&a)) && a % 2 == 1;
        if split(start) || split(range.end) {
            return Err(ExtError::IllegalAddress);
        }
        let mut regs = self.coord_block();
        let dst = regs.get_mut(range).ok_or(ExtError::IllegalAddress)?;
        dst.copy_from_slice(data);
        let members = regs.get(usize::from(coord::MEMBERS)).copied().unwrap_or(0);
        if members > 0xFF {
            return Err(ExtError::IllegalValue);
        }
        let get32 = |at: usize| -> u32 {
            match regs.get(at..at.saturating_add(2)) {
                Some([hi, lo]) => u32::from(*hi) << 16 | u32::from(*lo),
                _ => 0,
            }
        };
        let c = &mut self.coord;
        c.members = members as u8;
        for (i, p) in c.path.iter_mut().enumerate() {
            *p = get32(word(coord::PATH_SPEED, i));
        }
        for (k, t) in c.targets.iter_mut().enumerate() {
            *t = get32(word(coord::TARGETS, k)) as i32;
        }
        Ok(())
    }

    /// Start the move the block describes (members in position mode,
    /// awake, unfaulted, at rest).
    fn coord_start(&mut self) -> Result<(), ExtError> {
        if self.saving || self.run_mode == super::RunMode::Boot {
            return Err(ExtError::Refused);
        }
        let c = self.coord;
        let mut ids = [0usize; MAX_DEVICES];
        let mut targets = [0i64; MAX_DEVICES];
        let mut n = 0usize;
        let mut refused = None;
        for k in 0..MAX_DEVICES {
            if c.members & (1 << k) == 0 {
                continue;
            }
            let ready = self
                .devices
                .get(k)
                .map(|d| d.settings.mode == DriverMode::Position && d.can_move());
            match ready {
                None => refused = refused.or(Some(StartError::BadAxis)),
                Some(false) => refused = refused.or(Some(StartError::NotReady(k as u8))),
                Some(true) => {}
            }
            if let (Some(i), Some(t)) = (ids.get_mut(n), targets.get_mut(n)) {
                *i = k;
                *t = i64::from(c.targets.get(k).copied().unwrap_or(0));
            }
            n = n.saturating_add(1);
        }
        let path = Limits {
            max_speed: none_is_max(c.path[0]),
            acc: none_is_max(c.path[1]),
            dec: none_is_max(c.path[2]),
        };
        let result = match refused {
            Some(e) => Err(e),
            None => self.group.coord_start(
                ids.get(..n).unwrap_or(&[]),
                targets.get(..n).unwrap_or(&[]),
                path,
            ),
        };
        match result {
            Ok(()) => {
                self.coord.refusal = 0;
                self.coord.waypoint = c.targets;
                Ok(())
            }
            Err(e) => {
                self.coord.refusal = refusal_code(e);
                Err(ExtError::Refused)
            }
        }
    }

    /// A write of `data` at `offset` (at or after [`coord::WAYPOINT`]):
    /// pairs of the next waypoint (32-bit values whole), kept; a write that
    /// holds every running member's pair queues it at once (the block's
    /// doc), else [`coord::QUEUE`] does.
    fn coord_waypoint(&mut self, offset: u8, data: &[u16]) -> Result<(), ExtError> {
        let base = usize::from(coord::WAYPOINT);
        let start = usize::from(offset);
        let end = start.saturating_add(data.len());
        let odd = |a: usize| a.abs_diff(base) % 2 == 1;
        if odd(start) || odd(end) {
            return Err(ExtError::IllegalAddress);
        }
        let state = self.group.coord().state();
        if !matches!(state, CoordState::Starting | CoordState::Running) {
            self.coord.refusal = append_code(AppendError::NotRunning);
            return Err(ExtError::Refused);
        }
        let first_axis = start.saturating_sub(base) / 2;
        for (j, pair) in data.chunks(2).enumerate() {
            let v = match pair {
                [hi, lo] => (u32::from(*hi) << 16 | u32::from(*lo)) as i32,
                _ => return Err(ExtError::IllegalAddress),
            };
            if let Some(p) = self.coord.waypoint.get_mut(first_axis.saturating_add(j)) {
                *p = v;
            }
        }
        let members = self.group.coord().members();
        let (Some(&lo), Some(&hi)) = (members.first(), members.last()) else {
            return Ok(());
        };
        // Members are in chain order (the block's mask).
        let first = word(coord::WAYPOINT, usize::from(lo));
        let past = word(coord::WAYPOINT, usize::from(hi)).saturating_add(2);
        if start <= first && end >= past {
            self.coord_queue()
        } else {
            Ok(())
        }
    }

    /// Queue the waypoint written (its members' pairs) behind the move.
    fn coord_queue(&mut self) -> Result<(), ExtError> {
        let members = self.group.coord().members();
        let n = members.len();
        let mut targets = [0i64; MAX_DEVICES];
        for (t, &k) in targets.iter_mut().zip(members) {
            *t = i64::from(
                self.coord
                    .waypoint
                    .get(usize::from(k))
                    .copied()
                    .unwrap_or(0),
            );
        }
        let r = if n == 0 {
            Err(AppendError::NotRunning)
        } else {
            self.group.coord_append(targets.get(..n).unwrap_or(&[]))
        };
        match r {
            Ok(()) => {
                self.coord.refusal = 0;
                Ok(())
            }
            Err(e) => {
                self.coord.refusal = append_code(e);
                Err(ExtError::Refused)
            }
        }
    }

    /// After a write that came on `bus`: a move it started is that bus's
    /// for the communication watchdog (its members are the axes it moved).
    pub(super) fn coord_started_by(&mut self, bus: Bus) {
        let members = self.coord.members;
        for (k, m) in self.moved_by.iter_mut().enumerate() {
            if members & (1 << k) != 0 {
                *m = 1 << bus as u8;
            }
        }
    }
}

/// Register of the `i`-th 32-bit value from `base`.
fn word(base: u8, i: usize) -> usize {
    usize::from(base).saturating_add(i.saturating_mul(2))
}

fn none_is_max(v: u32) -> u32 {
    if v == 0 {
        u32::MAX
    } else {
        v
    }
}
