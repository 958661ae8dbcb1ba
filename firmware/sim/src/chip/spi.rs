//! The SPI side: byte parser (one byte per CS window), responses, and the
//! execution of every command, with the refusals of the strictness table.

use super::engine::dist_in_dir;
use super::*;
use crate::datasheet::{wrap_22, Access, Verdict};

impl Powerstep01 {
    // ------------------------------------------------------------ SPI ----

    /// The byte the next CS window shifts out of this device.
    pub fn output(&self) -> u8 {
        match self.dead {
            Some(stuck) => stuck,
            None => self.out,
        }
    }

    /// CS rising edge: interpret `input` (command or argument byte), then
    /// load the next response byte (or 0x00) into the shift register.
    pub fn latch(&mut self, input: u8) {
        if self.dead.is_some() {
            return;
        }
        if self.need > 0 {
            if let Some(slot) = self.args.get_mut(usize::from(self.got)) {
                *slot = input;
            }
            self.got = self.got.saturating_add(1);
            if self.got >= self.need {
                let n = usize::from(self.need.min(3));
                self.need = 0;
                self.got = 0;
                let mut frame = [self.cmd, 0, 0, 0];
                for (dst, src) in frame.iter_mut().skip(1).zip(self.args.iter()) {
                    *dst = *src;
                }
                self.complete(frame.get(..=n).unwrap_or(&[]));
            }
        } else {
            match datasheet::command_byte(input) {
                Verdict::Refused => self.refuse(),
                Verdict::Takes(0) => self.complete(&[input]),
                Verdict::Takes(n) => {
                    self.cmd = input;
                    self.need = n.min(3);
                    self.got = 0;
                }
            }
        }
        self.load_output();
    }

    /// One CS window for a device on its own: returns the byte clocked out
    /// while `input` was clocked in, then latches `input`.
    pub fn exchange(&mut self, input: u8) -> u8 {
        let out = self.output();
        self.latch(input);
        out
    }

    pub(super) fn load_output(&mut self) {
        if self.resp_next < self.resp_len {
            self.out = self
                .resp
                .get(usize::from(self.resp_next))
                .copied()
                .unwrap_or(0);
            self.resp_next = self.resp_next.saturating_add(1);
        } else {
            self.out = 0;
        }
    }

    pub(super) fn respond(&mut self, value: u32, len: u8) {
        let len = len.clamp(1, 3);
        let be = value.to_be_bytes();
        let start = 4usize.saturating_sub(usize::from(len));
        for (dst, src) in self.resp.iter_mut().zip(be.iter().skip(start)) {
            *dst = *src;
        }
        self.resp_len = len;
        self.resp_next = 0;
    }

    pub(super) fn refuse(&mut self) {
        self.cmd_error = true;
        self.command_errors = self.command_errors.saturating_add(1);
    }

    pub(super) fn complete(&mut self, frame: &[u8]) {
        match datasheet::decode(frame) {
            Some(cmd) => {
                if cmd != Command::Nop {
                    if self.log.is_full() {
                        let _ = self.log.pop_front();
                    }
                    let _ = self.log.push_back(cmd);
                    self.received_count = self.received_count.saturating_add(1);
                }
                self.execute(cmd);
                // Instant state changes (start speed, direction flip at rest,
                // zero-length moves) take effect at once.
                self.run_engine(0);
            }
            None => self.refuse(),
        }
    }

    pub(super) fn bridges_locked(&self) -> bool {
        self.ocd_lock || self.th_cond >= bits::th::BRIDGE_SHUTDOWN
    }

    /// Common part of every accepted motion or stop command.
    pub(super) fn enable_bridges(&mut self) {
        self.hiz = false;
        self.stck_mod = false;
    }

    pub(super) fn execute(&mut self, cmd: Command) {
        if enables_bridges(&cmd) && self.bridges_locked() {
            self.refuse();
            return;
        }
        match cmd {
            Command::Nop => {}
            Command::SetParam(r, v) => self.set_param(r, v),
            Command::GetParam(r) => {
                let address = vocab::address(r);
                let v = self.register_at(address);
                let len = datasheet::register(address).map_or(1, |s| s.bytes);
                self.respond(v, len);
            }
            Command::GetStatus => {
                let s = self.status_raw();
                self.respond(u32::from(s), 2);
                self.clear_latched();
            }
            Command::Run(dir, spd) => self.run_at(dir, spd, SpeedKind::Run),
            Command::GoUntil(act, dir, spd) => self.run_at(dir, spd, SpeedKind::GoUntil(act)),
            Command::ReleaseSw(act, dir) => self.release_sw(act, dir),
            Command::StepClock(dir) => self.step_clock(dir),
            Command::Move(dir, n) => self.move_by(dir, n),
            Command::GoTo(p) => self.go_to(None, wrap_22(p)),
            Command::GoToDir(dir, p) => self.go_to(Some(dir), wrap_22(p)),
            Command::GoHome => self.go_to(None, 0),
            Command::GoMark => {
                let mark = self.reg(addr::MARK);
                self.go_to(None, mark)
            }
            Command::ResetPos => {
                self.set_reg(addr::ABS_POS, 0);
                self.frac = 0;
            }
            Command::ResetDevice => {
                if !self.hiz {
                    self.refuse();
                    return;
                }
                self.power_up();
            }
            Command::SoftStop => {
                self.enable_bridges();
                self.motion = Motion::Stopping { hiz: false };
            }
            Command::HardStop => {
                self.enable_bridges();
                self.stop_now();
            }
            Command::SoftHiZ => {
                self.stck_mod = false;
                self.motion = Motion::Stopping { hiz: true };
            }
            Command::HardHiZ => {
                self.stck_mod = false;
                self.stop_now();
                self.hiz = true;
            }
        }
    }

