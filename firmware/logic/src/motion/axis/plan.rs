//! One control tick's commands for the axis's chip ([`Axis::plan`]): the
//! read-back, the setup, streaming, stopping, landing, homing, and the
//! register writes the chip takes in the slots left.

use super::*;

impl Axis {
    // ------------------------------------------------------------ per tick

    /// The chip's position in the profile's units (2⁻³³ logical steps), exact.
    pub(super) fn chip_fine(&self) -> i128 {
        let s = i128::from(self.cfg.step.shift());
        let l = i128::from(self.cfg.logical_shift);
        // logical = physical · 2^(L−S)
        let shift = 33 + l - s;
        i128::from(self.rb.chip_pos) << shift
    }

    /// Physical microstep at or below the profile's exact position (the same
    /// rounding as [`logical_to_physical`], so an axis approaching a target
    /// between two microsteps from below never passes the one it lands on):
    /// where the chip should be now.
    pub fn profile_physical(&self) -> i64 {
        let fine = self.profile.position_fine();
        // fine is in 2⁻³³ logical steps; physical = logical · 2^(S−L)
        // (S ≤ 8 and L ≤ 8: 25 ≤ shift ≤ 41).
        let shift = 33 + u32::from(self.cfg.logical_shift) - self.cfg.step.shift();
        units::shr_i128_to_i64(fine, shift)
    }

    /// The profile jumped (re-based to where the chip is, or to 0): the
    /// reads in flight and this tick's measure no following error against
    /// the old profile; this tick's read expects the new one.
    pub(super) fn profile_jumped(&mut self) {
        self.rb.in_flight.void_expected();
        self.rb.expected_at_read = self.profile_physical();
    }

    pub(super) fn target_physical(&self) -> i64 {
        logical_to_physical(
            self.required_position(),
            self.cfg.logical_shift,
            self.cfg.step,
        )
    }

    /// Emit this tick's commands for the axis's chip (read-back first).
    /// `emit` returns false when the batch is full; the axis then retries next tick.
    #[inline]
    pub fn plan(&mut self, mut emit: impl FnMut(Command) -> bool) {
        self.plan_with(&mut emit);
    }

    /// [`Axis::plan`], one copy for every caller: the batch's loop and the
    /// plain tick's capture share it in SRAM, where the tick's code runs
    /// (SRAM the stack needs too).
    #[inline(never)]
    fn plan_with(&mut self, emit: &mut dyn FnMut(Command) -> bool) {
        let mut used = 0usize;
        let mut leaves_hiz = false;
        let mut counted = |cmd: Command| {
            let ok = emit(cmd);
            if ok {
                used += 1;
                leaves_hiz |=
                    cmd.is_motion() || matches!(cmd, Command::SoftStop | Command::HardStop);
            }
            ok
        };
        self.plan_commands(&mut counted);
        // (Almost every tick nothing is dirty and nothing is asked.)
        let spare_work = self.image.dirty() || self.ext_read.is_some();
        if spare_work && self.is_configured() {
            used = self.plan_spare_slots(used, leaves_hiz, emit);
        }
        let read = self.rb.read.take();
        self.record_batch(read, used > usize::from(read.is_some()));
    }

    /// The record of the batch this plan goes out in ([`InFlight`]): what
    /// it reads, whether it carries more, and what the plan knew.
    #[inline]
    fn record_batch(&mut self, read: Option<Read>, commands: bool) {
        let sent = self.rb.in_flight.push_slot();
        sent.tick = self.tick;
        sent.commands = commands;
        sent.read = read;
        sent.expected = self.rb.expected_at_read;
        sent.expected_valid = true;
        sent.commanded = self.rate.commanded;
        sent.epoch = self.rate.epoch;
    }

    /// The regular read of this tick: ABS_POS on even ticks, STATUS on odd
    /// ones.
    fn regular_read(&self) -> Read {
        if self.tick % 2 == 0 {
            Read::Position
        } else {
            Read::Status
        }
    }

