//! The axis's commands: moves, runs, stops, Set zero, sleep and wake,
//! homing, register writes and reads, limits, step mode, chain errors.

use super::*;

impl Axis {
    // ------------------------------------------------------ motion commands

    /// Move to `target` logical steps (ignored while asleep or homing: the
    /// device layer refuses motion requests then).
    pub fn move_to(&mut self, target: i64) {
        if self.asleep || self.is_homing() {
            return;
        }
        self.fault = None;
        self.warm_start();
        self.profile.move_to(target);
    }
    /// Run at a signed speed (logical steps/s; ignored while asleep or homing).
    pub fn run_at(&mut self, steps_per_s: i32) {
        if self.asleep || self.is_homing() {
            return;
        }
        self.fault = None;
        self.warm_start();
        self.profile.run_at(steps_per_s);
    }

    /// Configure `reg` to hold `value` on the chip from now on, across chip
    /// resets. Registers that are written at any time (KVAL/TVAL, OCD_TH, …)
    /// go out in the next spare command slot; the others at the next setup.
    /// Returns false for the registers the motion layer owns (ABS_POS,
    /// STEP_MODE, MAX_SPEED, ACC, DEC) and the read-only ones.
    pub fn set_register(&mut self, reg: Register, value: u32) -> bool {
        use crate::powerstep::registers::Access;
        let owned_by_motion = matches!(
            reg,
            Register::AbsPos
                | Register::StepMode
                | Register::MaxSpeed
                | Register::Acc
                | Register::Dec
        );
        if owned_by_motion || reg.access() == Access::ReadOnly {
            return false;
        }
        self.image.set(reg, value);
        true
    }

    /// The phase currents as KVAL/TVAL register values: hold, and run (also
    /// used while accelerating and decelerating).
    pub fn set_currents(&mut self, hold: u32, run: u32) {
        self.image.set(Register::KvalHold, hold);
        self.image.set(Register::KvalRun, run);
        self.image.set(Register::KvalAcc, run);
        self.image.set(Register::KvalDec, run);
    }

    /// Switch the bridges off (PoStep60 sleep): stop at once, HardHiZ, hold
    /// the position where the chip stopped. Motion commands are ignored until
    /// [`Axis::wake`].
    pub fn sleep(&mut self) {
        if matches!(self.state, AxisState::Homing) {
            self.end_homing(HomingError::Aborted);
        }
        self.asleep = true;
        self.idle_command = None;
        self.profile.stop_now();
        self.stop_then(AfterStop::Hold, Command::HardHiZ);
    }

    /// Switch the bridges on again and hold (HardStop leaves HiZ without moving).
    pub fn wake(&mut self) {
        if self.asleep {
            self.asleep = false;
            self.idle_command = Some(Command::HardStop);
        }
    }

    /// Leave HiZ and hold the position (HardStop), e.g. once the hold
    /// current has been written. Ignored while asleep.
    pub fn energize(&mut self) {
        if !self.asleep {
            self.idle_command = Some(Command::HardStop);
        }
    }

    pub fn is_asleep(&self) -> bool {
        self.asleep
    }

    // --------------------------------------------------------------- homing

    /// Start homing (`super::homing`). The switch's NO/NC wiring is in
    /// `params`. Refused unless the axis rests, is configured and awake.
    pub fn start_homing(&mut self, params: HomingParams) -> Result<(), HomingError> {
        if !matches!(self.state, AxisState::Idle) || !self.profile.is_settled() || self.asleep {
            return Err(HomingError::NotReady);
        }
        let closed = self.rb.status.switch_closed();
        let pressed = closed != params.nc;
        self.homed = false;
        self.fault = None;
        // Nothing of the last move survives homing: the profile holds where
        // the chip is, and when homing ends (however it ends) the axis rests
        // where the chip stopped until a new motion command.
        self.profile.set_position_fine(self.chip_fine());
        self.profile_jumped();
        self.homing = Some(Homing::start(params, pressed, self.rb.chip_pos, self.tick));
        self.homing_out = [None, None];
        self.homing_ramps = true;
        self.state = AxisState::Homing;
        Ok(())
    }

