//! One simulated powerSTEP01: SPI byte parser, registers, STATUS, motion
//! engine, switch input and fault injection.
//!
//! # What the model guarantees
//!
//! * **SPI framing (AN4290 §1).** One byte per CS window. [`Powerstep01::output`]
//!   is the byte in the shift register that the next window clocks out;
//!   [`Powerstep01::latch`] is the CS rising edge: the received byte is a
//!   command byte or an argument byte (MSB first), then the next response
//!   byte — or 0x00 — is loaded. Parsing uses the model's own command table
//!   ([`datasheet::command_byte`], [`datasheet::decode`]), not the driver's.
//! * **No timeout.** A command waits for all of its argument bytes whatever
//!   they are, so a half-sent command swallows the next bytes.
//! * **Responses.** GetParam/GetStatus capture the value when the command byte
//!   is decoded and shift it out MSB first in the following windows; a new
//!   response-producing command replaces a pending response; other commands
//!   do not disturb it.
//! * **CMD_ERROR** (latched) for: an unknown command byte (no argument bytes
//!   are expected after it); SetParam/GetParam of a non-existent register and
//!   SetParam of a read-only register (refused at the command byte — the next
//!   byte is a new command); SetParam of a WS register while the motor is not
//!   stopped or of a WH register while the bridges are not in HiZ (refused
//!   after the last argument byte, value unchanged); Move/StepClock unless
//!   stopped; GoTo/GoTo_DIR/GoHome/GoMark while BUSY; ResetDevice outside HiZ.
//!   [`Powerstep01::command_errors`] counts every refusal.
//! * **Registers.** All 27 from the model's [`REGISTERS`] with their reset
//!   values, masked to their width on every write. ABS_POS is 22-bit two's complement and
//!   wraps; SPEED reads the current speed; STATUS is assembled on read.
//! * **Motion** in the chip's own units, integrated per 250 ns tick with exact
//!   integer arithmetic: speed in 2⁻⁴⁰ full step/tick internally (SPEED =
//!   speed ≫ 12), ACC/DEC in 2⁻⁴⁰ step/tick² (added once per tick), positions
//!   in microsteps of STEP_SEL with a 40-bit sub-microstep fraction
//!   (microstep rate = speed · 2^STEP_SEL). Each tick first updates the speed,
//!   then moves by the new speed. [`Powerstep01::advance`] integrates whole
//!   phases in closed form (arithmetic series in `u128`) and only loops over
//!   phase changes; leftover nanoseconds (< 250) are carried to the next call,
//!   so **the result does not depend on how time is sliced**: the state after
//!   `advance(a); advance(b)` equals the state after `advance(a + b)` when no
//!   command arrives in between (the only slicing dependence is the obvious
//!   one: a command takes effect at the tick boundary where it arrives).
//! * **Positioning** (Move, GoTo, GoTo_DIR, GoHome, GoMark) ends exactly on the
//!   target microstep with speed 0 and never passes it: the motor brakes once
//!   the remaining distance is ≤ the discrete braking distance at DEC down to
//!   the floor speed, continues at the floor speed if it gets there early, and
//!   stops on the tick that reaches the target.
//! * Never panics on any input: all arithmetic on inputs is checked,
//!   saturating or provably in range; no indexing by input values.
//!
//! The rules the model enforces and its modelling choices are listed in the
//! crate doc, with the datasheet or AN4290 section each one comes from.

use heapless::Deque;
use powerstep01::{Command, Direction, Register, Status, SwitchAction, ThermalStatus};

use crate::datasheet::{
    self, addr, config, fields, sign_extend_22, status as bits, status::mot, StatusWord, REGISTERS,
};
use crate::vocab;

/// Length of one chip tick (16 MHz oscillator).
pub const TICK_NS: u64 = 250;
/// Commands kept in the receive log.
pub const LOG_LEN: usize = 32;

