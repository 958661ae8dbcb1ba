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
//! * **The profile never asks for more than the chip can do.** The limits the
//!   profile runs with are the requested ones clamped to what a powerSTEP01
//!   can follow in the current step mode ([`units::limit_cap`]), and, while
//!   the chip may be moving, to what the ACC/DEC it is programmed with can
//!   follow ([`units::ramp_capability`]): ACC/DEC are writable only while the
//!   chip is stopped, so higher ramps take effect at the next start from
//!   rest, lower ones at once (never so low that the axis would pass a
//!   target it can still stop on: see [`Profile`]).
//! * **Exact landing.** When the profile has settled on its target the axis
//!   sends SoftStop, waits for the chip to report not-busy, then sends
//!   `GoTo(target)`: the chip covers the last few microsteps itself and cannot
//!   overshoot. The axis is settled when STATUS says not busy and ABS_POS
//!   equals the target. A `Run` toward the target is never faster than the
//!   chip can still stop from before it, from where it is estimated to be
//!   (`units::cap_to_stop`): a chip that got ahead of the profile (a late
//!   or skipped tick, which it ran through at its last speed) brakes
//!   earlier, and passes the target by no more than it ran in that time.
//! * **Every accepted command takes effect, in order.** A stop or Set zero
//!   in progress never discards a target, speed or zero given after it: when
//!   the chip has stopped, the profile is re-based (to the chip's position,
//!   or to 0 for Set zero) and keeps what it was asked to do since. Set zero
//!   is in effect at once for every read ([`Axis::actual_position`] is 0 from
//!   the call on) and a target given after it is in the new coordinates.
//! * **Wide positions.** ABS_POS is 22 bits; every read is unwrapped against
//!   the previous one (moves between two reads are far below 2²¹ microsteps),
//!   so the axis position is an `i64` and moves longer than 2²¹ work. The
//!   landing GoTo uses the chip's 22-bit shortest path, which is right because
//!   the residual at landing is a few microsteps. A read that went out in the
//!   same batch before a write of ABS_POS (ResetPos, re-basing) is discarded.
//! * **Units.** The profile runs in logical steps (PoStep60 step mode
//!   0 = full … 8 = 1/256); the chip in physical microsteps (STEP_SEL). The
//!   conversions are exact power-of-two scalings ([`units`]); a logical mode
//!   finer than the physical one lands on the physical microstep at or below
//!   the logical target.
//! * **The chip's configuration is the bridge's.** Every register the
//!   bridge configures (STEP_MODE, CONFIG, the current registers, MAX_SPEED,
//!   ACC, DEC, ABS_POS, and any other register given to
//!   [`Axis::set_register`]) is written at setup, and the chip is configured
//!   ([`Axis::is_configured`]) only once all of them have been written since
//!   its last reset. A reset or undervoltage (UVLO flag, also one seen in the
//!   middle of a setup) stops the profile where the chip actually was (never
//!   a jump in the commanded position), counts it ([`Axis::chip_resets`]),
//!   and runs the whole setup again with ABS_POS re-based to the axis
//!   position.
//! * **The chip saying no.** CMD_ERROR after a GoTo retries the landing. A
//!   bridge fault (overcurrent, thermal shutdown) stops the profile at the
//!   read-back position and switches the bridges off.

// Microstep positions are i64 (22-bit chip reads unwrapped, far from the i64
// range), speeds and ticks are bounded by the chip's caps; the rate estimate
// uses checked or saturating operations where its inputs are unbounded.
#![allow(clippy::arithmetic_side_effects)]

use super::divisor::Recalled;
use super::homing::{Homing, HomingError, HomingParams, HomingState, Seen, Step};
use super::profile::{Limits, Mode, Profile};
use super::units::{self, LIMIT_CAPS};
pub use super::units::{logical_to_physical, physical_to_logical, MAX_LOGICAL_SHIFT};

use crate::powerstep::chain::{Plan, Replies, ScheduleError, StreamRead, MAX_COMMANDS};
use crate::powerstep::commands::{Command, Direction, SPEED_MAX};
use crate::powerstep::fields::{DriveMode, StepMode, StepSel};
use crate::powerstep::registers::{sign_extend_22, wrap_22, Register};
use crate::powerstep::status::Status;
use crate::powerstep::status::ThermalStatus;