    /// Homing's state (Idle if it never ran).
    pub fn homing_state(&self) -> HomingState {
        self.homing.map_or(HomingState::Idle, |h| h.state)
    }

    /// Position 0 is the home switch's edge.
    pub fn is_homed(&self) -> bool {
        self.homed
    }

    pub fn is_homing(&self) -> bool {
        matches!(self.state, AxisState::Homing)
    }

    /// End a running homing sequence with `e` (the caller stops the chip).
    pub(super) fn end_homing(&mut self, e: HomingError) {
        self.homing_out = [None, None];
        if let Some(h) = self.homing.as_mut() {
            if h.state.is_running() {
                // The release may already have re-based ABS_POS.
                if h.state == HomingState::Releasing {
                    self.absolute_read = true;
                }
                h.state = HomingState::Failed(e);
            }
        }
        // MIN_SPEED back to what the image says.
        self.image.touch(Register::MinSpeed);
    }

    // ------------------------------------------------- chip register reads

    /// The value of chip register `reg` for the extension space: `Some` once
    /// a GetParam asked for by an earlier call came back (within
    /// [`REGISTER_READ_FRESH_TICKS`]); `None` means "asked, try again after
    /// the next control tick". GetParam(STATUS) clears no latched flag.
    pub fn read_register(&mut self, reg: Register) -> Option<u32> {
        if let Some(r) = self.ext_read {
            if r.reg == reg {
                if let Some((v, at)) = r.value {
                    if self.tick.saturating_sub(at) <= REGISTER_READ_FRESH_TICKS {
                        self.ext_read = None;
                        return Some(v);
                    }
                } else {
                    return None;
                }
            }
        }
        self.ext_read = Some(RegRead {
            reg,
            index: None,
            value: None,
            lead: false,
        });
        None
    }

    /// Change the logical step mode. A moving axis stops at once; the
    /// position is re-expressed in the new unit from the chip's microstep
    /// (exactly when the new unit is not finer than a microstep, else the
    /// step at or below), the limits are re-clamped for the new unit and the
    /// chip's ramps are rewritten at the next start.
    pub fn set_logical_shift(&mut self, shift: u8) {
        let shift = shift.min(MAX_LOGICAL_SHIFT);
        if shift == self.cfg.logical_shift {
            return;
        }
        self.profile.stop_now();
        self.cfg.logical_shift = shift;
        self.memo.target = (0, 0);
        self.speed_div = Recalled::new(units::speed_divisor(self.cfg.tick_us, shift));
        if self.stop.zero {
            self.profile.set_position(0);
            self.profile_jumped();
        } else {
            // Exactly where the chip is, in the new unit.
            self.profile.set_position_fine(self.chip_fine());
            self.profile_jumped();
        }
        self.limits.backstop = (0, 0);
        if !matches!(self.state, AxisState::Setup(_) | AxisState::Idle) {
            self.stop_then(AfterStop::Hold, self.stop_command());
        }
        self.refresh_limits();
    }
    /// Decelerate to a stop with the profile's deceleration. An axis at rest,
    /// or already stopping at once, has nothing to do. A member of a
    /// coordinated move asks its group, which stops every member along the
    /// line.
    pub fn soft_stop(&mut self) {
        if self.soft_stop_for_group() {
            // A coordinated move's member: the group stops along its line.
            return;
        }
        if matches!(self.state, AxisState::Homing) {
            self.end_homing(HomingError::Aborted);
            self.stop_then(AfterStop::Hold, Command::SoftStop);
            return;
        }
        if matches!(self.state, AxisState::Stopping) && self.stop.after == AfterStop::Hold {
            self.profile.stop_now();
        } else if !self.profile.is_settled() {
            self.profile.soft_stop();
        }
    }
    /// Stop at once, no ramp (HardStop), and hold where the chip stopped
    /// (no landing move: after an end switch that could go back into it).
    /// An axis that is asleep stays in HiZ.
    pub fn stop_now(&mut self) {
        if matches!(self.state, AxisState::Homing) {
            self.end_homing(HomingError::Aborted);
        }
        self.profile.stop_now();
        self.stop_then(AfterStop::Hold, self.stop_command());
    }
    /// Stop at once and make the position where the chip stops zero. In
    /// effect at once: the position reads 0 and a target given from now on
    /// is in the new coordinates.
    pub fn set_zero(&mut self) {
        if matches!(self.state, AxisState::Homing) {
            self.end_homing(HomingError::Aborted);
        }
        self.homed = false;
        self.profile.set_position(0);
        if matches!(self.state, AxisState::Setup(_)) {
            // The setup writes ABS_POS = chip_pos at its end.
            self.rb.chip_pos = 0;
            self.rb.raw = None;
            return;
        }
        self.stop.zero = true;
        self.stop_then(AfterStop::Hold, self.stop_command());
    }