/// Sub-microstep fraction bits (speeds are 2⁻⁴⁰ full step per tick).
const FRAC_BITS: u32 = 40;
const FRAC_MASK: u128 = (1u128 << FRAC_BITS) - 1;
const POS_MASK: u32 = 0x3F_FFFF;
/// 5 full steps/s in internal speed units: 5 · 250 ns · 2⁴⁰ = 1 374 389.5.
const RELEASE_SW_SPEED: u64 = 1_374_390;
/// "Infinite" acceleration (ACC = 0xFFF): larger than any speed difference.
const INFINITE_ACC: u64 = 1 << FRAC_BITS;
/// Zero-tick state changes allowed in a row before the engine gives up (defensive).
const MAX_INSTANT_STEPS: u32 = 64;

/// A fault or event injected from outside (test backdoor).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Fault {
    /// Supply dip: UVLO latched, bridges to HiZ, motion stops.
    Uvlo,
    /// Full reset to the power-up state including registers (brown-out): UVLO asserted.
    PowerCycle,
    /// OCD latched; if CONFIG.OC_SD is set the bridges go to HiZ.
    Overcurrent,
    /// TH_STATUS = 01 while the condition lasts.
    ThermalWarning,
    /// TH_STATUS = 10 (bridge shutdown): bridges HiZ, motion stops.
    ThermalShutdown,
    /// Temperature back to normal (TH_STATUS clears at the next GetStatus).
    ThermalNormal,
    /// Stall detected: STALL_A latched.
    Stall,
    /// The ADCIN input drops below its threshold (an unused ADCIN may do so
    /// for good): UVLO_ADC reads asserted while it lasts.
    AdcinLow,
    /// ADCIN back above its threshold.
    AdcinNormal,
    /// The device stops working: SDO stuck at this byte, input ignored.
    Dead(u8),
    /// Undo [`Fault::Dead`].
    Revive,
}

/// What a speed-controlled motion is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SpeedKind {
    Run,
    GoUntil(SwitchAction),
    ReleaseSw(SwitchAction),
}

/// The motion engine's current order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Motion {
    /// Not moving (holding, or HiZ). Speed is 0.
    Idle,
    /// Approach a target speed (`spd` in internal units, clamped on use).
    Speed {
        dir: Direction,
        spd: u64,
        kind: SpeedKind,
    },
    /// Go to `target` in direction `dir`; `remaining` microsteps are left
    /// (valid while the motor turns in `dir`, recomputed when it reverses).
    Position {
        dir: Direction,
        target: u32,
        remaining: u64,
        braking: bool,
    },
    /// SoftStop / SoftHiZ: decelerate to the floor speed, stop, maybe HiZ.
    Stopping { hiz: bool },
}

/// Result of a deceleration-to-stop phase.
enum Ph {
    Used(u64),
    Done,
    Wait,
}

/// A cam on the motor shaft that presses the end switch (SW input) below an
/// edge: [`Powerstep01::set_home_cam`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HomeCam {
    /// Pressed while the shaft is at or below this, microsteps.
    pub edge: i64,
    /// A normally closed switch: pressed opens the contact.
    pub nc: bool,
}

