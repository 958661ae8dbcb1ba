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

use super::divisor::Divisor;
use super::homing::{Homing, HomingError, HomingParams, HomingState, Seen, Step};
use super::profile::{Limits, Mode, Profile};
use super::units::{self, LIMIT_CAPS};
pub use super::units::{logical_to_physical, physical_to_logical, MAX_LOGICAL_SHIFT};

use crate::powerstep::chain::{Replies, MAX_COMMANDS};
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

/// Registers the bridge configures on the chip (besides the motion
/// registers MAX_SPEED, ACC, DEC, ABS_POS), with the values it wants there
/// and which of them still have to be written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChipImage {
    /// Wanted values, index = address − 1.
    values: [u32; 27],
    /// Bit `address`: the bridge configures this register.
    owned: u32,
    /// Bit `address`: not written since the last reset or change.
    dirty: u32,
    /// Bit `address`: written since the last GetStatus went out (the next
    /// STATUS says whether the chip took it).
    unconfirmed: u32,
    /// Bit `address`: written before the GetStatus now in flight; its
    /// CMD_ERROR puts them back on the list ([`ChipImage::refused`]).
    checking: u32,
}

impl ChipImage {
    const fn new() -> ChipImage {
        ChipImage {
            values: [0; 27],
            owned: 0,
            dirty: 0,
            unconfirmed: 0,
            checking: 0,
        }
    }

    /// Want `value` in `reg` (masked to its width).
    fn set(&mut self, reg: Register, value: u32) {
        let value = value & reg.mask();
        let bit = 1u32 << reg.address();
        let slot = self.values.get_mut(usize::from(reg.address()) - 1);
        if let Some(slot) = slot {
            if self.owned & bit == 0 || *slot != value {
                *slot = value;
                self.owned |= bit;
                self.dirty |= bit;
            }
        }
    }

    /// The wanted value of `reg`, if the bridge configures it.
    pub fn get(&self, reg: Register) -> Option<u32> {
        if self.owned & (1 << reg.address()) == 0 {
            return None;
        }
        self.values.get(usize::from(reg.address()) - 1).copied()
    }

    /// The chip was reset: every owned register has to be written again.
    fn on_reset(&mut self) {
        self.dirty = self.owned;
        self.unconfirmed = 0;
        self.checking = 0;
    }

    /// Nothing left to write.
    pub fn is_clean(&self) -> bool {
        self.dirty == 0
    }

    /// Configured registers not yet written (since the last reset or change).
    pub fn pending(&self) -> u32 {
        (self.dirty & self.owned).count_ones()
    }

    /// The next register to write: STEP_MODE, then CONFIG, then by address,
    /// among those `allowed` accepts.
    fn next(&self, allowed: impl Fn(Register) -> bool) -> Option<(Register, u32)> {
        // The control tick asks every tick; almost always nothing is dirty.
        if self.dirty == 0 {
            return None;
        }
        let first = [Register::StepMode, Register::Config];
        first
            .into_iter()
            .chain(Register::all())
            .filter(|r| self.dirty & (1 << r.address()) != 0 && allowed(*r))
            .find_map(|r| self.get(r).map(|v| (r, v)))
    }

    fn written(&mut self, reg: Register) {
        let bit = 1u32 << reg.address();
        self.dirty &= !bit;
        self.unconfirmed |= bit;
    }

    /// A GetStatus goes out: the writes before it are what its CMD_ERROR
    /// would be about.
    fn status_requested(&mut self) {
        self.checking |= self.unconfirmed;
        self.unconfirmed = 0;
    }

    /// That STATUS came back: with CMD_ERROR the chip refused a command
    /// since the previous one — maybe one of these writes — so they are
    /// written again (the same values: harmless if the refusal was another
    /// command's). A register is written only once the chip has taken it.
    fn status_seen(&mut self, cmd_error: bool) {
        if cmd_error {
            self.dirty |= self.checking & self.owned;
        }
        self.checking = 0;
    }