    /// The slots `used` left: changed configuration registers, then an
    /// extension-space register read. The commands used after them.
    fn plan_spare_slots(
        &mut self,
        mut used: usize,
        leaves_hiz: bool,
        emit: &mut dyn FnMut(Command) -> bool,
    ) -> usize {
        // Spare slots carry configuration registers that changed, each only
        // when the chip takes it ([`Axis::chip_takes`]): nothing starts the
        // chip this tick for a WS one, nothing ends HiZ for a WH one. So the
        // chip never has to refuse one.
        let still = self.profile.is_settled();
        while used < MAX_COMMANDS {
            let Some((reg, value)) = self.image.next(|r| self.chip_takes(r, still, !leaves_hiz))
            else {
                break;
            };
            if !emit(Command::SetParam(reg, value)) {
                break;
            }
            self.image.written(reg);
            used += 1;
        }
        // An extension-space register read.
        if let Some(r) = self.ext_read.as_mut() {
            if r.value.is_none() && r.index.is_none() {
                let same_as_read =
                    r.reg == Register::AbsPos && self.rb.read == Some(Read::Position);
                if same_as_read {
                    // Waits for the next tick.
                } else if used < MAX_COMMANDS && emit(Command::GetParam(r.reg)) {
                    r.index = Some((self.tick, used));
                    used += 1;
                } else {
                    // No room beside the regular read: it takes the next
                    // position read's place.
                    r.lead = true;
                }
            }
        }
        used
    }

    /// A STATUS read after the last command shows the bridges off (HiZ)
    /// and the motor stopped.
    pub(super) fn hiz_confirmed(&self) -> bool {
        let s = self.rb.status;
        s.hiz() && !s.busy() && self.rb.status_at > self.rb.sent_at
    }

    /// Whether the chip takes a write of `reg` now, as far as its last
    /// STATUS shows: WR registers always; WH ones only in HiZ
    /// ([`Axis::hiz_confirmed`]) if the chip `stays_hiz` (nothing before the
    /// write in this tick ends HiZ); WS ones then too, or while the axis is
    /// idle (the chip was confirmed stopped), STATUS says not busy and the
    /// chip `stays_still` through the write.
    pub(super) fn chip_takes(&self, reg: Register, stays_still: bool, stays_hiz: bool) -> bool {
        use crate::powerstep::registers::Access;
        let hiz = stays_hiz && self.hiz_confirmed();
        let stopped =
            hiz || (matches!(self.state, AxisState::Idle) && stays_still && !self.rb.status.busy());
        match reg.access() {
            Access::Always => true,
            Access::WhenStopped => stopped,
            Access::WhenHiZ => hiz,
            Access::ReadOnly => false,
        }
    }

    /// Write, in the slots this tick has left, the registers the chip takes
    /// while it stays stopped (and in HiZ, if it is): before a move starts
    /// from rest or before the wake's HardStop, so that what was accepted
    /// for the chip reaches it before anything it could be refused after.
    /// True if any is still waiting for a slot.
    pub(super) fn write_before_leaving_rest(
        &mut self,
        emit: &mut impl FnMut(Command) -> bool,
    ) -> bool {
        while let Some((reg, value)) = self.image.next(|r| self.chip_takes(r, true, true)) {
            if !emit(Command::SetParam(reg, value)) {
                return true;
            }
            self.image.written(reg);
        }
        false
    }

    /// A WH register is waiting that the chip, still in HiZ as far as the
    /// bridge knows, could take before a wake ends HiZ: the wake waits for
    /// it (or for a STATUS after the last command that shows no HiZ).
    pub(super) fn hiz_write_waiting(&self) -> bool {
        use crate::powerstep::registers::Access;
        let s = self.rb.status;
        let hiz_disproved = self.rb.status_at > self.rb.sent_at && !s.hiz();
        !hiz_disproved && self.image.next(|r| r.access() == Access::WhenHiZ).is_some()
    }

