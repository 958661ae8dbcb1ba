//! Axis output stage: turns the profile generator's setpoints into chain
//! commands for one powerSTEP01, and the chip's answers back into position.
//!
//! # What it guarantees
//!
//! * **One tick, one slot.** Every control tick [`Axis::plan`] emits at most
//!   [`crate::powerstep::chain::MAX_COMMANDS`] commands for its device: one
//!   read-back (ABS_POS on even ticks, STATUS via GetStatus on odd ticks) first,
//!   then the output command. The read's response comes out while the output
//!   command's argument bytes go in, so a streaming tick of any chain length is
//!   5 CS windows (`GetParam(ABS_POS)`/`GetStatus` + `Run`).
//! * **Streaming.** While the profile moves, the output is `Run(dir, speed)`
//!   with the profile's velocity (feed-forward) plus a proportional correction
//!   of the following error measured at the last position read-back
//!   ([`CORRECTION_TICKS`]). The chip's ACC/DEC are 1.5 × the profile's
//!   (rounded up), so it reaches each setpoint inside the tick and has room to
//!   correct while the profile ramps at its limit; its MAX_SPEED is a backstop
//!   25 % + 16 steps/s above the profile's max speed.
//! * **Exact landing.** When the profile has settled on its target the axis
//!   sends SoftStop, waits for the chip to report not-busy, then sends
//!   `GoTo(target)`: the chip covers the last few microsteps itself and cannot
//!   overshoot. The axis is settled when STATUS says not busy and ABS_POS
//!   equals the target.
//! * **Wide positions.** ABS_POS is 22 bits; every read is unwrapped against
//!   the previous one (moves between two reads are far below 2²¹ microsteps),
//!   so the axis position is an `i64` and moves longer than 2²¹ work. The
//!   landing GoTo uses the chip's 22-bit shortest path, which is right because
//!   the residual at landing is a few microsteps.
//! * **Units.** The profile runs in logical steps (PoStep60 step mode
//!   0 = full … 8 = 1/256); the chip in physical microsteps (STEP_SEL). The
//!   conversion is an exact power-of-two scaling ([`logical_to_physical`]); a
//!   logical mode finer than the physical one lands on the physical microstep
//!   at or below the logical target.
//! * **The chip saying no.** CMD_ERROR after a GoTo retries the landing. A
//!   reset or undervoltage (UVLO flag) stops the profile where the chip
//!   actually is (never a jump in the commanded position), rewrites the
//!   chip's configuration and re-bases its ABS_POS to the axis position; a
//!   bridge fault (overcurrent, thermal shutdown) stops the profile at the
//!   read-back position and leaves the bridges as the chip put them.

use super::profile::{Limits, Mode, Profile};
use heapless::Deque;

use crate::powerstep::chain::{Replies, MAX_COMMANDS};
use crate::powerstep::commands::{Command, Direction};
use crate::powerstep::fields::{DriveMode, StepMode, StepSel};
use crate::powerstep::registers::{sign_extend_22, wrap_22, Access, Register};
use crate::powerstep::status::Status;
use crate::powerstep::status::ThermalStatus;
use crate::powerstep::units;

/// Finest PoStep60 step mode (8 = 1/256).
pub const MAX_LOGICAL_SHIFT: u8 = 8;
/// The following error is corrected over this many ticks.
pub const CORRECTION_TICKS: i64 = 8;
/// The chip's ACC/DEC are the profile's times this ratio (3/2): with equal
/// ramps the chip could never catch up a following error while the profile
/// accelerates or brakes at its limit.
const RAMP_HEADROOM_NUM: u64 = 3;
const RAMP_HEADROOM_DEN: u64 = 2;

/// Logical position → physical microsteps (floor when the logical step is finer).
pub const fn logical_to_physical(pos: i64, logical_shift: u8, step: StepSel) -> i64 {
    let s = step.shift() as i64;
    let l = logical_shift as i64;
    if s >= l {
        pos << (s - l)
    } else {
        pos >> (l - s)
    }
}