    /// HardStop holds the motor; asleep, the bridges must stay off.
    /// How a stop ends: bridges off while asleep or while the chip is off
    /// for an overcurrent or thermal shutdown (a HardStop would switch
    /// them on again), else holding.
    pub(super) fn stop_command(&self) -> Command {
        if self.asleep || self.chip_off_for_fault {
            Command::HardHiZ
        } else {
            Command::HardStop
        }
    }

    /// The chain failed this tick: the chip may have missed commands or be
    /// out of step. Stop the profile where the axis last was and run the chip
    /// setup again (HardHiZ, configuration, ABS_POS re-based to the axis
    /// position), then hold again unless asleep.
    pub fn on_chain_error(&mut self) {
        self.fault = Some(AxisFault::ChainError);
        // The failed batch's replies never come, nor those of a batch
        // planned behind it (the overlapped tick drops it unsent).
        self.rb.in_flight = InFlight::EMPTY;
        if matches!(self.state, AxisState::Homing) {
            self.end_homing(HomingError::Fault);
        }
        self.homed = false;
        self.restart_setup();
        if !self.asleep {
            self.idle_command = Some(Command::HardStop);
        }
    }

    /// New limits (logical units). Clamped to what the chip can follow in the
    /// current step mode; while the chip moves, higher ramps than it is
    /// programmed with wait for the next start from rest.
    pub fn set_limits(&mut self, limits: Limits) {
        self.limits.requested = limits;
        self.refresh_limits();
    }

    /// The limits the profile may use now (module doc).
    pub(super) fn effective_limits(&mut self) -> Limits {
        let shift = self.cfg.logical_shift;
        let mut l = units::clamp_to_chip(self.limits.requested, shift);
        let chip_may_move = !matches!(self.state, AxisState::Idle | AxisState::Setup(_));
        if chip_may_move {
            let (acc, dec) = self.ramp_capabilities();
            l.acc = l.acc.min(acc);
            l.dec = l.dec.min(dec);
        }
        l
    }

    /// The ACC and DEC registers a move's start writes ([`units::ramp_reg`]
    /// of the requested limits clamped to the chip), worked out again only
    /// when the limits or the step mode change.
    pub(super) fn start_regs(&mut self) -> (u32, u32) {
        let key = (self.limits.requested, self.cfg.logical_shift);
        if let Some((k, regs)) = self.memo.start {
            if k == key {
                return regs;
            }
        }
        let l = units::clamp_to_chip(key.0, key.1);
        let regs = (units::ramp_reg(l.acc, key.1), units::ramp_reg(l.dec, key.1));
        self.memo.start = Some((key, regs));
        regs
    }