    pub(super) fn plan_commands(&mut self, mut emit: impl FnMut(Command) -> bool) {
        self.tick = self.tick.wrapping_add(1);
        self.rate_tick();
        self.plan_read(&mut emit);
        // In HiZ, what was accepted for the chip (a WH register written while
        // asleep) goes out before anything that ends HiZ — a wake, a stop, a
        // move. Not in a setup (it writes everything) or homing (its phase
        // commands need the slots; homing never starts in HiZ).
        let flush = !matches!(self.state, AxisState::Setup(_) | AxisState::Homing);
        if flush && self.hiz_confirmed() && self.write_before_leaving_rest(&mut emit) {
            return;
        }
        self.rb.expected_at_read = self.profile_physical();

        match self.state {
            AxisState::Setup(k) => self.plan_setup(k, &mut emit),
            AxisState::Idle if !self.profile.is_settled() => self.start_from_rest(&mut emit),
            AxisState::Landing if !self.profile.is_settled() => {
                // The chip is still busy: it keeps its ramps.
                self.start_streaming(&mut emit);
            }
            AxisState::Streaming => self.stream(&mut emit),
            AxisState::Stopping => self.plan_stopping(&mut emit),
            AxisState::Homing => self.plan_homing(&mut emit),
            AxisState::Landing => {
                if self.confirmed_stopped() {
                    if self.rb.chip_pos == self.target_physical() {
                        self.state = AxisState::Idle;
                    } else {
                        // Refused (CMD_ERROR) or disturbed: land again.
                        self.land(&mut emit);
                    }
                }
            }
            AxisState::Idle => self.plan_idle(&mut emit),
        }
    }

    /// The tick that just ended ran at the last Run's speed: the clock-rate
    /// estimate counts it (not while the chip's MAX_SPEED caps it: SPEED =
    /// MAX_SPEED · 2¹⁰).
    pub(super) fn rate_tick(&mut self) {
        let capped = self.rate.running.unsigned_abs() >= u64::from(self.limits.max_speed) << 10;
        if matches!(self.state, AxisState::Streaming) && self.rate.steady && !capped {
            self.rate.commanded = self.rate.commanded.wrapping_add(self.rate.running);
        } else {
            self.rate.disarm_tick();
        }
    }

    /// The read-back, first in every tick: ABS_POS on even ticks, STATUS on
    /// odd ones.
    pub(super) fn plan_read(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        let read = self.regular_read();
        // An extension-space read that found no room beside the regular
        // read goes in a position read's place (never a STATUS read's: it
        // sees faults and switches); a read of ABS_POS is both.
        if let Some(r) = self.ext_read.as_mut() {
            let waiting = r.lead && r.value.is_none() && r.index.is_none();
            if waiting && read == Read::Position {
                let reg = r.reg;
                if emit(Command::GetParam(reg)) {
                    r.index = Some((self.tick, 0));
                    r.lead = false;
                    self.rb.read = (reg == Register::AbsPos).then_some(Read::Position);
                } else {
                    self.rb.read = None;
                }
                return;
            }
        }
        let read_cmd = match read {
            Read::Position => Command::GetParam(Register::AbsPos),
            Read::Status => Command::GetStatus,
        };
        self.rb.read = if emit(read_cmd) { Some(read) } else { None };
        if self.rb.read == Some(Read::Status) {
            self.image.status_requested();
        }
    }

    /// A new motion from rest: first what the chip takes only at rest (e.g.
    /// MIN_SPEED put back after homing), then the chip's ramps, then stream.
    pub(super) fn start_from_rest(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        if self.write_before_leaving_rest(emit) {
            return;
        }
        let (acc, dec) = self.start_regs();
        // Only what differs (a batch with little room takes one a tick);
        // streaming starts at the tick after them.
        let mut wrote = false;
        if acc != self.limits.acc {
            if !emit(Command::SetParam(Register::Acc, acc)) {
                return;
            }
            self.limits.acc = acc;
            wrote = true;
        }
        if dec != self.limits.dec {
            if emit(Command::SetParam(Register::Dec, dec)) {
                self.limits.dec = dec;
            }
            return;
        }
        if !wrote {
            self.start_streaming(emit);
        }
    }