/// A simulated powerSTEP01.
#[derive(Clone, Debug)]
pub struct Powerstep01 {
    /// Register storage, index = address − 1. ABS_POS lives here (raw 22 bit).
    regs: [u32; REGISTERS.len()],
    // --- SPI parser ---
    cmd: u8,
    need: u8,
    got: u8,
    args: [u8; 3],
    // --- response / shift register ---
    resp: [u8; 3],
    resp_len: u8,
    resp_next: u8,
    out: u8,
    // --- motor state ---
    hiz: bool,
    dir: Direction,
    /// Speed, 2⁻⁴⁰ full step per tick.
    v: u64,
    /// Progress towards the next microstep in `dir`, 2⁻⁴⁰ microstep.
    frac: u64,
    /// Where the motor shaft is, 1/128 full steps since the chip was
    /// created: physical, so neither ABS_POS writes, ResetPos, the switch
    /// ACT nor a power cycle move it (test backdoor for switches on the axis).
    shaft: i64,
    motion: Motion,
    stck_mod: bool,
    // --- inputs and flags ---
    sw_closed: bool,
    sw_evn: bool,
    cmd_error: bool,
    /// UVLO latched (asserted).
    uvlo: bool,
    /// OCD latched (asserted).
    ocd: bool,
    /// Bridges locked off after an overcurrent shutdown until GetStatus.
    ocd_lock: bool,
    /// STALL_A latched (asserted).
    stall: bool,
    /// ADCIN below its undervoltage threshold (UVLO_ADC, a condition).
    adcin_low: bool,
    /// Thermal condition now (0..=3) and as reported (latched).
    th_cond: u8,
    th_latched: u8,
    dead: Option<u8>,
    /// Chip time not yet worth a whole tick, in 10⁻⁶ ns.
    ns_rem: u64,
    /// The home switch cam on the shaft, if any.
    cam: Option<HomeCam>,
    /// Oscillator error in ppm (the chip's time runs `1 + ppm/10⁶` as fast
    /// as the caller's): the internal 16 MHz oscillator is not exact.
    clock_ppm: i32,
    // --- inspection ---
    log: Deque<Command, LOG_LEN>,
    received_count: u64,
    command_errors: u32,
}

impl Default for Powerstep01 {
    fn default() -> Self {
        Self::new()
    }
}

mod engine;
mod inputs;
mod spi;
#[cfg(test)]
mod tests;

/// Mask of the register at `address` (0 where there is none).
fn mask(address: u8) -> u32 {
    datasheet::register(address).map_or(0, |r| r.mask())
}

impl Powerstep01 {
    /// A device just powered up: reset registers, HiZ, UVLO asserted.
    pub fn new() -> Self {
        let mut d = Powerstep01 {
            regs: [0; REGISTERS.len()],
            cmd: 0,
            need: 0,
            got: 0,
            args: [0; 3],
            resp: [0; 3],
            resp_len: 0,
            resp_next: 0,
            out: 0,
            hiz: true,
            dir: Direction::Forward,
            v: 0,
            frac: 0,
            shaft: 0,
            motion: Motion::Idle,
            stck_mod: false,
            sw_closed: false,
            sw_evn: false,
            cmd_error: false,
            uvlo: true,
            ocd: false,
            ocd_lock: false,
            stall: false,
            adcin_low: false,
            th_cond: 0,
            th_latched: 0,
            dead: None,
            ns_rem: 0,
            clock_ppm: 0,
            cam: None,
            log: Deque::new(),
            received_count: 0,
            command_errors: 0,
        };
        d.power_up();
        d
    }

    /// Back to the power-up state. Keeps what is physical or a test backdoor:
    /// switch level, thermal condition, dead state, time remainder, log, counters.
    fn power_up(&mut self) {
        for (slot, spec) in self.regs.iter_mut().zip(REGISTERS.iter()) {
            *slot = spec.reset & spec.mask();
        }
        self.need = 0;
        self.got = 0;
        self.resp_len = 0;
        self.resp_next = 0;
        self.out = 0;
        self.hiz = true;
        self.dir = Direction::Forward;
        self.v = 0;
        self.frac = 0;
        self.motion = Motion::Idle;
        self.stck_mod = false;
        self.sw_evn = false;
        self.cmd_error = false;
        self.uvlo = true;
        self.ocd = false;
        self.ocd_lock = false;
        self.stall = false;
        self.th_latched = self.th_cond;
    }

    // ------------------------------------------------------ registers ----

    /// The stored value at `address` (0 where there is no register).
    fn reg(&self, address: u8) -> u32 {
        datasheet::slot(address)
            .and_then(|i| self.regs.get(i))
            .copied()
            .unwrap_or(0)
    }

    fn set_reg(&mut self, address: u8, v: u32) {
        if let Some(slot) = datasheet::slot(address).and_then(|i| self.regs.get_mut(i)) {
            *slot = v & mask(address);
        }
    }