/// Physical microsteps → logical position (exact when the logical step is coarser
/// or equal; otherwise the physical microstep's first logical step).
pub const fn physical_to_logical(pos: i64, logical_shift: u8, step: StepSel) -> i64 {
    let s = step.shift() as i64;
    let l = logical_shift as i64;
    if s >= l {
        // Floor: a physical position between two logical steps reads as the lower one.
        pos >> (s - l)
    } else {
        pos << (l - s)
    }
}

/// Logical steps/s (or /s²) → full steps/s in Q16.16, rounded up.
pub const fn full_steps_q16_from_logical(v: u32, logical_shift: u8) -> u32 {
    let q = (v as u64) << 16;
    let div = 1u64 << logical_shift;
    let r = q.div_ceil(div);
    if r > u32::MAX as u64 {
        u32::MAX
    } else {
        r as u32
    }
}

/// Profile velocity (2⁻³² logical steps per tick) → chip SPEED units (signed):
/// `v · 10⁶ · 2²⁸ / (tick_us · 2³² · 2^L · 4·10⁶) = v / (tick_us · 2^(6+L))`.
pub const fn speed_reg_from_internal(v: i64, tick_us: u32, logical_shift: u8) -> i64 {
    let div = (tick_us as i64) << (6 + logical_shift as i64);
    if div == 0 {
        0
    } else {
        v / div
    }
}

/// A following error of `e` physical microsteps corrected over `ticks` ticks,
/// in chip SPEED units: `e / 2^S` full steps per `ticks · tick_us` µs.
pub const fn correction_speed_reg(e: i64, tick_us: u32, step: StepSel, ticks: i64) -> i64 {
    let div = (tick_us as i64) * ticks;
    if div <= 0 {
        return 0;
    }
    // full steps/s = e · 10⁶ / (2^S · div); reg = that · 2²⁸ / 4·10⁶.
    // |e| beyond 2³⁰ microsteps is no following error but a lost position:
    // clamp so the shift cannot overflow (the speed saturates anyway).
    let e = if e > 1 << 30 {
        1 << 30
    } else if e < -(1 << 30) {
        -(1 << 30)
    } else {
        e
    };
    (e << 26) / (div << step.shift())
}

/// Static description of one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisConfig {
    /// Control tick period, µs.
    pub tick_us: u32,
    /// PoStep60 step mode: logical step = 1/2^shift full step (0..=8).
    pub logical_shift: u8,
    /// The chip's STEP_SEL.
    pub step: StepSel,
    /// Voltage or current mode (current mode caps STEP_SEL at 1/16).
    pub drive: DriveMode,
}

impl AxisConfig {
    /// The STEP_MODE register value (BUSY output, no sync).
    pub fn step_mode(&self) -> StepMode {
        let finest = StepSel::finest(self.drive);
        StepMode {
            step: if self.step > finest {
                finest
            } else {
                self.step
            },
            mode: self.drive,
            sync_sel: 0,
            sync_enable: false,
        }
    }
}

/// What the output stage is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AxisState {
    /// Writing the chip's configuration (index of the next setup step).
    Setup(u8),
    /// At rest, holding.
    Idle,
    /// Streaming Run setpoints.
    Streaming,
    /// SoftStop sent at the end of a move; waiting for not-busy.
    Stopping,
    /// GoTo sent; waiting for not-busy on the target.
    Landing,
}

/// Why the last motion ended other than on its target.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AxisFault {
    /// The chip reported UVLO: undervoltage or reset; configuration rewritten.
    ChipReset,
    /// Overcurrent.
    Overcurrent,
    /// Thermal bridge or device shutdown.
    Thermal,
    /// The chain's SPI transfer failed; the chip was set up again.
    ChainError,
}

/// Which read-back is in flight this tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Read {
    Position,
    Status,
}