    /// At rest: energize (or wake) only once the changed currents are out,
    /// and a WH register accepted while asleep before the wake's HardStop
    /// ends HiZ (the spare slots write them); an asleep chip found out of
    /// HiZ is put back.
    pub(super) fn plan_idle(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        use crate::powerstep::registers::Access;
        let fresh = self.rb.status_at > self.rb.sent_at;
        if self.asleep && fresh && !self.rb.status.hiz() {
            // Asleep means bridges off: a chip found out of HiZ (a command
            // it was never sent) is put back.
            if emit(Command::HardHiZ) {
                self.rb.sent_at = self.tick;
            }
            return;
        }
        let currents = self.image.next(|r| r.access() == Access::Always).is_some();
        if !currents && !self.hiz_write_waiting() {
            if let Some(cmd) = self.idle_command.take() {
                if emit(cmd) {
                    self.rb.sent_at = self.tick;
                } else {
                    self.idle_command = Some(cmd);
                }
            }
        }
    }

    /// One tick of the setup: as many of its writes as the slots allow.
    pub(super) fn plan_setup(&mut self, mut k: u8, emit: &mut impl FnMut(Command) -> bool) {
        loop {
            let cmd = match k {
                phase::HIZ => Command::HardHiZ,
                phase::IMAGE => match self.image.next(|_| true) {
                    Some((reg, value)) => Command::SetParam(reg, value),
                    None => {
                        k = phase::MAX_SPEED;
                        continue;
                    }
                },
                phase::MAX_SPEED => {
                    let v = self.profile.limits().max_speed;
                    Command::SetParam(
                        Register::MaxSpeed,
                        units::backstop_reg(v, self.cfg.logical_shift),
                    )
                }
                phase::ACC => Command::SetParam(
                    Register::Acc,
                    units::ramp_reg(self.profile.limits().acc, self.cfg.logical_shift),
                ),
                phase::DEC => Command::SetParam(
                    Register::Dec,
                    units::ramp_reg(self.profile.limits().dec, self.cfg.logical_shift),
                ),
                _ => Command::SetParam(Register::AbsPos, wrap_22(self.rb.chip_pos as i32)),
            };
            if !emit(cmd) {
                break;
            }
            match cmd {
                // A WH write later in this setup needs a STATUS after it.
                Command::HardHiZ => self.rb.sent_at = self.tick,
                Command::SetParam(Register::MaxSpeed, v) => self.limits.max_speed = v,
                Command::SetParam(Register::Acc, v) => self.limits.acc = v,
                Command::SetParam(Register::Dec, v) => self.limits.dec = v,
                Command::SetParam(Register::AbsPos, _) => self.discard_position_read(),
                Command::SetParam(reg, _) if k == phase::IMAGE => self.image.written(reg),
                _ => {}
            }
            if k == phase::ABS_POS {
                self.state = AxisState::Idle;
                self.rb.raw = None;
                self.refresh_limits();
                return;
            }
            if k != phase::IMAGE {
                k += 1;
            }
        }
        self.state = AxisState::Setup(k);
    }

    /// A position read that went out in this batch before a write of
    /// ABS_POS predates it: drop it.
    pub(super) fn discard_position_read(&mut self) {
        if self.rb.read == Some(Read::Position) {
            self.rb.read = None;
        }
        // And those of the batches still in flight (the overlapped tick):
        // their replies come after this write is planned.
        self.rb.in_flight.drop_reads(Some(Read::Position));
    }

    pub(super) fn start_streaming(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        self.state = AxisState::Streaming;
        self.refresh_limits();
        self.stream(emit);
    }