    /// Write `reg` again (if owned) at the next chance.
    fn touch(&mut self, reg: Register) {
        let bit = 1u32 << reg.address();
        self.dirty |= self.owned & bit;
    }
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
    /// What was read this tick (decoded in `absorb`).
    read: Option<Read>,
    status: Status,
    /// Tick of the last one-shot command, the last STATUS and ABS_POS reads
    /// (u64: never wraps, so the ordering checks hold for any uptime).
    sent_at: u64,
    status_at: u64,
    pos_at: u64,
    /// Tick at which the current setup began (a UVLO read after it is a new reset).
    setup_at: u64,
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
    speed_div: Divisor,
    corr_div: Divisor,
    /// [`units::cap_to_stop`] for the profile's deceleration.
    stop_cap: units::StopCap,
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
}

/// How fast the chip's time runs against the bridge's: the powerSTEP01's
/// internal oscillator is a few % off 16 MHz, so a `Run` at speed `s` moves
/// it `ratio · s`. Without this a proportional correction leaves a following
/// error of `ratio − 1` times the speed times the correction period (3.6 full
/// steps at ±5 % in the random scenario) and a move passes its target by
/// several microsteps before it lands.
///
/// Estimated while streaming at a steady profile speed (cruising: a ramp
/// makes the chip move less than commanded) from what was commanded and
/// what the chip moved between position reads: over windows of at least
/// [`RATE_WINDOW`] microsteps while the chip follows (following error ≤
/// [`RATE_MAX_ERROR`], speed below its MAX_SPEED), `ratio = moved /
/// commanded` (clamped to ±10 %; the first window's estimate is taken as
/// it is — the only division, once per axis —, later windows correct it by a
/// division-free step); every `Run` speed is then divided by it (a multiply
/// by the Q16 reciprocal, kept by Newton steps).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct ClockRate {
    /// chip time / bridge time, Q16 (65 536: equal).
    ratio: u32,
    /// 2³² / ratio.
    inv: u32,
    /// SPEED of the last `Run` (signed, as sent): what the chip runs at.
    running: i64,
    /// Sum of `running` over the ticks since the last position read.
    since_read: i64,
    /// Window sums: commanded (SPEED · ticks) and moved (microsteps).
    cmd: i64,
    moved: i64,
    /// The last position read came while streaming: a window may go on.
    armed: bool,
    /// The profile kept its speed at the last tick: the chip ran at
    /// `running` the whole tick (while the profile ramps, the chip ramps
    /// toward each new speed with its ACC and moves less than commanded).
    steady: bool,
    /// Windows taken so far (the first one replaces the default).
    estimates: u32,
    /// Position reads in the current window.
    reads: u32,
}

/// The clock-rate estimate's bounds, Q16 (±10 %).
const RATIO_MIN: i64 = 58_982;
const RATIO_MAX: i64 = 72_090;

/// Microsteps a window of the clock-rate estimate must cover.
pub const RATE_WINDOW: i64 = 1024;
/// Position reads a window must span after the first estimate (64 ticks).
pub const RATE_READS: u32 = 32;
/// A window ends when the following error exceeds this (microsteps): the
/// chip is not following the `Run` speeds then (still stopping, landing).
pub const RATE_MAX_ERROR: i64 = 64;

impl ClockRate {
    const NEW: ClockRate = ClockRate {
        ratio: 1 << 16,
        inv: 1 << 16,
        running: 0,
        since_read: 0,
        cmd: 0,
        moved: 0,
        armed: false,
        steady: false,
        estimates: 0,
        reads: 0,
    };

    /// The window ends (the chip did something else than follow `Run`).
    fn disarm(&mut self) {
        self.armed = false;
        self.reads = 0;
        self.cmd = 0;
        self.moved = 0;
        self.since_read = 0;
        self.running = 0;
    }