/// The following error is corrected over this many ticks.
pub const CORRECTION_TICKS: i64 = 8;

/// The correction period in ticks for a tick of `tick_us`: 8 ms (8 ticks at
/// 1 kHz, 40 at 5 kHz), so the correction is as gentle at any tick rate.
pub const fn correction_ticks(tick_us: u32) -> i64 {
    let t = CORRECTION_TICKS * 1000 / if tick_us == 0 { 1 } else { tick_us as i64 };
    if t < 1 {
        1
    } else {
        t
    }
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
    /// Writing the chip's configuration (the setup phase, see [`Axis::plan`]).
    Setup(u8),
    /// At rest, holding.
    Idle,
    /// Streaming Run setpoints.
    Streaming,
    /// A stop command sent (end of a move, Stop, Set zero…); waiting for not-busy.
    Stopping,
    /// GoTo sent; waiting for not-busy on the target.
    Landing,
    /// Running the homing sequence (`super::homing`).
    Homing,
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
    /// End of a move: land on the profile's target with GoTo.
    Land,
    /// Stop, Set zero, sleep, step-mode change: stay where the chip stopped
    /// (and start whatever was asked for since from there).
    Hold,
}

/// Setup phases (the `u8` of [`AxisState::Setup`]).
mod phase {
    /// HardHiZ: bridges off, motor stopped (WH and WS registers writable).
    pub const HIZ: u8 = 0;
    /// Every configuration register of the image.
    pub const IMAGE: u8 = 1;
    pub const MAX_SPEED: u8 = 2;
    pub const ACC: u8 = 3;
    pub const DEC: u8 = 4;
    /// ABS_POS re-based to the axis position; then the axis is configured.
    pub const ABS_POS: u8 = 5;
}

/// Requested limits and the motion registers as programmed on the chip.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct LimitState {
    /// As set by [`Axis::set_limits`] (logical units of the current step mode).
    requested: Limits,
    /// MAX_SPEED, ACC, DEC registers as written (0: not since the last reset).
    max_speed: u32,
    acc: u32,
    dec: u32,
    /// (profile max speed, its MAX_SPEED backstop register), cached.
    backstop: (u32, u32),
}

/// What the chip reported, and when.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Readback {
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
    /// What this tick's plan reads (moved into `in_flight` when the plan
    /// is made).
    read: Option<Read>,
    /// The batches planned and not yet absorbed, oldest first: one with a
    /// tick that plans, clocks and absorbs a batch before the next plan;
    /// two with the overlapped tick, which plans batch k + 1 while batch k
    /// is on the bus.
    in_flight: InFlight,
    status: Status,
    /// Tick of the last one-shot command, the last STATUS and ABS_POS reads
    /// (u64: never wraps, so the ordering checks hold for any uptime).
    sent_at: u64,
    status_at: u64,
    pos_at: u64,
    /// Tick at which the current setup began (a UVLO read after it is a new reset).
    setup_at: u64,
}

/// What a batch read, as the plan that sent it knew it: its replies are
/// taken with these, however many plans came after it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Sent {
    /// The tick of the plan (the stamp of what it reads).
    tick: u64,
    /// Where the chip should be as the read reaches it (valid unless the
    /// profile has jumped since, to where the chip is: a following error
    /// against the old profile means nothing).
    expected: i64,
    /// The clock-rate estimate's command sum and window epoch at the plan.
    commanded: i64,
    epoch: u32,
    read: Option<Read>,
    expected_valid: bool,
    /// The plan sent more than its read.
    commands: bool,
}

impl Sent {
    const NONE: Sent = Sent {
        tick: 0,
        expected: 0,
        commanded: 0,
        epoch: 0,
        read: None,
        expected_valid: false,
        commands: false,
    };
}

/// The batches in flight, oldest first (at most two: the overlapped tick's
/// batch on the bus and the one planned behind it), a ring of two.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct InFlight {
    slots: [Sent; 2],
    /// The oldest one's slot (0 or 1) and how many there are (0 to 2).
    head: u8,
    len: u8,
}