    pub(super) fn plan_stopping(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        if let Some(cmd) = self.stop.pending {
            if emit(cmd) {
                self.stop.pending = None;
                self.rb.sent_at = self.tick;
            }
            return;
        }
        let may_stream = self.stop.after == AfterStop::Land && !self.asleep;
        if may_stream && !self.profile.is_settled() {
            // A new target during the end-of-move soft stop: go on at once.
            self.start_streaming(emit);
            return;
        }
        if !self.confirmed_stopped() {
            return;
        }
        if self.stop.zero {
            if !emit(Command::ResetPos) {
                return;
            }
            self.discard_position_read();
            self.stop.zero = false;
            self.rb.chip_pos = 0;
            self.rb.raw = None;
            self.rb.error = 0;
            // Keep whatever was asked for since Set zero, in the new coordinates.
            self.profile.rebase_fine(0);
            self.profile_jumped();
        } else if self.stop.after == AfterStop::Hold {
            // Exactly where the chip is, even between two logical steps: the
            // next move (maybe given while stopping) starts from there.
            self.profile.rebase_fine(self.chip_fine());
            self.profile_jumped();
            self.rb.error = 0;
        }
        match self.stop.after {
            AfterStop::Hold => {
                self.state = AxisState::Idle;
                self.refresh_limits();
            }
            AfterStop::Land => {
                if self.profile.mode() == Mode::Hold {
                    // Defensive: hold on the step the chip reached.
                    self.profile.set_position_fine(self.chip_fine());
                    self.profile_jumped();
                }
                self.land(emit);
            }
        }
    }

    pub(super) fn plan_homing(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        let Some(mut h) = self.homing else {
            self.state = AxisState::Idle;
            return;
        };
        if self.homing_ramps {
            // The chip runs the search and release ramps itself: ACC and DEC
            // are the axis's limits (no streaming headroom). WS registers;
            // the chip rests (homing starts only from rest).
            let l = units::clamp_to_chip(self.limits.requested, self.cfg.logical_shift);
            let acc = units::chip_ramp_reg(l.acc, self.cfg.logical_shift);
            let dec = units::chip_ramp_reg(l.dec, self.cfg.logical_shift);
            // Each only once it has gone out (a batch with little room
            // takes one a tick).
            if acc != self.limits.acc && emit(Command::SetParam(Register::Acc, acc)) {
                self.limits.acc = acc;
            }
            if acc == self.limits.acc
                && (dec == self.limits.dec || emit(Command::SetParam(Register::Dec, dec)))
            {
                self.limits.dec = dec;
                self.homing_ramps = false;
            }
            return;
        }
        // The rest of a phase's commands first (nothing else until they
        // are out).
        if self.homing_out.iter().any(Option::is_some) {
            self.flush_homing(emit);
            return;
        }
        let s = self.rb.status;
        let seen = Seen {
            busy: s.busy(),
            pressed: s.switch_closed() != h.params.nc,
            fresh: self.rb.status_at > self.rb.sent_at && self.rb.pos_at > self.rb.status_at,
            pos: self.rb.pos_at_status,
        };
        let step = h.step(seen, self.rb.chip_pos, self.tick);
        self.homing = Some(h);
        match step {
            Step::Wait => {}
            Step::Send(cmds) => {
                self.homing_out = cmds;
                self.flush_homing(emit);
            }
            Step::Finished => {
                // The chip rests on the home frame: hold there, exactly
                // (the next position read is taken as it is), MIN_SPEED
                // back to the image's value.
                self.homed = true;
                self.absolute_read = true;
                self.image.touch(Register::MinSpeed);
                self.stop.after = AfterStop::Hold;
                self.stop.pending = None;
                self.rb.sent_at = self.tick;
                self.state = AxisState::Stopping;
            }
            Step::Fail(e) => {
                self.end_homing(e);
                self.stop_then(AfterStop::Hold, Command::SoftStop);
            }
        }
    }

    /// Send what is left of a homing phase's commands, in order, as far as
    /// the batch takes them.
    pub(super) fn flush_homing(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        let mut sent = false;
        for slot in self.homing_out.iter_mut() {
            if let Some(cmd) = *slot {
                if !emit(cmd) {
                    break;
                }
                *slot = None;
                sent = true;
            }
        }
        if sent {
            self.rb.sent_at = self.tick;
        }
    }

    /// GoTo the target. The chip takes the shortest path modulo 2²², which is
    /// the right one because the residual at landing is a few microsteps.
    pub(super) fn land(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        let target = self.target_physical();
        if emit(Command::GoTo(sign_extend_22(wrap_22(target as i32)))) {
            self.rb.sent_at = self.tick;
            self.state = AxisState::Landing;
        }
    }