    /// A position read while streaming: the chip moved `moved` microsteps
    /// since the last one under the `since_read` commands.
    fn take(&mut self, moved: i64, tick_us: u32, step_shift: u32) {
        if self.armed {
            self.cmd = self.cmd.saturating_add(self.since_read);
            self.moved = self.moved.saturating_add(moved);
        }
        self.since_read = 0;
        self.armed = true;
        self.reads = self.reads.saturating_add(1);
        // A window covers RATE_WINDOW microsteps; after the first estimate
        // also RATE_READS reads (a fast axis would update every tick).
        if self.moved.abs() < RATE_WINDOW || (self.estimates > 0 && self.reads < RATE_READS) {
            return;
        }
        self.reads = 0;
        let (cmd, moved) = (self.cmd, self.moved);
        self.cmd = 0;
        self.moved = 0;
        if cmd == 0 || (cmd < 0) != (moved < 0) {
            return;
        }
        // Expected microsteps at ratio 1: cmd · tick_us · 2^(S+2) / 2²⁸.
        let Some(e) = cmd
            .checked_mul(i64::from(tick_us.max(1)))
            .and_then(|x| x.checked_mul(1 << (step_shift.min(8) + 2)))
            // Rounded (a floor would bias every window by up to a microstep).
            .map(|x| (x + (1 << 27)) >> 28)
            .filter(|x| *x != 0)
        else {
            return;
        };
        if self.estimates == 0 {
            // The first window sets the ratio outright: one division per
            // axis, ever (later windows correct it without dividing).
            let Some(num) = moved.checked_mul(1 << 16) else {
                return;
            };
            self.ratio = (num / e).clamp(RATIO_MIN, RATIO_MAX) as u32;
            self.inv = ((1u64 << 32) / u64::from(self.ratio)) as u32;
        } else {
            // Later windows: ratio += (moved − predicted) / expected, the
            // division by `expected` replaced by a shift by its bit length
            // (2^(len−1) ≤ |e| < 2^len), which takes a quarter to half of the
            // step: a few windows converge, no window overshoots.
            let predicted = (e * i64::from(self.ratio) + (1 << 15)) >> 16;
            let len = 64 - e.unsigned_abs().leading_zeros();
            let step = moved.saturating_sub(predicted).saturating_mul(1 << 16) >> len;
            let step = if e < 0 { -step } else { step };
            self.ratio = (i64::from(self.ratio) + step).clamp(RATIO_MIN, RATIO_MAX) as u32;
            // 1/ratio by two Newton steps from the last one (it moved little).
            for _ in 0..2 {
                let r = u64::from(self.ratio);
                let inv = u64::from(self.inv);
                let corr = (2u64 << 16).saturating_sub((r * inv) >> 16);
                self.inv = ((inv * corr) >> 16) as u32;
            }
        }
        self.estimates = self.estimates.saturating_add(1);
    }

    /// A SPEED the chip runs at the bridge's rate, in its own time.
    fn scale(&self, speed: u64) -> u64 {
        (speed * u64::from(self.inv)) >> 16
    }
}

