//! One simulated powerSTEP01: SPI byte parser, registers, STATUS, motion
//! engine, switch input and fault injection.
//!
//! # What the model guarantees
//!
//! * **SPI framing (AN4290 §1).** One byte per CS window. [`Powerstep01::output`]
//!   is the byte in the shift register that the next window clocks out;
//!   [`Powerstep01::latch`] is the CS rising edge: the received byte is a
//!   command byte or an argument byte (MSB first), then the next response
//!   byte — or 0x00 — is loaded. Parsing uses [`Command::classify`] and
//!   [`Command::decode`] from the powerstep layer; no encoding is repeated here.
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
//! * **Registers.** All 27 from [`REGISTERS`] with their reset values, masked
//!   to their width on every write. ABS_POS is 22-bit two's complement and
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
//! # Strictness: what a real chip refuses or does, rule by rule
//!
//! The bridge is tested against this model, so the model must not be more
//! lenient than the datasheet. Each rule below is held by the named test (in
//! `tests.rs`), which fails against a model that skips the rule.
//!
//! | rule (facts doc / AN4290) | held by |
//! |---|---|
//! | GoTo, GoTo_DIR, GoHome, GoMark refused (CMD_ERROR) while BUSY | `goto_family_while_busy_is_refused`, `move_is_refused_while_a_run_is_still_accelerating` |
//! | Move refused unless stopped (also at constant speed) | `move_while_moving_is_refused`, `move_while_running_at_constant_speed_is_refused` |
//! | StepClock refused unless stopped | `step_clock_while_moving_is_refused` |
//! | WS registers (ABS_POS, EL_POS, ACC, DEC, MIN_SPEED, ALARM_EN) refused unless stopped, value unchanged | `ws_register_written_while_moving_is_refused_after_the_last_argument` |
//! | WH registers (STEP_MODE, CONFIG, GATECFG, BEMF) refused unless in HiZ | `wh_register_written_while_not_in_hiz_is_refused` |
//! | … also right after a wake (HardStop) earlier in the same batch | `a_wh_register_write_after_a_wake_in_the_same_batch_is_refused` |
//! | SW input: SW_F follows the level; SW_EVN latches the closing edge (until GetStatus) | `switch_closing_only_latches_the_event_when_sw_mode_is_1` |
//! | CONFIG.SW_MODE = 0: a closing edge hard-stops any motion | `switch_closing_hard_stops_the_motor_when_sw_mode_is_0`, `go_until_hard_stops_when_sw_mode_is_0` |
//! | GoUntil: ACT (ABS_POS reset or copy to MARK) on the closing edge, then SoftStop with DEC | `go_until_resets_abs_pos_on_switch_closing_then_soft_stops`, `go_until_copies_abs_pos_to_mark_with_act_1` |
//! | ReleaseSW: max(MIN_SPEED, 5 step/s) until the switch opens, then ACT and HardStop | `release_sw_runs_slowly_until_the_switch_opens_then_hard_stops`, `release_sw_uses_min_speed_when_it_is_faster` |
//! | Read-only and non-existent registers refused at the command byte | `set_param_to_a_read_only_register_is_refused_at_the_command_byte`, `set_param_to_a_non_existent_register_is_refused_at_the_command_byte` |
//! | Unknown command bytes refused, no arguments consumed | `unknown_byte_sets_cmd_error_and_consumes_no_arguments` |
//! | ResetDevice refused outside HiZ | `reset_device_outside_hiz_is_refused` |
//! | Run speed clamped to [MIN_SPEED, MAX_SPEED] | `run_speed_is_clamped_to_min_and_max_speed`, `a_faster_run_accelerates_with_acc_up_to_max_speed_only` |
//! | Speed changes ramp with the chip's own ACC (up) and DEC (down), never at once | `run_reaches_speed_after_the_analytic_acceleration_time`, `a_slower_run_decelerates_with_dec_not_at_once`, `soft_stop_decelerates_with_dec`, `run_in_the_opposite_direction_decelerates_then_reverses`, `lowering_max_speed_while_running_decelerates_to_it` |
//! | Positioning never passes its target | `go_to_and_move_land_exactly_on_random_targets`, `positioning_arrives_slowly_and_brakes_with_dec` |
//! | Every register at its reset value after power-up and reset (currents included), UVLO asserted | `power_up_registers_hold_their_table_reset_values`, `power_cycle_restores_every_register_including_the_currents`, `power_cycle_restores_reset_registers_and_asserts_uvlo` |
//! | Latched flags (UVLO, OCD, STALL, SW_EVN, CMD_ERROR) stay until GetStatus; GetParam(STATUS) clears nothing | `get_status_clears_latched_flags_but_get_param_status_does_not`, `uvlo_reads_asserted_after_power_up_until_the_first_get_status`, `latched_thermal_status_stays_while_the_condition_persists` |
//! | Overcurrent with OC_SD and thermal shutdown switch the bridges off and refuse motion | `overcurrent_with_oc_sd_goes_hiz_and_locks_the_bridges_until_get_status`, `thermal_shutdown_puts_bridges_in_hiz_until_the_condition_clears` |
//! | ABS_POS is 22 bits and wraps | `abs_pos_wraps_at_22_bits` |
//! | A half-sent command swallows the next bytes (no timeout) | `a_half_received_command_swallows_the_next_bytes` |
//!
//! # Modelling choices (UNCONFIRMED or unspecified behaviour)
//!
//! 1. **ResetDevice outside HiZ is refused** with CMD_ERROR (single ST-forum
//!    observation, facts doc §2/§8.10).
//! 2. **UVLO after reset:** power-up, ResetDevice and [`Fault::PowerCycle`]
//!    leave UVLO asserted (latched) until the first GetStatus.
//! 3. **Latching and clearing:** GetStatus returns STATUS, then clears SW_EVN
//!    and CMD_ERROR and re-evaluates UVLO, OCD, STALL and TH_STATUS from the
//!    current condition. UVLO dips, overcurrent and stall are modelled as
//!    events (their condition is gone once injected), thermal as a persisting
//!    condition ([`Fault::ThermalNormal`] ends it). TH_STATUS is treated as
//!    latched (facts doc: UNCONFIRMED). UVLO_ADC follows the ADCIN condition
//!    ([`Fault::AdcinLow`] / [`Fault::AdcinNormal`]) and is not latched
//!    (UNCONFIRMED); ADC_OUT keeps its table reset value.
//! 4. **Oscillator error** ([`Powerstep01::set_clock_error_ppm`], 0 by
//!    default): the chip's time runs `1 + ppm/10⁶` as fast as the caller's,
//!    like an internal 16 MHz oscillator a few % off. The tolerance of the
//!    real one is not in the facts doc (UNCONFIRMED); the motion tests use
//!    ±5 %.
//! 5. **Stall** asserts STALL_A (bit 14, ST naming) only; it does not stop
//!    the motor (the chip only flags it).
//! 6. **Bridge lock:** after an overcurrent with CONFIG.OC_SD = 1, and while
//!    the thermal condition is shutdown, commands that would enable the
//!    bridges (motion and stop commands) are refused with CMD_ERROR; the
//!    overcurrent lock is released by GetStatus.
//! 7. **Floor speed:** MIN_SPEED (bits 11:0) is the start speed of every
//!    motion from rest and the speed at which decelerations end (a SoftStop
//!    stops when the speed would drop below it). LSPD_OPT (bit 12) is
//!    ignored. When MAX_SPEED < MIN_SPEED, MAX_SPEED wins.
//! 8. **ACC = 0xFFF** is infinite acceleration (speed jumps to the target);
//!    DEC = 0xFFF is an ordinary finite deceleration. ACC or DEC = 0 never
//!    changes speed in that direction (no hang, the motor just keeps going).
//! 9. **Direction changes:** Run/GoUntil/GoTo… in the opposite direction while
//!    moving decelerate with DEC to the floor speed, stop, then start the
//!    other way. DIR reads the direction the motor actually turns.
//! 10. **Positioning while moving** (GoTo while a Run is at constant speed —
//!     accepted because BUSY is released): in the wrong direction the motor
//!     brakes, reverses and comes back; in the right direction with less room
//!     than the braking distance it brakes and stops abruptly on the target
//!     rather than overshoot. GoTo to the current microstep while moving stops
//!     at once on it.
//! 11. **GoUntil** waits for a SW falling edge (a switch already closed does
//!     not count), applies ACT, then SoftStops — or HardStops when
//!     CONFIG.SW_MODE is 0, because the switch hard-stop interrupt applies to
//!     every edge.
//!     **ReleaseSW** moves at max(MIN_SPEED, 5 step/s) (clamped by MAX_SPEED)
//!     until the switch opens, applies ACT, then HardStops; sent while the
//!     switch is already open it applies ACT at once and does not move.
//! 12. **Step-clock mode** is left by any motion, stop or HiZ command; each
//!     [`Powerstep01::step_clock_pulse`] moves one microstep (ignored in HiZ).
//! 13. **Dead device** ([`Fault::Dead`]): SDO stuck at the given byte, input
//!     ignored, the motion engine frozen with bridges off. [`Fault::Revive`]
//!     reconnects it with its state kept (bridges still in HiZ, parser idle,
//!     pending response dropped). A power cycle does not revive a dead device.
//! 14. **Power-up:** HiZ, stopped, DIR = forward, UVLO asserted.
//! 15. **EL_POS** follows the motion (1/128 units, 9 bits).
//! 16. **Log:** [`Powerstep01::received`] holds the last 32 fully received,
//!     decodable commands other than NOP (also those refused for a state
//!     reason); NOPs — the chain's padding — are not logged, and bytes
//!     refused at the command byte are not commands and are only counted as
//!     errors. The log survives ResetDevice and power cycles.