    /// A STATUS read after the last one-shot command says not busy, and a
    /// position read came after it.
    pub(super) fn confirmed_stopped(&self) -> bool {
        self.rb.status_at > self.rb.sent_at
            && self.rb.pos_at > self.rb.status_at
            && !self.rb.status.busy()
    }

    pub(super) fn stream(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        let before = self.profile_step().unsigned_abs();
        // MAX_SPEED backstop: raised at once when the profile needs more; lowered
        // to the new max speed only once the profile has slowed down to it (a
        // lower max speed mid-move is reached with the profile's DEC, not the chip's).
        let shift = self.cfg.logical_shift;
        let vmax = self.profile.internal_limits().0.unsigned_abs();
        let now = before.max(self.profile.velocity_internal().unsigned_abs());
        let max_speed = self.profile.limits().max_speed;
        if self.limits.backstop.0 != max_speed || self.limits.backstop.1 == 0 {
            self.set_backstop(max_speed);
        }
        let need = if now > vmax {
            let v = crate::motion::profile::speed_from_internal(now as i64, self.cfg.tick_us);
            units::backstop_reg(v.clamp(0, i64::from(u32::MAX)) as u32, shift)
        } else {
            self.limits.backstop.1
        };
        let change = need > self.limits.max_speed || (now <= vmax && need != self.limits.max_speed);
        if change && emit(Command::SetParam(Register::MaxSpeed, need)) {
            self.limits.max_speed = need;
        }
        if self.profile.is_settled() {
            let sent = emit(Command::SoftStop);
            self.end_move(sent);
            return;
        }
        let (dir, mag) = self.run_speed();
        if emit(Command::Run(dir, mag)) {
            self.rate.running = signed_speed(dir, mag);
        }
    }

    /// The MAX_SPEED backstop for profile max speed `v`.
    pub(super) fn set_backstop(&mut self, v: u32) {
        self.limits.backstop = (v, units::backstop_reg(v, self.cfg.logical_shift));
    }

    /// The profile's tick of a streaming axis; the speed before it.
    #[inline(always)]
    fn profile_step(&mut self) -> i64 {
        let v0 = self.profile.velocity_internal();
        self.profile.tick();
        self.rate.steady = self.profile.velocity_internal() == v0;
        v0
    }

    /// The profile has settled on the target: the chip stops (its SoftStop
    /// `sent` in this batch, or pending for the next), then lands.
    #[inline(always)]
    fn end_move(&mut self, sent: bool) {
        self.stop.after = AfterStop::Land;
        if sent {
            self.rb.sent_at = self.tick;
        } else {
            self.stop.pending = Some(Command::SoftStop);
        }
        self.state = AxisState::Stopping;
    }

    /// This tick's Run: the profile's speed (feed-forward) plus the
    /// following error's correction, capped to what the chip can still
    /// stop from before the target, in the chip's own time.
    #[inline(always)]
    fn run_speed(&mut self) -> (Direction, u32) {
        // (speed_reg_with and correction_reg_with, remembered: while
        // cruising both are the last tick's.)
        let ff = self.speed_div.div_signed(self.profile.velocity_internal());
        let corr = self
            .corr_div
            .div_signed(units::correction_numerator(self.rb.error));
        // Bounded (units::correction_cap); the common case, within the
        // standstill bound, is one 32-bit product and a compare.
        let corr =
            if corr.unsigned_abs() <= u64::from(units::correction_cap_at_rest(self.limits.dec)) {
                corr
            } else {
                let cap = units::correction_cap(self.limits.dec, ff);
                corr.max(-cap).min(cap)
            };
        let spd = self.cap_to_stop(ff, ff + corr);
        let dir = if spd < 0 || (spd == 0 && ff < 0) {
            Direction::Reverse
        } else {
            Direction::Forward
        };
        let mag = self
            .rate
            .scale(spd.unsigned_abs())
            .min(u64::from(SPEED_MAX)) as u32;
        (dir, mag)
    }