/// What to do once the chip has stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum AfterStop {
    /// Land on the profile's target with GoTo.
    Land,
    /// Make the current position zero (PoStep60 Set zero).
    Zero,
    /// Stay where the chip stopped (after sleep): no landing move.
    Hold,
}

/// One axis: profile generator + output stage for one chip of the chain.
#[derive(Clone, Debug)]
pub struct Axis {
    cfg: AxisConfig,
    profile: Profile,
    state: AxisState,
    /// Unwrapped chip position, physical microsteps.
    chip_pos: i64,
    /// Last raw ABS_POS read; `None` until the first read after (re)basing.
    raw: Option<u32>,
    /// `chip_pos` at the last clean STATUS read (restored after a chip reset).
    pos_at_status: i64,
    /// Physical position the chip should have had at this tick's read.
    expected_at_read: i64,
    /// Following error at the last read (expected − actual), microsteps.
    error: i64,
    /// What was read this tick (decoded in `absorb`).
    read: Option<Read>,
    status: Status,
    /// One-shot command to send at the next plan.
    pending: Option<Command>,
    after_stop: AfterStop,
    /// Tick of the last one-shot command, the last STATUS and ABS_POS reads
    /// (u64: never wraps, so the ordering checks hold for any uptime).
    sent_at: u64,
    status_at: u64,
    pos_at: u64,
    /// Chip MAX_SPEED, ACC, DEC as written (register values).
    chip_limits: (u32, u32, u32),
    /// (profile max speed, its MAX_SPEED backstop register), cached.
    backstop: (u32, u32),
    fault: Option<AxisFault>,
    tick: u64,
    /// CONFIG register value written at setup (None: leave the chip's).
    chip_config: Option<u16>,
    /// Register writes (WR registers only) waiting for a free command slot.
    writes: Deque<(Register, u32), 8>,
    /// One-shot command to send while idle (wake up: HardStop).
    idle_command: Option<Command>,
    /// Bridges switched off on request: motion commands are not executed.
    asleep: bool,
    /// Bridges switched off after an overcurrent/thermal shutdown (until the
    /// chip reports healthy again).
    chip_off_for_fault: bool,
    /// Chip resets / undervoltages detected since boot.
    resets: u32,
}

/// Setup steps after which the chip is configured.
const SETUP_STEPS: u8 = 4;

impl Axis {
    pub fn new(cfg: AxisConfig, limits: Limits) -> Axis {
        let cfg = AxisConfig {
            logical_shift: cfg.logical_shift.min(MAX_LOGICAL_SHIFT),
            ..cfg
        };
        Axis {
            cfg,
            profile: Profile::new(cfg.tick_us, limits),
            state: AxisState::Setup(0),
            chip_pos: 0,
            raw: None,
            pos_at_status: 0,
            expected_at_read: 0,
            error: 0,
            read: None,
            status: Status::IDLE,
            pending: None,
            after_stop: AfterStop::Land,
            sent_at: 0,
            status_at: 0,
            pos_at: 0,
            chip_limits: (0, 0, 0),
            backstop: (0, 0),
            fault: None,
            tick: 0,
            chip_config: None,
            writes: Deque::new(),
            idle_command: None,
            asleep: false,
            chip_off_for_fault: false,
            resets: 0,
        }
    }

    /// Write this CONFIG value at setup (e.g. SW_MODE = 1 so the switch input
    /// only raises an event and the bridge decides what it means).
    pub fn with_chip_config(mut self, config: u16) -> Axis {
        self.chip_config = Some(config);
        self
    }

