//! The axis as a member of a coordinated move ([`crate::motion::coordinated`]):
//! its profile led tick by tick along the group's line instead of stepping
//! on its own, the stops that end the line, and how the group learns that
//! a member left it.

use super::*;

/// An axis led by a coordinated move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct LeadMark {
    /// The member's target on the line (logical steps).
    target: i64,
    /// The axis's tick at the last lead (a soft stop is the group's only
    /// while the group still leads: see [`Axis::soft_stop`]).
    at: u64,
    /// A soft stop asked of this member: the group stops along the line.
    stop_asked: bool,
    /// More of the path is queued behind `target`: the line runs through
    /// it rather than stopping on it (so the Run is not capped to stop
    /// there, [`Axis::cap_to_stop`]).
    through: bool,
}

impl Axis {
    /// The axis can join a coordinated move: configured, awake, at rest,
    /// not homing, its bridges not off for a fault.
    pub fn can_follow(&self) -> bool {
        self.is_at_rest() && !self.asleep && !self.chip_off_for_fault && self.lead.is_none()
    }

    /// The limits the axis streams a move with from rest (its requested
    /// limits clamped to the chip, and to what the ACC and DEC a start
    /// writes can follow): what a coordinated move scales the path by.
    pub fn streaming_limits(&mut self) -> Limits {
        let (acc, dec) = self.start_regs();
        let (cap_acc, cap_dec) = self.ramp_capabilities_of(acc, dec);
        let mut l = units::clamp_to_chip(self.limits.requested, self.cfg.logical_shift);
        l.acc = l.acc.min(cap_acc);
        l.dec = l.dec.min(cap_dec);
        l
    }

    /// Join a coordinated move to `target` (logical steps): the move starts
    /// as any move from rest (the chip's ramps first, then streaming), and
    /// every tick's setpoint is the group's ([`Axis::lead`]).
    pub fn follow(&mut self, target: i64) {
        self.fault = None;
        self.warm_start();
        self.profile.move_to(target);
        self.lead = Some(LeadMark {
            target,
            at: self.tick,
            stop_asked: false,
            through: false,
        });
    }

    /// Whether the group's path goes on beyond the member's target (a
    /// waypoint is queued behind it) or ends there.
    pub fn lead_through(&mut self, through: bool) {
        if let Some(m) = self.lead.as_mut() {
            m.through = through;
        }
    }

    /// The group's line runs through the target the profile moves to.
    pub(super) fn led_through(&self) -> bool {
        self.lead.is_some_and(|m| m.through)
    }

    /// The group's path went on to its next waypoint: the member's target
    /// on the line is now `target` (logical steps; where it lands if the
    /// path ends there).
    pub fn retarget_lead(&mut self, target: i64) {
        if let Some(m) = self.lead.as_mut() {
            m.target = target;
            self.profile.move_to(target);
        }
    }

    /// This tick's setpoint from the group: the profile ends the tick at
    /// `pos` (2⁻³³ logical steps) with velocity `vel` (2⁻³² steps/tick).
    pub fn lead(&mut self, pos: i128, vel: i64) {
        self.profile.lead(pos, vel);
        if let Some(m) = self.lead.as_mut() {
            m.at = self.tick;
        }
    }

    /// Still on the group's line: led, moving to the line's target, not
    /// stopped, reset or faulted since it joined. A member led to rest on its target (in a path, a segment in
    /// which it has no distance to go) lands there as a move does, and is
    /// still following: the next lead that moves it streams again.
    pub fn is_following(&self) -> bool {
        match self.lead {
            None => false,
            Some(m) => {
                let landing = match self.state {
                    AxisState::Idle | AxisState::Streaming | AxisState::Landing => true,
                    // The end-of-move soft stop before the landing's GoTo.
                    AxisState::Stopping => self.stop.after == AfterStop::Land,
                    _ => false,
                };
                self.profile.mode() == Mode::Position(m.target) && landing
            }
        }
    }

    /// The axis started streaming: the next lead moves its chip.
    pub fn is_streaming(&self) -> bool {
        matches!(self.state, AxisState::Streaming)
    }

    /// A soft stop was asked of this member since the last call.
    pub fn take_stop_request(&mut self) -> bool {
        self.lead
            .as_mut()
            .is_some_and(|m| core::mem::take(&mut m.stop_asked))
    }

    /// No longer led: the line has ended (the axis lands on its target by
    /// itself) or the group has stopped.
    pub fn unlead(&mut self) {
        self.lead = None;
    }

    /// The line stopped with the axis at `pos` (2⁻³³ logical steps, the
    /// last lead's, at rest): the chip stops (SoftStop from the little
    /// speed it has) and the axis holds where the chip stops.
    pub fn hold_led(&mut self, pos: i128) {
        self.lead = None;
        self.profile.set_position_fine(pos);
        self.stop_then(AfterStop::Hold, Command::SoftStop);
    }

    /// A soft stop of a member of a coordinated move the group still leads
    /// is the group's: true if taken that way.
    pub(super) fn soft_stop_for_group(&mut self) -> bool {
        let tick = self.tick;
        match self.lead.as_mut() {
            Some(m) if tick <= m.at.saturating_add(1) => {
                m.stop_asked = true;
                true
            }
            _ => false,
        }
    }
}