use heapless::Deque;

use crate::powerstep::commands::{Command, CommandByte, Direction, SwitchAction};
use crate::powerstep::fields::Config;
use crate::powerstep::registers::{sign_extend_22, wrap_22, Access, Register, REGISTERS};
use crate::powerstep::status::{bits, MotorStatus, Status, ThermalStatus};

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
const ACC_INFINITE_CODE: u32 = 0xFFF;
/// Zero-tick state changes allowed in a row before the engine gives up (defensive).
const MAX_INSTANT_STEPS: u32 = 64;

/// A fault or event injected from outside (test backdoor).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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
    regs: [u32; 27],
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

fn reg_index(r: Register) -> usize {
    usize::from(r.address()).saturating_sub(1)
}

impl Powerstep01 {
    /// A device just powered up: reset registers, HiZ, UVLO asserted.
    pub fn new() -> Self {
        let mut d = Powerstep01 {
            regs: [0; 27],
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
        for (slot, info) in self.regs.iter_mut().zip(REGISTERS.iter()) {
            *slot = info.reset & info.register.mask();
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

    fn reg(&self, r: Register) -> u32 {
        self.regs.get(reg_index(r)).copied().unwrap_or(0)
    }

    fn set_reg(&mut self, r: Register, v: u32) {
        if let Some(slot) = self.regs.get_mut(reg_index(r)) {
            *slot = v & r.mask();
        }
    }

    fn write_reg(&mut self, r: Register, v: u32) {
        match r {
            Register::Speed | Register::Status => {}
            Register::AbsPos => {
                self.set_reg(r, v);
                self.frac = 0;
            }
            Register::StepMode => {
                if (v ^ self.reg(r)) & 7 != 0 {
                    self.frac = 0;
                }
                self.set_reg(r, v);
            }
            _ => self.set_reg(r, v),
        }
    }

    fn abs_raw(&self) -> u32 {
        self.reg(Register::AbsPos)
    }

    /// Register value as GetParam would return it (raw, masked to its width).
    pub fn register(&self, r: Register) -> u32 {
        let v = match r {
            Register::Speed => self.speed_reg(),
            Register::Status => u32::from(self.status().raw()),
            _ => self.reg(r),
        };
        v & r.mask()
    }

    /// Backdoor write, no access rule (masked to the width). SPEED and STATUS
    /// are computed and ignore this.
    pub fn set_register_raw(&mut self, r: Register, v: u32) {
        self.write_reg(r, v);
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
        self.reg(Register::StepMode) & 7
    }

    fn vmax(&self) -> u64 {
        u64::from(self.reg(Register::MaxSpeed) & 0x3FF) << 22
    }

    fn vmin(&self) -> u64 {
        u64::from(self.reg(Register::MinSpeed) & 0xFFF) << 16
    }

    /// Start/stop floor speed (MIN_SPEED, never above MAX_SPEED).
    fn floor(&self) -> u64 {
        self.vmin().min(self.vmax())
    }

    fn acc(&self) -> u64 {
        let a = self.reg(Register::Acc);
        if a == ACC_INFINITE_CODE {
            INFINITE_ACC
        } else {
            u64::from(a)
        }
    }

    fn dec(&self) -> u64 {
        u64::from(self.reg(Register::Dec))
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

    fn motor_status(&self) -> MotorStatus {
        let v = self.v;
        match self.motion {
            Motion::Idle => MotorStatus::Stopped,
            Motion::Stopping { .. } => {
                if v > 0 {
                    MotorStatus::Decelerating
                } else {
                    MotorStatus::Stopped
                }
            }
            Motion::Speed { dir, spd, .. } => {
                let vt = self.speed_target(spd);
                if v > 0 && dir != self.dir {
                    MotorStatus::Decelerating
                } else if v < vt {
                    MotorStatus::Accelerating
                } else if v > vt {
                    MotorStatus::Decelerating
                } else if v == 0 {
                    MotorStatus::Stopped
                } else {
                    MotorStatus::ConstantSpeed
                }
            }
            Motion::Position { dir, braking, .. } => {
                if v > 0 && dir != self.dir {
                    MotorStatus::Decelerating
                } else if braking {
                    if v > self.floor() {
                        MotorStatus::Decelerating
                    } else {
                        MotorStatus::ConstantSpeed
                    }
                } else {
                    let vmax = self.vmax();
                    if v < vmax {
                        MotorStatus::Accelerating
                    } else if v > vmax {
                        MotorStatus::Decelerating
                    } else {
                        MotorStatus::ConstantSpeed
                    }
                }
            }
        }
    }

    /// STATUS as GetParam(STATUS) reads it (nothing is cleared).
    pub fn status(&self) -> Status {
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
        s |= (self.motor_status() as u16) << 5;
        if self.cmd_error {
            s |= bits::CMD_ERROR;
        }
        if self.stck_mod {
            s |= bits::STCK_MOD;
        }
        if !self.uvlo {
            s |= bits::UVLO;
        }
        s |= u16::from(self.th_latched & 3) << 11;
        if !self.ocd {
            s |= bits::OCD;
        }
        if !self.stall {
            s |= bits::STALL_A;
        }
        Status(s)
    }

    /// TH_STATUS as it will read.
    pub fn thermal(&self) -> ThermalStatus {
        ThermalStatus::from_bits(u16::from(self.th_latched))
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