    pub fn config(&self) -> AxisConfig {
        self.cfg
    }
    pub fn state(&self) -> AxisState {
        self.state
    }
    pub fn profile(&self) -> &Profile {
        &self.profile
    }
    /// Last STATUS read from the chip.
    pub fn status(&self) -> Status {
        self.status
    }
    /// Following error at the last position read, in physical microsteps.
    pub fn following_error(&self) -> i64 {
        self.error
    }
    /// The chip's unwrapped position in physical microsteps.
    pub fn chip_position(&self) -> i64 {
        self.chip_pos
    }
    /// Actual position in logical steps (from the chip's read-back).
    pub fn actual_position(&self) -> i64 {
        physical_to_logical(self.chip_pos, self.cfg.logical_shift, self.cfg.step)
    }
    /// Where the profile wants the axis (logical steps, nearest).
    pub fn required_position(&self) -> i64 {
        match self.profile.mode() {
            Mode::Position(t) => t,
            _ => self.profile.position_round(),
        }
    }
    /// Chip resets or undervoltages detected since boot (each one re-ran the setup).
    pub fn chip_resets(&self) -> u32 {
        self.resets
    }
    /// Why the last motion was cut short, if it was (cleared by the next move).
    pub fn fault(&self) -> Option<AxisFault> {
        self.fault
    }
    /// Nothing moving: profile settled, chip landed and confirmed.
    pub fn is_settled(&self) -> bool {
        self.state == AxisState::Idle && self.profile.is_settled()
    }

    // ------------------------------------------------------ motion commands

    /// Move to `target` logical steps (ignored while asleep).
    pub fn move_to(&mut self, target: i64) {
        if self.asleep {
            return;
        }
        self.fault = None;
        self.profile.move_to(target);
    }
    /// Run at a signed speed (logical steps/s; ignored while asleep).
    pub fn run_at(&mut self, steps_per_s: i32) {
        if self.asleep {
            return;
        }
        self.fault = None;
        self.profile.run_at(steps_per_s);
    }

    /// Queue a write of a register that is writable at any time (KVAL/TVAL,
    /// OCD_TH, …). A queued write to the same register is replaced. Returns
    /// false for registers with access restrictions or when the queue is full.
    pub fn write_register(&mut self, reg: Register, value: u32) -> bool {
        if reg.access() != Access::Always {
            return false;
        }
        if let Some(slot) = self.writes.iter_mut().find(|(r, _)| *r == reg) {
            slot.1 = value;
            return true;
        }
        self.writes.push_back((reg, value)).is_ok()
    }