    /// The control tick's common cases, known before anything changes:
    /// [`Axis::plan`] will send the read and at most one command without a
    /// response after it (a Run, the SoftStop that ends a move, a GoTo that
    /// lands, a one-shot stop, wake or HiZ), which every batch takes: no
    /// changed register and no extension-space read waits, and the axis
    /// streams with its MAX_SPEED backstop in place (at most at its max
    /// speed, so the profile's tick keeps it there or below), starts a move
    /// whose ramp registers are on the chip already, rests, or waits for a
    /// stop or a landing. [`Axis::plan_plain`] is that plan without the
    /// batch.
    pub fn plain(&self) -> bool {
        if self.ext_read.is_some() || self.image.dirty() {
            return false;
        }
        if matches!(self.state, AxisState::Streaming) {
            return self.backstop_stands(self.profile.limits().max_speed);
        }
        self.plain_waiting()
    }

    /// The MAX_SPEED backstop needs no write this tick while the profile,
    /// with max speed `max_speed`, stays at most at it ([`Axis::stream`]).
    fn backstop_stands(&self, max_speed: u32) -> bool {
        let (profile_max, backstop) = self.limits.backstop;
        let vmax = self.profile.internal_limits().0.unsigned_abs();
        self.profile.velocity_internal().unsigned_abs() <= vmax
            && backstop != 0
            && profile_max == max_speed
            && self.limits.max_speed == backstop
    }

    /// [`Axis::plain`] for an axis that does not stream.
    #[inline(never)]
    fn plain_waiting(&self) -> bool {
        let may_stream = self.stop.after == AfterStop::Land && !self.asleep;
        match self.state {
            // [`Axis::plan_idle`]: one command at most.
            AxisState::Idle if self.profile.is_settled() => true,
            // [`Axis::start_from_rest`] with the ramp registers in place:
            // the stream's first tick, at the limits refresh_limits gives
            // it (the max speed is the requested one clamped to the chip).
            AxisState::Idle => {
                let regs = self
                    .memo
                    .start
                    .filter(|(k, _)| *k == (self.limits.requested, self.cfg.logical_shift));
                let in_place = regs.is_some_and(|(_, r)| r == (self.limits.acc, self.limits.dec));
                let max = units::clamp_to_chip(self.limits.requested, self.cfg.logical_shift);
                in_place
                    && self.profile.velocity_internal() == 0
                    && self.backstop_stands(max.max_speed)
            }
            // [`Axis::plan_stopping`]: the pending stop, nothing while the
            // chip stops, or the landing's GoTo (not with Set zero's
            // ResetPos before it, not a new target streaming on).
            AxisState::Stopping => {
                let streams_on = may_stream && !self.profile.is_settled();
                let resets = self.stop.zero && self.confirmed_stopped();
                self.stop.pending.is_some() || (!streams_on && !resets)
            }
            // Settled: nothing while the chip lands, or a GoTo again.
            AxisState::Landing => self.profile.is_settled(),
            _ => false,
        }
    }

    /// [`Axis::plan`] for an axis that is [`Axis::plain`], written into
    /// `plan` as device `device` ([`Plan::stream_put`]) instead of pushed
    /// into a batch (which would take the read and the command after it).
    /// An error if the plan was not plain after all (a bug: the caller
    /// fails the tick safely) or `device` is not in the plan.
    pub fn plan_plain(&mut self, plan: &mut Plan, device: usize) -> Result<(), ScheduleError> {
        if matches!(self.state, AxisState::Streaming) {
            return match self.plan_streaming_plain() {
                (read, Command::Run(dir, speed)) => plan.stream_put_run(device, read, dir, speed),
                (read, cmd) => plan.stream_put(device, read, Some(cmd)),
            };
        }
        match self.plan_captured() {
            (Some(read), cmd) => plan.stream_put(device, read, cmd),
            (None, _) => Err(ScheduleError::TooManyCommands),
        }
    }