    fn write_reg(&mut self, address: u8, v: u32) {
        match address {
            addr::SPEED | addr::STATUS => {}
            addr::ABS_POS => {
                self.set_reg(address, v);
                self.frac = 0;
            }
            addr::STEP_MODE => {
                if (v ^ self.reg(address)) & fields::STEP_SEL != 0 {
                    self.frac = 0;
                }
                self.set_reg(address, v);
            }
            _ => self.set_reg(address, v),
        }
    }

    fn abs_raw(&self) -> u32 {
        self.reg(addr::ABS_POS)
    }

    /// The value at `address` as GetParam would return it (raw, masked to
    /// its width; 0 where there is no register).
    pub fn register_at(&self, address: u8) -> u32 {
        let v = match address {
            addr::SPEED => self.speed_reg(),
            addr::STATUS => u32::from(self.status_raw()),
            _ => self.reg(address),
        };
        v & mask(address)
    }

    /// Register value as GetParam would return it (raw, masked to its width).
    pub fn register(&self, r: Register) -> u32 {
        self.register_at(vocab::address(r))
    }

    /// Backdoor write, no access rule (masked to the width). SPEED and STATUS
    /// are computed and ignore this.
    pub fn set_register_raw(&mut self, r: Register, v: u32) {
        self.write_reg(vocab::address(r), v);
    }

    /// The motor shaft's position, 1/128 full steps (see the field).
    pub fn shaft_position(&self) -> i64 {
        self.shaft
    }

    /// ABS_POS, sign-extended.
    pub fn abs_pos(&self) -> i32 {
        sign_extend_22(self.abs_raw())
    }

    /// SPEED register value (0.28 step/tick, 20 bit).
    pub fn speed_reg(&self) -> u32 {
        u32::try_from(self.v >> 12)
            .unwrap_or(u32::MAX)
            .min(0xF_FFFF)
    }

    /// Speed at full internal resolution: 2⁻⁴⁰ full step per 250 ns tick.
    pub fn speed_internal(&self) -> u64 {
        self.v
    }

    // --------------------------------------------------------- status ----

    fn step_shift(&self) -> u32 {
        self.reg(addr::STEP_MODE) & fields::STEP_SEL
    }

    fn vmax(&self) -> u64 {
        u64::from(self.reg(addr::MAX_SPEED) & fields::MAX_SPEED) << 22
    }

    fn vmin(&self) -> u64 {
        u64::from(self.reg(addr::MIN_SPEED) & fields::MIN_SPEED) << 16
    }

    /// Start/stop floor speed (MIN_SPEED, never above MAX_SPEED).
    fn floor(&self) -> u64 {
        self.vmin().min(self.vmax())
    }

    fn acc(&self) -> u64 {
        let a = self.reg(addr::ACC);
        if a == fields::ACC_INFINITE {
            INFINITE_ACC
        } else {
            u64::from(a)
        }
    }

    fn dec(&self) -> u64 {
        u64::from(self.reg(addr::DEC))
    }

    fn speed_target(&self, spd: u64) -> u64 {
        spd.max(self.vmin()).min(self.vmax())
    }

    /// A command is executing (BUSY pin low).
    pub fn is_busy(&self) -> bool {
        match self.motion {
            Motion::Idle => false,
            Motion::Stopping { .. } | Motion::Position { .. } => true,
            Motion::Speed { dir, spd, kind } => match kind {
                SpeedKind::Run => self.dir != dir || self.v != self.speed_target(spd),
                SpeedKind::GoUntil(_) | SpeedKind::ReleaseSw(_) => true,
            },
        }
    }

    fn busy(&self) -> bool {
        self.is_busy()
    }

    /// Speed is zero and no motion command is executing.
    pub fn is_stopped(&self) -> bool {
        self.v == 0 && !self.busy()
    }

    pub fn is_hiz(&self) -> bool {
        self.hiz
    }

    /// True while [`Fault::Dead`] is in force.
    pub fn is_dead(&self) -> bool {
        self.dead.is_some()
    }

    /// Level of the SW input (true = closed).
    pub fn switch_closed(&self) -> bool {
        self.sw_closed
    }