    /// Switch the bridges off (PoStep60 sleep): stop at once, HardHiZ, hold
    /// the position where the chip stopped. Motion commands are ignored until
    /// [`Axis::wake`].
    pub fn sleep(&mut self) {
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

    /// Change the logical step mode. A moving axis stops at once; the
    /// position is re-expressed in the new unit from the chip's microstep
    /// (exactly when the new unit is not finer than a microstep, else the
    /// step at or below), and the chip's ramps are rewritten at the next start.
    pub fn set_logical_shift(&mut self, shift: u8) {
        let shift = shift.min(MAX_LOGICAL_SHIFT);
        if shift == self.cfg.logical_shift {
            return;
        }
        self.profile.stop_now();
        self.cfg.logical_shift = shift;
        let here = self.actual_position();
        self.profile.set_position(here);
        self.chip_limits = (0, 0, 0);
        self.backstop = (0, 0);
        if !matches!(self.state, AxisState::Setup(_) | AxisState::Idle) {
            self.stop_then(AfterStop::Hold, self.stop_command());
        }
    }
    /// Decelerate to a stop with the profile's deceleration.
    pub fn soft_stop(&mut self) {
        self.profile.soft_stop();
    }
    /// Stop at once, no ramp (HardStop), and hold where the chip stopped
    /// (no landing move: after an end switch that could go back into it).
    /// An axis that is asleep stays in HiZ.
    pub fn stop_now(&mut self) {
        self.profile.stop_now();
        self.stop_then(AfterStop::Hold, self.stop_command());
    }
    /// Stop at once and make the current position zero.
    pub fn set_zero(&mut self) {
        self.profile.stop_now();
        self.stop_then(AfterStop::Zero, self.stop_command());
    }

    /// HardStop holds the motor; asleep, the bridges must stay off.
    fn stop_command(&self) -> Command {
        if self.asleep {
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
        self.profile.stop_now();
        let here = self.actual_position();
        self.profile.set_position(here);
        self.raw = None;
        self.error = 0;
        self.pending = None;
        self.read = None;
        self.chip_limits = (0, 0, 0);
        self.state = AxisState::Setup(0);
        if !self.asleep {
            self.idle_command = Some(Command::HardStop);
        }
    }
    /// New limits: the profile uses them at the next tick; the chip's ACC/DEC
    /// follow at the next start from rest (writable only while stopped), its
    /// MAX_SPEED at once.
    pub fn set_limits(&mut self, limits: Limits) {
        self.profile.set_limits(limits);
    }

    fn stop_then(&mut self, after: AfterStop, cmd: Command) {
        if matches!(self.state, AxisState::Setup(_)) {
            if after == AfterStop::Zero {
                self.chip_pos = 0;
                self.profile.set_position(0);
            }
            return;
        }
        self.after_stop = after;
        self.pending = Some(cmd);
        self.state = AxisState::Stopping;
    }

    // ------------------------------------------------------------- limits

    /// Chip MAX_SPEED register for a profile speed (logical steps/s): a
    /// backstop 25 % + 16 steps/s above it.
    fn backstop_reg(&self, steps_per_s: u32) -> u32 {
        let v = full_steps_q16_from_logical(steps_per_s, self.cfg.logical_shift);
        let backstop = v.saturating_add(v / 4).saturating_add(16 << 16);
        units::max_speed_from_steps_per_s(backstop).max(1)
    }

    /// Chip (MAX_SPEED, ACC, DEC) registers for the profile's limits.
    fn wanted_chip_limits(&self) -> (u32, u32, u32) {
        let l = self.profile.limits();
        let shift = self.cfg.logical_shift;
        // The chip ramps RAMP_HEADROOM faster than the profile, so it reaches
        // every setpoint inside the tick and has room left for corrections.
        let ramp = |a: u32| {
            let full = full_steps_q16_from_logical(a, shift);
            let fast =
                (u64::from(full) * RAMP_HEADROOM_NUM / RAMP_HEADROOM_DEN).min(u64::from(u32::MAX));
            (units::acc_from_steps_per_s2(fast as u32) + 1).min(units::ACC_MAX_FINITE)
        };
        (self.backstop_reg(l.max_speed), ramp(l.acc), ramp(l.dec))
    }

    // ------------------------------------------------------------ per tick

    /// The chip's position in the profile's units (2⁻³³ logical steps), exact.
    fn chip_fine(&self) -> i128 {
        let s = i128::from(self.cfg.step.shift());
        let l = i128::from(self.cfg.logical_shift);
        // logical = physical · 2^(L−S)
        let shift = 33 + l - s;
        i128::from(self.chip_pos) << shift
    }

    /// Physical microstep nearest to the profile's exact position: where the
    /// chip should be now.
    pub fn profile_physical(&self) -> i64 {
        let fine = self.profile.position_fine();
        let s = i128::from(self.cfg.step.shift());
        let l = i128::from(self.cfg.logical_shift);
        // fine is in 2⁻³³ logical steps; physical = logical · 2^(S−L)
        let shift = 33 - s + l;
        let half = 1i128 << (shift - 1);
        ((fine + half) >> shift) as i64
    }

    fn target_physical(&self) -> i64 {
        logical_to_physical(
            self.required_position(),
            self.cfg.logical_shift,
            self.cfg.step,
        )
    }

    /// Emit this tick's commands for the axis's chip (read-back first).
    /// `emit` returns false when the batch is full; the axis then retries next tick.
    pub fn plan(&mut self, mut emit: impl FnMut(Command) -> bool) {
        let mut used = 0usize;
        let mut counted = |cmd: Command| {
            let ok = emit(cmd);
            if ok {
                used += 1;
            }
            ok
        };
        self.plan_commands(&mut counted);
        // Spare slots carry queued register writes (currents, thresholds).
        while used < MAX_COMMANDS {
            let Some((reg, value)) = self.writes.pop_front() else {
                break;
            };
            if !emit(Command::SetParam(reg, value)) {
                let _ = self.writes.push_front((reg, value));
                break;
            }
            used += 1;
        }
    }

    fn plan_commands(&mut self, mut emit: impl FnMut(Command) -> bool) {
        self.tick = self.tick.wrapping_add(1);
        let read = if self.tick % 2 == 0 {
            Read::Position
        } else {
            Read::Status
        };
        let read_cmd = match read {
            Read::Position => Command::GetParam(Register::AbsPos),
            Read::Status => Command::GetStatus,
        };
        self.read = if emit(read_cmd) { Some(read) } else { None };
        self.expected_at_read = self.profile_physical();

        match self.state {
            AxisState::Setup(k) => {
                for cmd in self.setup_commands(k).into_iter().flatten() {
                    emit(cmd);
                }
                self.state = if k + 1 >= SETUP_STEPS {
                    AxisState::Idle
                } else {
                    AxisState::Setup(k + 1)
                };
            }
            AxisState::Idle | AxisState::Landing if !self.profile.is_settled() => {
                // A new motion: make the chip's ramps match, then stream.
                let want = self.wanted_chip_limits();
                let ramps_differ = (want.1, want.2) != (self.chip_limits.1, self.chip_limits.2);
                if self.state == AxisState::Idle && ramps_differ {
                    emit(Command::SetParam(Register::Acc, want.1));
                    emit(Command::SetParam(Register::Dec, want.2));
                    self.chip_limits.1 = want.1;
                    self.chip_limits.2 = want.2;
                } else {
                    self.state = AxisState::Streaming;
                    self.stream(&mut emit);
                }
            }
            AxisState::Streaming => self.stream(&mut emit),
            AxisState::Stopping => {
                if let Some(cmd) = self.pending.take() {
                    emit(cmd);
                    self.sent_at = self.tick;
                } else if !self.profile.is_settled()
                    && self.after_stop == AfterStop::Land
                    && !self.asleep
                {
                    self.state = AxisState::Streaming;
                    self.stream(&mut emit);
                } else if self.confirmed_stopped() {
                    // Hold exactly where the profile is (or make it zero).
                    match self.after_stop {
                        AfterStop::Hold => {
                            // Exactly where the chip is, even between two
                            // logical steps: the next move starts from there.
                            self.profile.set_position_fine(self.chip_fine());
                            self.state = AxisState::Idle;
                        }
                        AfterStop::Zero => {
                            emit(Command::ResetPos);
                            self.chip_pos = 0;
                            self.raw = None;
                            self.profile.set_position(0);
                            self.state = AxisState::Idle;
                        }
                        AfterStop::Land => {
                            if self.profile.mode() == Mode::Hold {
                                // After a hard stop: hold on the step the chip reached.
                                self.profile.set_position(self.actual_position());
                                self.profile.move_to(self.actual_position());
                            }
                            self.land(&mut emit);
                        }
                    }
                }
            }
            AxisState::Landing => {
                if self.confirmed_stopped() {
                    if self.chip_pos == self.target_physical() {
                        self.state = AxisState::Idle;
                    } else {
                        // Refused (CMD_ERROR) or disturbed: land again.
                        self.land(&mut emit);
                    }
                }
            }
            AxisState::Idle => {
                // Energize only once the queued current writes are out.
                if self.writes.is_empty() {
                    if let Some(cmd) = self.idle_command.take() {
                        emit(cmd);
                    }
                }
            }
        }
    }

    /// GoTo the target. The chip takes the shortest path modulo 2²², which is
    /// the right one because the residual at landing is a few microsteps.
    fn land(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        let target = self.target_physical();
        emit(Command::GoTo(sign_extend_22(wrap_22(target as i32))));
        self.sent_at = self.tick;
        self.state = AxisState::Landing;
    }

    /// A STATUS read after the last one-shot command says not busy, and a
    /// position read came after it.
    fn confirmed_stopped(&self) -> bool {
        self.status_at > self.sent_at && self.pos_at > self.status_at && !self.status.busy()
    }

    fn stream(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        let before = self.profile.velocity_internal().unsigned_abs();
        self.profile.tick();
        // MAX_SPEED backstop: raised at once when the profile needs more; lowered
        // to the new max speed only once the profile has slowed down to it (a
        // lower max speed mid-move is reached with the profile's DEC, not the chip's).
        let vmax = self.profile.internal_limits().0.unsigned_abs();
        let now = before.max(self.profile.velocity_internal().unsigned_abs());
        let max_speed = self.profile.limits().max_speed;
        if self.backstop.0 != max_speed {
            self.backstop = (max_speed, self.backstop_reg(max_speed));
        }
        let need = if now > vmax {
            let v = super::profile::speed_from_internal(now as i64, self.cfg.tick_us);
            self.backstop_reg(v.clamp(0, i64::from(u32::MAX)) as u32)
        } else {
            self.backstop.1
        };
        if need > self.chip_limits.0 || (now <= vmax && need != self.chip_limits.0) {
            emit(Command::SetParam(Register::MaxSpeed, need));
            self.chip_limits.0 = need;
        }
        if self.profile.is_settled() {
            self.after_stop = AfterStop::Land;
            emit(Command::SoftStop);
            self.sent_at = self.tick;
            self.state = AxisState::Stopping;
            return;
        }
        let ff = speed_reg_from_internal(
            self.profile.velocity_internal(),
            self.cfg.tick_us,
            self.cfg.logical_shift,
        );
        let corr = correction_speed_reg(
            self.error,
            self.cfg.tick_us,
            self.cfg.step,
            CORRECTION_TICKS,
        );
        let spd = ff + corr;
        let dir = if spd < 0 || (spd == 0 && ff < 0) {
            Direction::Reverse
        } else {
            Direction::Forward
        };
        let mag = spd
            .unsigned_abs()
            .min(u64::from(crate::powerstep::commands::SPEED_MAX)) as u32;
        emit(Command::Run(dir, mag));
    }

    fn setup_commands(&self, k: u8) -> [Option<Command>; 2] {
        let want = self.wanted_chip_limits();
        match k {
            0 => [
                Some(Command::HardHiZ),
                Some(Command::SetParam(
                    Register::StepMode,
                    u32::from(self.cfg.step_mode().to_reg()),
                )),
            ],
            1 => [
                self.chip_config
                    .map(|c| Command::SetParam(Register::Config, u32::from(c))),
                Some(Command::SetParam(Register::MaxSpeed, want.0)),
            ],
            2 => [
                Some(Command::SetParam(Register::Acc, want.1)),
                Some(Command::SetParam(Register::Dec, want.2)),
            ],
            // The bridges stay in HiZ until the first motion or `energize`.
            _ => [
                Some(Command::SetParam(
                    Register::AbsPos,
                    wrap_22(self.chip_pos as i32),
                )),
                None,
            ],
        }
    }

    /// Take this tick's replies for the axis's device.
    pub fn absorb(&mut self, replies: &Replies, device: usize) {
        match self.read.take() {
            Some(Read::Position) => {
                if let Some(raw) = replies.param(device, Register::AbsPos) {
                    self.take_position(raw);
                }
            }
            Some(Read::Status) => {
                if let Some(s) = replies.status(device) {
                    self.take_status(s);
                }
            }
            None => {}
        }
    }

    fn take_position(&mut self, raw: u32) {
        if matches!(self.state, AxisState::Setup(_)) {
            return; // the chip's frame is being re-based
        }
        let base = self.raw.unwrap_or(wrap_22(self.chip_pos as i32));
        let delta = sign_extend_22(raw.wrapping_sub(base) & 0x3F_FFFF);
        self.chip_pos += i64::from(delta);
        self.raw = Some(raw);
        self.pos_at = self.tick;
        self.error = self.expected_at_read - self.chip_pos;
        if self.state != AxisState::Streaming {
            self.error = 0;
        }
    }

    fn take_status(&mut self, s: Status) {
        self.status = s;
        self.status_at = self.tick;
        if s.uvlo() && !matches!(self.state, AxisState::Setup(_)) {
            // Reset or undervoltage: positions read since the last clean
            // STATUS are not trustworthy; stop where the chip was then.
            self.fault = Some(AxisFault::ChipReset);
            self.resets = self.resets.wrapping_add(1);
            self.chip_pos = self.pos_at_status;
            self.raw = None;
            self.error = 0;
            let here = self.actual_position();
            self.profile.set_position(here);
            self.pending = None;
            self.chip_limits = (0, 0, 0);
            self.state = AxisState::Setup(0);
            return;
        }
        if s.overcurrent()
            || matches!(
                s.thermal(),
                ThermalStatus::BridgeShutdown | ThermalStatus::DeviceShutdown
            )
        {
            self.fault = Some(if s.overcurrent() {
                AxisFault::Overcurrent
            } else {
                AxisFault::Thermal
            });
            // The power stage is in trouble: bridges off (they may already be,
            // with OC_SD), hold where the chip is, no landing move.
            if !matches!(self.state, AxisState::Setup(_)) && !self.chip_off_for_fault {
                self.profile.stop_now();
                self.chip_off_for_fault = true;
                self.stop_then(AfterStop::Hold, Command::HardHiZ);
            }
        } else {
            self.chip_off_for_fault = false;
        }
        self.pos_at_status = self.chip_pos;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logical_to_physical_scales_by_powers_of_two() {
        // logical 1/16 (4) on a chip at 1/128 (7): ×8
        assert_eq!(logical_to_physical(100, 4, StepSel::OneTwentyEighth), 800);
        assert_eq!(physical_to_logical(800, 4, StepSel::OneTwentyEighth), 100);
        // logical 1/256 (8) on a chip at 1/16: ÷16, floor
        assert_eq!(logical_to_physical(4096, 8, StepSel::Sixteenth), 256);
        assert_eq!(logical_to_physical(-1, 8, StepSel::Sixteenth), -1);
        assert_eq!(physical_to_logical(256, 8, StepSel::Sixteenth), 4096);
        // full steps on full steps
        assert_eq!(logical_to_physical(-7, 0, StepSel::Full), -7);
    }

    #[test]
    fn full_step_rates_round_up() {
        // 1000 logical 1/16 steps/s = 62.5 full steps/s
        assert_eq!(full_steps_q16_from_logical(1000, 4), 62 * 65536 + 32768);
        assert_eq!(full_steps_q16_from_logical(1, 8), 256);
        assert_eq!(full_steps_q16_from_logical(3, 1), 98_304);
    }

    #[test]
    fn speed_register_from_profile_velocity() {
        // 1 logical full step per 1 ms tick = 1000 full steps/s = 67108.864 SPEED
        assert_eq!(speed_reg_from_internal(1 << 32, 1000, 0), 67_108);
        // same speed in 1/128 logical steps = 1000/128 full steps/s
        assert_eq!(speed_reg_from_internal(1 << 32, 1000, 7), 524);
        assert_eq!(speed_reg_from_internal(-(1 << 32), 1000, 0), -67_108);
    }

    #[test]
    fn correction_of_one_full_step_over_eight_ticks() {
        // 128 microsteps (one full step at 1/128) in 8 ms = 125 full steps/s = 8388.6 SPEED
        assert_eq!(
            correction_speed_reg(128, 1000, StepSel::OneTwentyEighth, 8),
            8388
        );
        assert_eq!(
            correction_speed_reg(-128, 1000, StepSel::OneTwentyEighth, 8),
            -8388
        );
    }
}