    /// Work out at the request (a bus task, not the control tick) what the
    /// next move's start would otherwise work out in its tick: the ACC and
    /// DEC registers it writes, their ramp capabilities, the streaming
    /// limits' internal units, deceleration divisor, stop cap and MAX_SPEED
    /// backstop (every one a
    /// remembered pure function: nothing changes but how long the start's
    /// tick takes; 8 axes starting in one tick is the control tick's worst).
    pub(super) fn warm_start(&mut self) {
        let l = self.streaming_limits();
        self.profile.prepare_limits(l);
        if self.limits.backstop.0 != l.max_speed || self.limits.backstop.1 == 0 {
            self.set_backstop(l.max_speed);
        }
        let key = (l.dec, self.cfg.logical_shift, self.cfg.step);
        let known = self.memo.stop_cap == Some(key)
            || self.memo.other_stop_cap.is_some_and(|(k, _)| k == key);
        if !known {
            self.memo.other_stop_cap = Some((key, units::StopCap::new(key.0, key.1, key.2)));
        }
    }

    /// [`units::ramp_capability`] of the chip's ACC and DEC, worked out
    /// again only when they or the step mode change (every move start asks;
    /// the 128-bit arithmetic costs ~1 000 instructions).
    fn ramp_capabilities(&mut self) -> (u32, u32) {
        self.ramp_capabilities_of(self.limits.acc, self.limits.dec)
    }

    /// [`Axis::ramp_capabilities`] of ACC and DEC registers `acc`, `dec`.
    pub(super) fn ramp_capabilities_of(&mut self, acc: u32, dec: u32) -> (u32, u32) {
        let key = (acc, dec, self.cfg.logical_shift);
        if let Some((k, caps)) = self.memo.ramps {
            if k == key {
                return caps;
            }
        }
        let caps = (
            units::ramp_capability(key.0, key.2),
            units::ramp_capability(key.1, key.2),
        );
        self.memo.ramps = Some((key, caps));
        caps
    }

    pub(super) fn refresh_limits(&mut self) {
        let l = self.effective_limits();
        if l != self.profile.limits() {
            self.profile.set_limits(l);
        }
        // Worked out again only when its inputs change (as above).
        let key = (l.dec, self.cfg.logical_shift, self.cfg.step);
        if self.memo.stop_cap != Some(key) {
            let cap = match self.memo.other_stop_cap {
                Some((k, cap)) if k == key => cap,
                _ => units::StopCap::new(key.0, key.1, key.2),
            };
            self.memo.other_stop_cap = self.memo.stop_cap.map(|k| (k, self.stop_cap));
            self.stop_cap = cap;
            self.memo.stop_cap = Some(key);
        }
    }

    pub(super) fn stop_then(&mut self, after: AfterStop, cmd: Command) {
        if matches!(self.state, AxisState::Setup(_)) {
            // The chip is in HiZ and stopped; the setup's ABS_POS write
            // re-bases it to the axis position.
            return;
        }
        self.stop.after = after;
        self.stop.pending = Some(cmd);
        self.state = AxisState::Stopping;
    }

    /// Stop the profile where the chip is and set the chip up again.
    pub(super) fn restart_setup(&mut self) {
        if matches!(self.state, AxisState::Homing) {
            self.end_homing(HomingError::Fault);
        }
        self.homed = false;
        self.absolute_read = false;
        self.ext_read = None;
        if self.stop.zero {
            // An accepted Set zero stays in effect.
            self.rb.chip_pos = 0;
            self.stop.zero = false;
        }
        self.profile.set_position_fine(self.chip_fine());
        self.profile_jumped();
        self.rb.raw = None;
        self.rb.error = 0;
        self.rb.read = None;
        // What the batches in flight read predates the setup.
        self.rb.in_flight.drop_reads(None);
        self.stop.pending = None;
        self.limits.max_speed = 0;
        self.limits.acc = 0;
        self.limits.dec = 0;
        self.limits.backstop = (0, 0);
        self.image.on_reset();
        self.state = AxisState::Setup(phase::HIZ);
        self.rb.setup_at = self.tick + 1;
        self.refresh_limits();
    }
}