    /// MOT_STATUS code ([`mot`]).
    fn motor_status(&self) -> u16 {
        let v = self.v;
        match self.motion {
            Motion::Idle => mot::STOPPED,
            Motion::Stopping { .. } => {
                if v > 0 {
                    mot::DECELERATING
                } else {
                    mot::STOPPED
                }
            }
            Motion::Speed { dir, spd, .. } => {
                let vt = self.speed_target(spd);
                if v > 0 && dir != self.dir {
                    mot::DECELERATING
                } else if v < vt {
                    mot::ACCELERATING
                } else if v > vt {
                    mot::DECELERATING
                } else if v == 0 {
                    mot::STOPPED
                } else {
                    mot::CONSTANT_SPEED
                }
            }
            Motion::Position { dir, braking, .. } => {
                if v > 0 && dir != self.dir {
                    mot::DECELERATING
                } else if braking {
                    if v > self.floor() {
                        mot::DECELERATING
                    } else {
                        mot::CONSTANT_SPEED
                    }
                } else {
                    let vmax = self.vmax();
                    if v < vmax {
                        mot::ACCELERATING
                    } else if v > vmax {
                        mot::DECELERATING
                    } else {
                        mot::CONSTANT_SPEED
                    }
                }
            }
        }
    }

    /// STATUS as GetParam(STATUS) reads it (nothing is cleared), in the
    /// driver crate's vocabulary type (the bits are the model's, see
    /// [`datasheet::status`]).
    pub fn status(&self) -> Status {
        Status(self.status_raw())
    }

    /// STATUS read with the model's own layout.
    pub fn status_word(&self) -> StatusWord {
        StatusWord(self.status_raw())
    }

    /// The 16 STATUS bits (nothing is cleared).
    pub fn status_raw(&self) -> u16 {
        let mut s: u16 = bits::STALL_B;
        if !self.adcin_low {
            s |= bits::UVLO_ADC;
        }
        if self.hiz {
            s |= bits::HIZ;
        }
        if !self.busy() {
            s |= bits::BUSY;
        }
        if self.sw_closed {
            s |= bits::SW_F;
        }
        if self.sw_evn {
            s |= bits::SW_EVN;
        }
        if self.dir == Direction::Forward {
            s |= bits::DIR;
        }
        s |= (self.motor_status() << bits::MOT_SHIFT) & bits::MOT_STATUS;
        if self.cmd_error {
            s |= bits::CMD_ERROR;
        }
        if self.stck_mod {
            s |= bits::STCK_MOD;
        }
        if !self.uvlo {
            s |= bits::UVLO;
        }
        s |= (u16::from(self.th_latched) << bits::TH_SHIFT) & bits::TH_STATUS;
        if !self.ocd {
            s |= bits::OCD;
        }
        if !self.stall {
            s |= bits::STALL_A;
        }
        s
    }

    /// TH_STATUS as it will read.
    pub fn thermal(&self) -> ThermalStatus {
        datasheet::thermal_status(self.th_latched)
    }

    /// CONFIG.SW_MODE = 1: a switch turn-on edge is only reported.
    fn sw_user(&self) -> bool {
        self.reg(addr::CONFIG) & config::SW_MODE != 0
    }

    /// CONFIG.OC_SD = 1: an overcurrent switches the bridges off.
    fn oc_shutdown(&self) -> bool {
        self.reg(addr::CONFIG) & config::OC_SD != 0
    }

    // ------------------------------------------------------ inspection ----

    /// The last [`LOG_LEN`] fully received commands except NOP, oldest first.
    pub fn received(&self) -> impl Iterator<Item = &Command> {
        self.log.iter()
    }

    /// Commands (except NOP) received since creation or the last [`Self::clear_log`].
    pub fn received_count(&self) -> u64 {
        self.received_count
    }

    /// Empty the log and reset [`Self::received_count`].
    pub fn clear_log(&mut self) {
        self.log.clear();
        self.received_count = 0;
    }

    /// Number of refused commands (each one set CMD_ERROR).
    pub fn command_errors(&self) -> u32 {
        self.command_errors
    }
}