impl InFlight {
    const EMPTY: InFlight = InFlight {
        slots: [Sent::NONE; 2],
        head: 0,
        len: 0,
    };

    /// [`InFlight::push_slot`] filled with `s` (the tests' records).
    #[cfg(test)]
    fn push(&mut self, s: Sent) {
        *self.push_slot() = s;
    }

    /// A new plan's record, its slot to be filled in place (a third drops
    /// the oldest: a tick that planned without ending its batch, whose
    /// replies never come).
    #[inline]
    fn push_slot(&mut self) -> &mut Sent {
        if self.len == 2 {
            self.head ^= 1;
            self.len = 1;
        }
        let [a, b] = &mut self.slots;
        let slot = if (self.head ^ self.len) & 1 == 0 {
            a
        } else {
            b
        };
        self.len += 1;
        slot
    }

    /// The oldest batch's record (its replies are being absorbed).
    #[inline]
    fn pop(&mut self) -> Option<Sent> {
        if self.len == 0 {
            return None;
        }
        let s = self.slots.get(usize::from(self.head & 1)).copied();
        self.head ^= 1;
        self.len -= 1;
        s
    }

    /// The records in flight.
    fn each(&mut self, mut f: impl FnMut(&mut Sent)) {
        for k in 0..self.len {
            if let Some(s) = self.slots.get_mut(usize::from((self.head ^ k) & 1)) {
                f(s);
            }
        }
    }

    /// A batch in flight carries commands (not only its read): until its
    /// replies are in, the chip may not have them.
    fn commands(&self) -> bool {
        let [a, b] = &self.slots;
        match (self.len, self.head) {
            (0, _) => false,
            (1, 0) => a.commands,
            (1, _) => b.commands,
            _ => a.commands || b.commands,
        }
    }

    /// The profile jumped: no batch in flight measures a following error.
    fn void_expected(&mut self) {
        self.each(|s| s.expected_valid = false);
    }

    /// Forget what the batches in flight read of `kind` (`None`: every read).
    fn drop_reads(&mut self, kind: Option<Read>) {
        self.each(|s| {
            if kind.is_none() || s.read == kind {
                s.read = None;
            }
        });
    }
}

/// The stop in progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct StopState {
    /// One-shot stop command to send at the next plan.
    pending: Option<Command>,
    after: AfterStop,
    /// Set zero accepted: the position where the chip stops becomes 0.
    zero: bool,
}

/// One axis: profile generator + output stage for one chip of the chain.
#[derive(Clone, Debug)]
pub struct Axis {
    cfg: AxisConfig,
    /// Divisors of the per-tick speed conversions (follow `cfg`).
    speed_div: Recalled,
    corr_div: Recalled,
    /// [`units::cap_to_stop`] for the profile's deceleration.
    stop_cap: units::StopCap,
    /// The inputs `stop_cap` and the ramp capabilities were worked out for.
    memo: LimitMemo,
    profile: Profile,
    state: AxisState,
    limits: LimitState,
    rb: Readback,
    image: ChipImage,
    stop: StopState,
    fault: Option<AxisFault>,
    /// Control ticks planned so far.
    tick: u64,
    /// One-shot command to send while idle (wake up: HardStop).
    idle_command: Option<Command>,
    /// Bridges switched off on request: motion commands are not executed.
    asleep: bool,
    /// Bridges switched off after an overcurrent/thermal shutdown (until the
    /// chip reports healthy again).
    chip_off_for_fault: bool,
    /// Chip resets / undervoltages detected since boot.
    resets: u32,
    /// The homing sequence (running or its last outcome).
    homing: Option<Homing>,
    /// Homing started: ACC/DEC get the axis's limits before its first phase.
    homing_ramps: bool,
    /// A homing phase's commands not yet sent (a batch with little room
    /// takes them over several ticks, in order).
    homing_out: [Option<Command>; 2],
    /// Position 0 is the home switch's edge (until a chip reset, a chain
    /// error or a stall says otherwise).
    homed: bool,
    /// The chip's ABS_POS frame was re-based by the chip (homing): take the
    /// next position read as it is, not unwrapped against the last one.
    absolute_read: bool,
    /// A chip register read for the extension space.
    ext_read: Option<RegRead>,
    /// The chip's oscillator against the control tick (see [`ClockRate`]).
    rate: ClockRate,
    /// A member of a coordinated move ([`Axis::follow`]).
    lead: Option<lead::LeadMark>,
}