    /// [`Axis::plan`] of a streaming axis that is [`Axis::plain`], step for
    /// step (the control tick's common case, written out: the read, then
    /// [`Axis::stream`] without the backstop's write, which
    /// [`Axis::backstop_stands`] rules out).
    fn plan_streaming_plain(&mut self) -> (StreamRead, Command) {
        self.tick = self.tick.wrapping_add(1);
        self.rate_tick();
        let read = self.regular_read();
        if read == Read::Status {
            self.image.status_requested();
        }
        self.rb.read = None;
        self.rb.expected_at_read = self.profile_physical();
        self.profile_step();
        let cmd = if self.profile.is_settled() {
            self.end_move(true);
            Command::SoftStop
        } else {
            let (dir, mag) = self.run_speed();
            self.rate.running = signed_speed(dir, mag);
            Command::Run(dir, mag)
        };
        self.record_batch(Some(read), true);
        let read = match read {
            Read::Position => StreamRead::Param(Register::AbsPos),
            Read::Status => StreamRead::Status,
        };
        (read, cmd)
    }

    /// [`Axis::plan`] itself, its commands captured (every one taken, as
    /// the batch takes a read and one more): the plain ticks that are not
    /// a stream's.
    #[inline(never)]
    fn plan_captured(&mut self) -> (Option<StreamRead>, Option<Command>) {
        let mut out: [Option<Command>; 2] = [None; 2];
        let mut count = 0usize;
        self.plan(|cmd| {
            if let Some(slot) = out.get_mut(count) {
                *slot = Some(cmd);
            }
            count = count.saturating_add(1);
            true
        });
        let read = match out[0] {
            Some(Command::GetParam(Register::AbsPos)) => Some(StreamRead::Param(Register::AbsPos)),
            Some(Command::GetStatus) => Some(StreamRead::Status),
            _ => None,
        };
        let shaped = count <= 2 && out[1].is_none_or(|c| c.response_len() == 0);
        (read.filter(|_| shaped), out[1])
    }

    /// A `Run` (`spd`, the feed-forward `ff` plus the correction) toward
    /// the target no faster than the chip can still stop from before it,
    /// from where the chip is estimated to be as the `Run` reaches it (the
    /// profile's position at this tick's start less the last following
    /// error): a chip ahead of the profile (a late or skipped tick, during
    /// which it ran on at its last speed) brakes earlier instead of being
    /// carried past the target by the correction. Only while the profile
    /// itself can stop on the target in that direction: one that cannot
    /// (a retarget inside the braking distance) passes it on purpose, and
    /// so does a member of a path whose line runs through the target to
    /// the next waypoint.
    pub(super) fn cap_to_stop(&mut self, ff: i64, spd: i64) -> i64 {
        let Mode::Position(t) = self.profile.mode() else {
            return spd;
        };
        if (ff >= 0) != (spd >= 0) {
            return spd;
        }
        if self.memo.target.0 != t {
            let phys = logical_to_physical(t, self.cfg.logical_shift, self.cfg.step);
            self.memo.target = (t, phys);
        }
        let target = self.memo.target.1;
        // Where the chip should be as this Run reaches it, and how far
        // behind that it is (ahead of it if negative), toward the target.
        let profile = self.rb.expected_at_read;
        let (ahead, behind) = if spd >= 0 {
            (target.saturating_sub(profile), self.rb.error)
        } else {
            (
                profile.saturating_sub(target),
                self.rb.error.saturating_neg(),
            )
        };
        let left = ahead.saturating_add(behind);
        if ahead <= 0 || left > self.stop_cap.room() || self.led_through() {
            return spd;
        }
        let cap2 = self.stop_cap.speed2(left);
        if units::within(spd, cap2) || !units::within(ff, self.stop_cap.speed2(ahead)) {
            return spd;
        }
        units::cap_speed(spd, cap2)
    }
}

/// A Run's speed as the chip runs it, signed by its direction.
fn signed_speed(dir: Direction, mag: u32) -> i64 {
    match dir {
        Direction::Forward => i64::from(mag),
        Direction::Reverse => -i64::from(mag),
    }
}