/// A read of a chip register asked for by the extension space.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct RegRead {
    reg: Register,
    /// Command index of the GetParam in this tick's batch, once sent.
    index: Option<usize>,
    /// The value and the tick it was read at.
    value: Option<(u32, u64)>,
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
            speed_div: units::speed_divisor(cfg.tick_us, cfg.logical_shift),
            corr_div: units::correction_divisor(
                cfg.tick_us,
                cfg.step,
                correction_ticks(cfg.tick_us),
            ),
            stop_cap: units::StopCap::new(limits.dec, cfg.logical_shift, cfg.step),
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
            homed: false,
            absolute_read: false,
            ext_read: None,
            rate: ClockRate::NEW,
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
    /// Nothing moving: profile settled, chip landed and confirmed.
    pub fn is_settled(&self) -> bool {
        self.state == AxisState::Idle && self.profile.is_settled()
    }
    /// Every register the bridge configures has been written since the
    /// chip's last reset.
    pub fn is_configured(&self) -> bool {
        !matches!(self.state, AxisState::Setup(_))
    }
    /// The registers the bridge configures on the chip and their values.
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

    // ------------------------------------------------------ motion commands

    /// Move to `target` logical steps (ignored while asleep or homing: the
    /// device layer refuses motion requests then).
    pub fn move_to(&mut self, target: i64) {
        if self.asleep || self.is_homing() {
            return;
        }
        self.fault = None;
        self.profile.move_to(target);
    }
    /// Run at a signed speed (logical steps/s; ignored while asleep or homing).
    pub fn run_at(&mut self, steps_per_s: i32) {
        if self.asleep || self.is_homing() {
            return;
        }
        self.fault = None;
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
        if self.state == AxisState::Homing {
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
        if self.state != AxisState::Idle || !self.profile.is_settled() || self.asleep {
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
        self.homing = Some(Homing::start(params, pressed, self.rb.chip_pos, self.tick));
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
        self.state == AxisState::Homing
    }

    /// End a running homing sequence with `e` (the caller stops the chip).
    fn end_homing(&mut self, e: HomingError) {
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
        self.speed_div = units::speed_divisor(self.cfg.tick_us, shift);
        if self.stop.zero {
            self.profile.set_position(0);
        } else {
            // Exactly where the chip is, in the new unit.
            self.profile.set_position_fine(self.chip_fine());
        }
        self.limits.backstop = (0, 0);
        if !matches!(self.state, AxisState::Setup(_) | AxisState::Idle) {
            self.stop_then(AfterStop::Hold, self.stop_command());
        }
        self.refresh_limits();
    }
    /// Decelerate to a stop with the profile's deceleration. An axis at rest,
    /// or already stopping at once, has nothing to do.
    pub fn soft_stop(&mut self) {
        if self.state == AxisState::Homing {
            self.end_homing(HomingError::Aborted);
            self.stop_then(AfterStop::Hold, Command::SoftStop);
            return;
        }
        if self.state == AxisState::Stopping && self.stop.after == AfterStop::Hold {
            self.profile.stop_now();
        } else if !self.profile.is_settled() {
            self.profile.soft_stop();
        }
    }
    /// Stop at once, no ramp (HardStop), and hold where the chip stopped
    /// (no landing move: after an end switch that could go back into it).
    /// An axis that is asleep stays in HiZ.
    pub fn stop_now(&mut self) {
        if self.state == AxisState::Homing {
            self.end_homing(HomingError::Aborted);
        }
        self.profile.stop_now();
        self.stop_then(AfterStop::Hold, self.stop_command());
    }
    /// Stop at once and make the position where the chip stops zero. In
    /// effect at once: the position reads 0 and a target given from now on
    /// is in the new coordinates.
    pub fn set_zero(&mut self) {
        if self.state == AxisState::Homing {
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
        if self.state == AxisState::Homing {
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
    fn effective_limits(&self) -> Limits {
        let shift = self.cfg.logical_shift;
        let mut l = units::clamp_to_chip(self.limits.requested, shift);
        let chip_may_move = !matches!(self.state, AxisState::Idle | AxisState::Setup(_));
        if chip_may_move {
            l.acc = l.acc.min(units::ramp_capability(self.limits.acc, shift));
            l.dec = l.dec.min(units::ramp_capability(self.limits.dec, shift));
        }
        l
    }

    fn refresh_limits(&mut self) {
        let l = self.effective_limits();
        if l != self.profile.limits() {
            self.profile.set_limits(l);
        }
        self.stop_cap = units::StopCap::new(l.dec, self.cfg.logical_shift, self.cfg.step);
    }

    fn stop_then(&mut self, after: AfterStop, cmd: Command) {
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
    fn restart_setup(&mut self) {
        if self.state == AxisState::Homing {
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
        self.rb.raw = None;
        self.rb.error = 0;
        self.rb.read = None;
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

    // ------------------------------------------------------------ per tick

    /// The chip's position in the profile's units (2⁻³³ logical steps), exact.
    fn chip_fine(&self) -> i128 {
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
        let s = i128::from(self.cfg.step.shift());
        let l = i128::from(self.cfg.logical_shift);
        // fine is in 2⁻³³ logical steps; physical = logical · 2^(S−L)
        let shift = 33 - s + l;
        (fine >> shift) as i64
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
        if !self.is_configured() {
            return;
        }
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
            if r.value.is_none() && r.index.is_none() && used < MAX_COMMANDS {
                let same_as_read =
                    r.reg == Register::AbsPos && self.rb.read == Some(Read::Position);
                if !same_as_read && emit(Command::GetParam(r.reg)) {
                    r.index = Some(used);
                }
            }
        }
    }

    /// A STATUS read after the last command shows the bridges off (HiZ)
    /// and the motor stopped.
    fn hiz_confirmed(&self) -> bool {
        let s = self.rb.status;
        s.hiz() && !s.busy() && self.rb.status_at > self.rb.sent_at
    }

    /// Whether the chip takes a write of `reg` now, as far as its last
    /// STATUS shows: WR registers always; WH ones only in HiZ
    /// ([`Axis::hiz_confirmed`]) if the chip `stays_hiz` (nothing before the
    /// write in this tick ends HiZ); WS ones then too, or while the axis is
    /// idle (the chip was confirmed stopped), STATUS says not busy and the
    /// chip `stays_still` through the write.
    fn chip_takes(&self, reg: Register, stays_still: bool, stays_hiz: bool) -> bool {
        use crate::powerstep::registers::Access;
        let hiz = stays_hiz && self.hiz_confirmed();
        let stopped =
            hiz || (self.state == AxisState::Idle && stays_still && !self.rb.status.busy());
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
    fn write_before_leaving_rest(&mut self, emit: &mut impl FnMut(Command) -> bool) -> bool {
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
    fn hiz_write_waiting(&self) -> bool {
        use crate::powerstep::registers::Access;
        let s = self.rb.status;
        let hiz_disproved = self.rb.status_at > self.rb.sent_at && !s.hiz();
        !hiz_disproved && self.image.next(|r| r.access() == Access::WhenHiZ).is_some()
    }

    fn plan_commands(&mut self, mut emit: impl FnMut(Command) -> bool) {
        self.tick = self.tick.wrapping_add(1);
        // The tick that just ended ran at the last Run's speed.
        // Not while the chip's MAX_SPEED caps it (SPEED = MAX_SPEED · 2¹⁰).
        let capped = self.rate.running.unsigned_abs() >= u64::from(self.limits.max_speed) << 10;
        if self.state == AxisState::Streaming && self.rate.steady && !capped {
            self.rate.since_read = self.rate.since_read.saturating_add(self.rate.running);
        } else {
            self.rate.disarm();
        }
        let read = if self.tick % 2 == 0 {
            Read::Position
        } else {
            Read::Status
        };
        let read_cmd = match read {
            Read::Position => Command::GetParam(Register::AbsPos),
            Read::Status => Command::GetStatus,
        };
        self.rb.read = if emit(read_cmd) { Some(read) } else { None };
        if self.rb.read == Some(Read::Status) {
            self.image.status_requested();
        }
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
            AxisState::Idle if !self.profile.is_settled() => {
                // A new motion from rest: first what the chip takes only at
                // rest (e.g. MIN_SPEED put back after homing), then the
                // chip's ramps, then stream.
                if self.write_before_leaving_rest(&mut emit) {
                    return;
                }
                let l = units::clamp_to_chip(self.limits.requested, self.cfg.logical_shift);
                let acc = units::ramp_reg(l.acc, self.cfg.logical_shift);
                let dec = units::ramp_reg(l.dec, self.cfg.logical_shift);
                if (acc, dec) != (self.limits.acc, self.limits.dec) {
                    if emit(Command::SetParam(Register::Acc, acc)) {
                        self.limits.acc = acc;
                    }
                    if emit(Command::SetParam(Register::Dec, dec)) {
                        self.limits.dec = dec;
                    }
                } else {
                    self.start_streaming(&mut emit);
                }
            }
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
            AxisState::Idle => {
                // Energize (or wake) only once the changed currents are out,
                // and a WH register accepted while asleep before the wake's
                // HardStop ends HiZ (the spare slots below write them).
                use crate::powerstep::registers::Access;
                let fresh = self.rb.status_at > self.rb.sent_at;
                if self.asleep && fresh && !self.rb.status.hiz() {
                    // Asleep means bridges off: a chip found out of HiZ (a
                    // command it was never sent) is put back.
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
        }
    }

    /// One tick of the setup: as many of its writes as the slots allow.
    fn plan_setup(&mut self, mut k: u8, emit: &mut impl FnMut(Command) -> bool) {
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
    fn discard_position_read(&mut self) {
        if self.rb.read == Some(Read::Position) {
            self.rb.read = None;
        }
    }

    fn start_streaming(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        self.state = AxisState::Streaming;
        self.refresh_limits();
        self.stream(emit);
    }

    fn plan_stopping(&mut self, emit: &mut impl FnMut(Command) -> bool) {
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
        } else if self.stop.after == AfterStop::Hold {
            // Exactly where the chip is, even between two logical steps: the
            // next move (maybe given while stopping) starts from there.
            self.profile.rebase_fine(self.chip_fine());
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
                }
                self.land(emit);
            }
        }
    }

    fn plan_homing(&mut self, emit: &mut impl FnMut(Command) -> bool) {
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
            if emit(Command::SetParam(Register::Acc, acc)) {
                self.limits.acc = acc;
                if emit(Command::SetParam(Register::Dec, dec)) {
                    self.limits.dec = dec;
                    self.homing_ramps = false;
                }
            }
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
                for cmd in cmds.into_iter().flatten() {
                    emit(cmd);
                }
                self.rb.sent_at = self.tick;
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

    /// GoTo the target. The chip takes the shortest path modulo 2²², which is
    /// the right one because the residual at landing is a few microsteps.
    fn land(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        let target = self.target_physical();
        if emit(Command::GoTo(sign_extend_22(wrap_22(target as i32)))) {
            self.rb.sent_at = self.tick;
            self.state = AxisState::Landing;
        }
    }

    /// A STATUS read after the last one-shot command says not busy, and a
    /// position read came after it.
    fn confirmed_stopped(&self) -> bool {
        self.rb.status_at > self.rb.sent_at
            && self.rb.pos_at > self.rb.status_at
            && !self.rb.status.busy()
    }

    fn stream(&mut self, emit: &mut impl FnMut(Command) -> bool) {
        let v0 = self.profile.velocity_internal();
        let before = v0.unsigned_abs();
        self.profile.tick();
        self.rate.steady = self.profile.velocity_internal() == v0;
        // MAX_SPEED backstop: raised at once when the profile needs more; lowered
        // to the new max speed only once the profile has slowed down to it (a
        // lower max speed mid-move is reached with the profile's DEC, not the chip's).
        let shift = self.cfg.logical_shift;
        let vmax = self.profile.internal_limits().0.unsigned_abs();
        let now = before.max(self.profile.velocity_internal().unsigned_abs());
        let max_speed = self.profile.limits().max_speed;
        if self.limits.backstop.0 != max_speed || self.limits.backstop.1 == 0 {
            self.limits.backstop = (max_speed, units::backstop_reg(max_speed, shift));
        }
        let need = if now > vmax {
            let v = super::profile::speed_from_internal(now as i64, self.cfg.tick_us);
            units::backstop_reg(v.clamp(0, i64::from(u32::MAX)) as u32, shift)
        } else {
            self.limits.backstop.1
        };
        let change = need > self.limits.max_speed || (now <= vmax && need != self.limits.max_speed);
        if change && emit(Command::SetParam(Register::MaxSpeed, need)) {
            self.limits.max_speed = need;
        }
        if self.profile.is_settled() {
            self.stop.after = AfterStop::Land;
            if emit(Command::SoftStop) {
                self.rb.sent_at = self.tick;
                self.state = AxisState::Stopping;
            } else {
                self.stop.pending = Some(Command::SoftStop);
                self.state = AxisState::Stopping;
            }
            return;
        }
        let ff = units::speed_reg_with(self.profile.velocity_internal(), self.speed_div);
        let corr = units::correction_reg_with(self.rb.error, self.corr_div);
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
        if emit(Command::Run(dir, mag)) {
            self.rate.running = match dir {
                Direction::Forward => i64::from(mag),
                Direction::Reverse => -i64::from(mag),
            };
        }
    }

    /// A `Run` (`spd`, the feed-forward `ff` plus the correction) toward
    /// the target no faster than the chip can still stop from before it,
    /// from where the chip is estimated to be as the `Run` reaches it (the
    /// profile's position at this tick's start less the last following
    /// error): a chip ahead of the profile (a late or skipped tick, during
    /// which it ran on at its last speed) brakes earlier instead of being
    /// carried past the target by the correction. Only while the profile
    /// itself can stop on the target in that direction: one that cannot
    /// (a retarget inside the braking distance) passes it on purpose.
    fn cap_to_stop(&self, ff: i64, spd: i64) -> i64 {
        let Mode::Position(t) = self.profile.mode() else {
            return spd;
        };
        if (ff >= 0) != (spd >= 0) {
            return spd;
        }
        let target = logical_to_physical(t, self.cfg.logical_shift, self.cfg.step);
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
        if ahead <= 0 || left > self.stop_cap.room() {
            return spd;
        }
        let cap2 = self.stop_cap.speed2(left);
        if units::within(spd, cap2) || !units::within(ff, self.stop_cap.speed2(ahead)) {
            return spd;
        }
        units::cap_speed(spd, cap2)
    }

    /// Take this tick's replies for the axis's device.
    pub fn absorb(&mut self, replies: &Replies, device: usize) {
        if let Some(r) = self.ext_read.as_mut() {
            if let Some(i) = r.index.take() {
                if let Some(crate::powerstep::chain::Reply::Param(reg, v)) = replies.get(device, i)
                {
                    if reg == r.reg {
                        r.value = Some((v, self.tick));
                    }
                }
            }
        }
        match self.rb.read.take() {
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
        let rb = &mut self.rb;
        if core::mem::take(&mut self.absolute_read) {
            // The chip re-based its frame (homing): its value is the position.
            rb.chip_pos = i64::from(sign_extend_22(raw));
            self.rate.disarm();
        } else {
            let base = rb.raw.unwrap_or(wrap_22(rb.chip_pos as i32));
            let delta = sign_extend_22(raw.wrapping_sub(base) & 0x3F_FFFF);
            rb.chip_pos += i64::from(delta);
            // Only while the chip follows: a chip still stopping or landing
            // when streaming began runs its own ramps.
            let follows = (rb.expected_at_read - rb.chip_pos).abs() <= RATE_MAX_ERROR;
            if self.state == AxisState::Streaming && rb.raw.is_some() && follows {
                self.rate
                    .take(i64::from(delta), self.cfg.tick_us, self.cfg.step.shift());
            } else {
                self.rate.disarm();
            }
        }
        let rb = &mut self.rb;
        rb.raw = Some(raw);
        rb.pos_at = self.tick;
        // Measured in every state: when a move starts while the chip is
        // still stopping or landing, the correction starts at once.
        rb.error = if self.stop.zero {
            0
        } else {
            rb.expected_at_read - rb.chip_pos
        };
    }

    fn take_status(&mut self, s: Status) {
        self.rb.status = s;
        self.rb.status_at = self.tick;
        self.image.status_seen(s.command_error());
        if s.uvlo() {
            // Reset or undervoltage. In a setup, only a read issued after
            // the setup began reports a new one (the power-up flag, or the
            // one that started this setup, was cleared by the first read).
            let new = match self.state {
                AxisState::Setup(_) => self.tick > self.rb.setup_at,
                _ => true,
            };
            if new {
                self.fault = Some(AxisFault::ChipReset);
                self.resets = self.resets.wrapping_add(1);
                if !matches!(self.state, AxisState::Setup(_)) {
                    // Positions read since the last clean STATUS are not
                    // trustworthy; stop where the chip was then.
                    self.rb.chip_pos = self.rb.pos_at_status;
                }
                self.restart_setup();
                return;
            }
        }
        if s.stalled() {
            // A stall may have lost steps: the home is no longer known.
            self.homed = false;
        }
        if s.overcurrent()
            || matches!(
                s.thermal(),
                ThermalStatus::BridgeShutdown | ThermalStatus::DeviceShutdown
            )
        {
            if self.state == AxisState::Homing {
                self.end_homing(HomingError::Fault);
            }
            self.fault = Some(if s.overcurrent() {
                AxisFault::Overcurrent
            } else {
                AxisFault::Thermal
            });
            // The power stage is in trouble: bridges off (they may already be,
            // with OC_SD), hold where the chip is, no landing move.
            if self.is_configured() && !self.chip_off_for_fault {
                self.profile.stop_now();
                self.chip_off_for_fault = true;
                self.stop_then(AfterStop::Hold, Command::HardHiZ);
            }
        } else {
            self.chip_off_for_fault = false;
        }
        self.rb.pos_at_status = self.rb.chip_pos;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn axis() -> Axis {
        let cfg = AxisConfig {
            tick_us: 1000,
            logical_shift: 4,
            step: StepSel::OneTwentyEighth,
            drive: DriveMode::Voltage,
        };
        Axis::new(
            cfg,
            Limits {
                max_speed: 16_000,
                acc: 160_000,
                dec: 160_000,
            },
        )
    }

    #[test]
    fn the_image_writes_step_mode_and_config_first() {
        let mut a = axis().with_chip_config(0x2C98);
        a.set_currents(40, 50);
        let order: heapless::Vec<Register, 8> = core::iter::from_fn(|| {
            let (r, _) = a.image.next(|_| true)?;
            a.image.written(r);
            Some(r)
        })
        .collect();
        assert_eq!(
            &order[..],
            &[
                Register::StepMode,
                Register::Config,
                Register::MinSpeed,
                Register::KvalHold,
                Register::KvalRun,
                Register::KvalAcc,
                Register::KvalDec
            ]
        );
    }

    #[test]
    fn a_chip_reset_makes_every_owned_register_dirty_again() {
        let mut a = axis();
        a.set_currents(40, 50);
        while let Some((r, _)) = a.image.next(|_| true) {
            a.image.written(r);
        }
        assert!(a.image.is_clean());
        a.set_currents(40, 50);
        assert!(a.image.is_clean(), "the same values are not written again");
        a.image.on_reset();
        assert_eq!(a.image.get(Register::KvalHold), Some(40));
        assert!(a.image.next(|r| r == Register::KvalDec).is_some());
    }

    #[test]
    fn motion_registers_are_not_writable_through_the_image() {
        let mut a = axis();
        for r in [
            Register::AbsPos,
            Register::StepMode,
            Register::MaxSpeed,
            Register::Acc,
            Register::Dec,
            Register::Speed,
            Register::Status,
        ] {
            assert!(!a.set_register(r, 1), "{r:?}");
        }
        assert!(a.set_register(Register::OcdTh, 12));
        assert_eq!(a.chip_image().get(Register::OcdTh), Some(12));
    }

    #[test]
    fn a_write_is_done_only_once_the_next_status_shows_no_command_error() {
        let mut a = axis();
        a.set_register(Register::OcdTh, 12);
        let (r, _) = a.image.next(|_| true).expect("dirty");
        assert_eq!(r, Register::StepMode);
        while let Some((r, _)) = a.image.next(|_| true) {
            a.image.written(r);
        }
        assert!(a.image.is_clean());
        // The GetStatus after the writes comes back with CMD_ERROR: the
        // chip refused a command since the last one, maybe one of them.
        a.image.status_requested();
        a.image.status_seen(true);
        assert_eq!(
            a.image.next(|r| r == Register::OcdTh),
            Some((Register::OcdTh, 12)),
            "written again"
        );
        // A clean STATUS confirms them.
        while let Some((r, _)) = a.image.next(|_| true) {
            a.image.written(r);
        }
        a.image.status_requested();
        a.image.status_seen(false);
        assert!(a.image.is_clean());
        // Writes after the GetStatus went out are not what it is about.
        a.set_register(Register::OcdTh, 13);
        a.image.status_requested();
        a.image.written(Register::OcdTh);
        a.image.status_seen(true);
        assert!(a.image.is_clean(), "the next STATUS decides about that one");
    }

    #[test]
    fn set_zero_reads_zero_at_once() {
        let mut a = axis();
        a.state = AxisState::Idle;
        a.rb.chip_pos = 12_345;
        a.set_zero();
        assert_eq!(a.actual_position(), 0);
        assert_eq!(a.required_position(), 0);
    }

    #[test]
    fn limits_beyond_the_chip_are_clamped_for_the_profile() {
        let mut a = axis();
        a.set_logical_shift(0);
        a.set_limits(Limits {
            max_speed: 65_535,
            acc: 65_535,
            dec: 65_535,
        });
        assert_eq!(a.requested_limits().max_speed, 65_535);
        assert_eq!(a.profile().limits(), a.limit_cap());
    }
}