/// What [`Axis::refresh_limits`] last worked out, by its inputs: both are
/// pure functions of them, and a move start asks for both.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct LimitMemo {
    /// (ACC, DEC registers, logical shift) and their ramp capabilities.
    ramps: Option<(RampKey, (u32, u32))>,
    /// (deceleration, logical shift, STEP_SEL) of `stop_cap`.
    stop_cap: Option<(u32, u8, StepSel)>,
    /// Another stop cap and its inputs: the one before `stop_cap`, or the
    /// next move's ([`Axis::warm_start`]); a start and its stop alternate
    /// between two.
    other_stop_cap: Option<((u32, u8, StepSel), units::StopCap)>,
    /// (the requested limits, logical shift) and the ACC and DEC registers
    /// a move's start writes for them.
    start: Option<((Limits, u8), (u32, u32))>,
    /// A position target and its physical microsteps (the stop cap asks
    /// every tick; put back to (0, 0) when the logical step changes, the
    /// only input besides the target that can).
    target: (i64, i64),
}

/// The chip's ACC and DEC registers and the logical step mode.
type RampKey = (u32, u32, u8);

/// A read of a chip register asked for by the extension space.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct RegRead {
    reg: Register,
    /// The plan's tick and the command index of the GetParam in its
    /// batch, once sent.
    index: Option<(u64, usize)>,
    /// The value and the tick it was read at.
    value: Option<(u32, u64)>,
    /// The batch had no room for it after the regular read (a window
    /// budget): the next position read's slot carries it instead.
    lead: bool,
}

/// A register value read for the extension space stays good this many ticks.
pub const REGISTER_READ_FRESH_TICKS: u64 = 20;

impl Axis {
    pub fn new(cfg: AxisConfig, limits: Limits) -> Axis {
        let cfg = AxisConfig {
            logical_shift: cfg.logical_shift.min(MAX_LOGICAL_SHIFT),
            ..cfg
        };
        let mut image = ChipImage::new();
        image.set(Register::StepMode, u32::from(cfg.step_mode().to_reg()));
        // The Run setpoints need a start speed of 0 (homing changes it for
        // ReleaseSW and puts it back).
        image.set(Register::MinSpeed, 0);
        let mut axis = Axis {
            cfg,
            speed_div: Recalled::new(units::speed_divisor(cfg.tick_us, cfg.logical_shift)),
            corr_div: Recalled::new(units::correction_divisor(
                cfg.tick_us,
                cfg.step,
                correction_ticks(cfg.tick_us),
            )),
            stop_cap: units::StopCap::new(limits.dec, cfg.logical_shift, cfg.step),
            memo: LimitMemo {
                ramps: None,
                stop_cap: None,
                other_stop_cap: None,
                start: None,
                target: (0, 0),
            },
            profile: Profile::new(cfg.tick_us, limits),
            state: AxisState::Setup(phase::HIZ),
            limits: LimitState {
                requested: limits,
                max_speed: 0,
                acc: 0,
                dec: 0,
                backstop: (0, 0),
            },
            rb: Readback {
                chip_pos: 0,
                raw: None,
                pos_at_status: 0,
                expected_at_read: 0,
                error: 0,
                read: None,
                in_flight: InFlight::EMPTY,
                status: Status::IDLE,
                sent_at: 0,
                status_at: 0,
                pos_at: 0,
                setup_at: 1,
            },
            image,
            stop: StopState {
                pending: None,
                after: AfterStop::Land,
                zero: false,
            },
            fault: None,
            tick: 0,
            idle_command: None,
            asleep: false,
            chip_off_for_fault: false,
            resets: 0,
            homing: None,
            homing_ramps: false,
            homing_out: [None, None],
            homed: false,
            absolute_read: false,
            ext_read: None,
            rate: ClockRate::NEW,
            lead: None,
        };
        axis.refresh_limits();
        axis
    }