    /// SetParam: written if the register's access class allows it now.
    fn set_param(&mut self, r: Register, v: u32) {
        let address = vocab::address(r);
        let allowed = match datasheet::register(address).map(|s| s.access) {
            None | Some(Access::ReadOnly) => false,
            Some(Access::Always) => true,
            Some(Access::WhenStopped) => self.is_stopped(),
            Some(Access::WhenHiZ) => self.hiz,
        };
        if allowed {
            self.write_reg(address, v);
        } else {
            self.refuse();
        }
    }

    /// Run and GoUntil: constant speed `spd` (steps/tick, 2^-28) towards `dir`.
    fn run_at(&mut self, dir: Direction, spd: u32, kind: SpeedKind) {
        self.enable_bridges();
        self.motion = Motion::Speed {
            dir,
            spd: u64::from(spd) << 12,
            kind,
        };
    }

    /// ReleaseSW: at the release speed until the switch opens (at once if
    /// it is open).
    fn release_sw(&mut self, act: SwitchAction, dir: Direction) {
        self.enable_bridges();
        if !self.sw_closed {
            self.apply_act(act);
            self.stop_now();
        } else {
            self.motion = Motion::Speed {
                dir,
                spd: RELEASE_SW_SPEED,
                kind: SpeedKind::ReleaseSw(act),
            };
        }
    }

    /// StepClock: refused unless stopped; the STCK pin then steps the motor.
    fn step_clock(&mut self, dir: Direction) {
        if !self.is_stopped() {
            self.refuse();
            return;
        }
        self.enable_bridges();
        self.stck_mod = true;
        self.motion = Motion::Idle;
        self.v = 0;
        if self.dir != dir {
            self.frac = 0;
        }
        self.dir = dir;
    }

    /// Move: `n` microsteps towards `dir`; refused unless stopped.
    fn move_by(&mut self, dir: Direction, n: u32) {
        if !self.is_stopped() {
            self.refuse();
            return;
        }
        self.enable_bridges();
        let n = u64::from(n & POS_MASK);
        let pos = self.abs_raw();
        let target = match dir {
            Direction::Forward => pos.wrapping_add(n as u32),
            Direction::Reverse => pos.wrapping_sub(n as u32),
        } & POS_MASK;
        self.start_position(dir, target, n);
    }

    /// GoTo family: refused while BUSY; `dir` forces the direction.
    pub(super) fn go_to(&mut self, dir: Option<Direction>, target: u32) {
        if self.busy() {
            self.refuse();
            return;
        }
        self.enable_bridges();
        let pos = self.abs_raw();
        let (dir, remaining) = match dir {
            Some(d) => (d, dist_in_dir(d, pos, target)),
            None => {
                let delta = sign_extend_22(target.wrapping_sub(pos) & POS_MASK);
                if delta > 0 || (delta == 0 && self.v == 0) {
                    (Direction::Forward, delta.unsigned_abs().into())
                } else if delta == 0 {
                    // Already on the target while moving: stop on it.
                    (self.dir, 0)
                } else {
                    (Direction::Reverse, delta.unsigned_abs().into())
                }
            }
        };
        if remaining == 0 && self.v == 0 {
            self.motion = Motion::Idle;
            return;
        }
        self.start_position(dir, target, remaining);
    }

    pub(super) fn start_position(&mut self, dir: Direction, target: u32, remaining: u64) {
        self.motion = Motion::Position {
            dir,
            target,
            remaining,
            braking: false,
        };
    }

    pub(super) fn stop_now(&mut self) {
        self.v = 0;
        self.motion = Motion::Idle;
    }

    pub(super) fn apply_act(&mut self, act: SwitchAction) {
        match act {
            SwitchAction::ResetAbsPos => {
                self.set_reg(addr::ABS_POS, 0);
            }
            SwitchAction::CopyToMark => {
                let p = self.abs_raw();
                self.set_reg(addr::MARK, p);
            }
        }
    }

    pub(super) fn clear_latched(&mut self) {
        self.sw_evn = false;
        self.cmd_error = false;
        // Event-type conditions are over once injected (module docs, choice 3).
        self.uvlo = false;
        self.ocd = false;
        self.ocd_lock = false;
        self.stall = false;
        self.th_latched = self.th_cond;
    }
}

/// Motion and stop commands switch the bridges on (and are refused while a
/// fault keeps them off).
fn enables_bridges(cmd: &Command) -> bool {
    matches!(
        cmd,
        Command::Run(..)
            | Command::StepClock(_)
            | Command::Move(..)
            | Command::GoTo(_)
            | Command::GoToDir(..)
            | Command::GoUntil(..)
            | Command::ReleaseSw(..)
            | Command::GoHome
            | Command::GoMark
            | Command::SoftStop
            | Command::HardStop
    )
}