    /// Write this CONFIG value at setup (e.g. SW_MODE = 1 so the switch input
    /// only raises an event and the bridge decides what it means).
    pub fn with_chip_config(mut self, config: u16) -> Axis {
        self.image.set(Register::Config, u32::from(config));
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
        self.rb.status
    }
    /// Following error at the last position read, in physical microsteps.
    pub fn following_error(&self) -> i64 {
        self.rb.error
    }
    /// The chip's unwrapped position in physical microsteps.
    pub fn chip_position(&self) -> i64 {
        self.rb.chip_pos
    }
    /// Actual position in logical steps (from the chip's read-back); 0 from
    /// the moment Set zero is accepted.
    pub fn actual_position(&self) -> i64 {
        if self.stop.zero {
            return 0;
        }
        physical_to_logical(self.rb.chip_pos, self.cfg.logical_shift, self.cfg.step)
    }
    /// Where the profile wants the axis (logical steps, nearest).
    pub fn required_position(&self) -> i64 {
        match self.profile.mode() {
            Mode::Position(t) => t,
            _ => self.profile.position_round(),
        }
    }
    /// How fast the chip's oscillator runs against the control tick, as
    /// estimated while cruising (Q16: 65 536 = equal; see `ClockRate`).
    pub fn clock_ratio_q16(&self) -> u32 {
        self.rate.ratio
    }

    /// Chip resets or undervoltages detected since boot (each one re-ran the setup).
    pub fn chip_resets(&self) -> u32 {
        self.resets
    }
    /// Why the last motion was cut short, if it was (cleared by the next move).
    pub fn fault(&self) -> Option<AxisFault> {
        self.fault
    }
    /// Nothing moving: profile settled, chip landed and confirmed, and
    /// every command has reached the chip (no batch in flight carries more
    /// than its read: what a reset or a save waits for).
    pub fn is_settled(&self) -> bool {
        self.is_at_rest() && !self.rb.in_flight.commands()
    }

    /// Nothing moving: profile settled, chip landed and confirmed (a
    /// register write may still be on its way: the idle-current timer and
    /// the panel's lamp do not count it as motion).
    pub fn is_at_rest(&self) -> bool {
        matches!(self.state, AxisState::Idle) && self.profile.is_settled()
    }
    /// Every register the bridge configures has been written since the
    /// chip's last reset.
    pub fn is_configured(&self) -> bool {
        !matches!(self.state, AxisState::Setup(_))
    }
    /// What the bridge configures in `reg` on this axis's chip: the chip
    /// image's value, or for MAX_SPEED, ACC and DEC the value last written
    /// (None before the set-up wrote it, and for every register the bridge
    /// does not configure: ABS_POS, EL_POS, MARK, SPEED, ADC_OUT, STATUS).
    pub fn programmed(&self, reg: Register) -> Option<u32> {
        let written = match reg {
            Register::MaxSpeed => self.limits.max_speed,
            Register::Acc => self.limits.acc,
            Register::Dec => self.limits.dec,
            _ => return self.image.get(reg),
        };
        (!matches!(self.state, AxisState::Setup(_)) || written != 0).then_some(written)
    }

    /// The registers the bridge configures on the chip and their values.
    pub fn chip_image(&self) -> &ChipImage {
        &self.image
    }
    /// Limits as requested (before any clamp).
    pub fn requested_limits(&self) -> Limits {
        self.limits.requested
    }
    /// The fastest limits the chip can follow in the current step mode.
    pub fn limit_cap(&self) -> Limits {
        Self::cap(self.cfg.logical_shift)
    }
    fn cap(shift: u8) -> Limits {
        LIMIT_CAPS
            .get(usize::from(shift))
            .copied()
            .unwrap_or(LIMIT_CAPS[0])
    }
}

mod commands;
mod image;
mod lead;
mod plan;
mod rate;
mod readback;
#[cfg(test)]
mod tests;

pub use image::ChipImage;
use rate::ClockRate;
pub use rate::{RATE_MAX_ERROR, RATE_READS, RATE_WINDOW};
