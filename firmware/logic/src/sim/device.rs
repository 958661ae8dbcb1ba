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
//! this file's `tests`), which fails against a model that skips the rule.
//!
//! | rule (facts doc / AN4290) | held by |
//! |---|---|
//! | GoTo, GoTo_DIR, GoHome, GoMark refused (CMD_ERROR) while BUSY | `goto_family_while_busy_is_refused`, `move_is_refused_while_a_run_is_still_accelerating` |
//! | Move refused unless stopped (also at constant speed) | `move_while_moving_is_refused`, `move_while_running_at_constant_speed_is_refused` |
//! | StepClock refused unless stopped | `step_clock_while_moving_is_refused` |
//! | WS registers (ABS_POS, EL_POS, ACC, DEC, MIN_SPEED, ALARM_EN) refused unless stopped, value unchanged | `ws_register_written_while_moving_is_refused_after_the_last_argument` |
//! | WH registers (STEP_MODE, CONFIG, GATECFG, BEMF) refused unless in HiZ | `wh_register_written_while_not_in_hiz_is_refused` |
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
//!    latched (facts doc: UNCONFIRMED). UVLO_ADC always reads inactive (ADCIN
//!    fine); ADC_OUT keeps its table reset value.
//! 4. **Stall** asserts STALL_A (bit 14, ST naming) only; it does not stop
//!    the motor (the chip only flags it).
//! 5. **Bridge lock:** after an overcurrent with CONFIG.OC_SD = 1, and while
//!    the thermal condition is shutdown, commands that would enable the
//!    bridges (motion and stop commands) are refused with CMD_ERROR; the
//!    overcurrent lock is released by GetStatus.
//! 6. **Floor speed:** MIN_SPEED (bits 11:0) is the start speed of every
//!    motion from rest and the speed at which decelerations end (a SoftStop
//!    stops when the speed would drop below it). LSPD_OPT (bit 12) is
//!    ignored. When MAX_SPEED < MIN_SPEED, MAX_SPEED wins.
//! 7. **ACC = 0xFFF** is infinite acceleration (speed jumps to the target);
//!    DEC = 0xFFF is an ordinary finite deceleration. ACC or DEC = 0 never
//!    changes speed in that direction (no hang, the motor just keeps going).
//! 8. **Direction changes:** Run/GoUntil/GoTo… in the opposite direction while
//!    moving decelerate with DEC to the floor speed, stop, then start the
//!    other way. DIR reads the direction the motor actually turns.
//! 9. **Positioning while moving** (GoTo while a Run is at constant speed —
//!    accepted because BUSY is released): in the wrong direction the motor
//!    brakes, reverses and comes back; in the right direction with less room
//!    than the braking distance it brakes and stops abruptly on the target
//!    rather than overshoot. GoTo to the current microstep while moving stops
//!    at once on it.
//! 10. **GoUntil** waits for a SW falling edge (a switch already closed does
//!     not count), applies ACT, then SoftStops — or HardStops when
//!     CONFIG.SW_MODE is 0, because the switch hard-stop interrupt applies to
//!     every edge.
//!     **ReleaseSW** moves at max(MIN_SPEED, 5 step/s) (clamped by MAX_SPEED)
//!     until the switch opens, applies ACT, then HardStops; sent while the
//!     switch is already open it applies ACT at once and does not move.
//! 11. **Step-clock mode** is left by any motion, stop or HiZ command; each
//!     [`Powerstep01::step_clock_pulse`] moves one microstep (ignored in HiZ).
//! 12. **Dead device** ([`Fault::Dead`]): SDO stuck at the given byte, input
//!     ignored, the motion engine frozen with bridges off. [`Fault::Revive`]
//!     reconnects it with its state kept (bridges still in HiZ, parser idle,
//!     pending response dropped). A power cycle does not revive a dead device.
//! 13. **Power-up:** HiZ, stopped, DIR = forward, UVLO asserted.
//! 14. **EL_POS** follows the motion (1/128 units, 9 bits).
//! 15. **Log:** [`Powerstep01::received`] holds the last 32 fully received,
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
    /// Thermal condition now (0..=3) and as reported (latched).
    th_cond: u8,
    th_latched: u8,
    dead: Option<u8>,
    /// Nanoseconds not yet worth a whole tick.
    ns_rem: u64,
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

fn reg_index(r: Register) -> usize {
    usize::from(r.address()).saturating_sub(1)
}

/// Distance in microsteps from `from` to `to` going in `dir` (22-bit wrap).
fn dist_in_dir(dir: Direction, from: u32, to: u32) -> u64 {
    let d = match dir {
        Direction::Forward => to.wrapping_sub(from),
        Direction::Reverse => from.wrapping_sub(to),
    };
    u64::from(d & POS_MASK)
}

/// Full-step distance (2⁻⁴⁰ step) of `j` ticks accelerating by `a` from `v`.
fn s_up(v: u64, a: u64, j: u64) -> u128 {
    let (v, a, j) = (u128::from(v), u128::from(a), u128::from(j));
    j * v + a * (j * (j + 1) / 2)
}

/// Full-step distance of `j` ticks decelerating by `d` from `v` (`j·d ≤ v`).
fn s_down(v: u64, d: u64, j: u64) -> u128 {
    let (v, d, j) = (u128::from(v), u128::from(d), u128::from(j));
    (j * v).saturating_sub(d * (j * (j + 1) / 2))
}

/// Discrete braking distance from `v` down to the floor `vf` at `d` per tick
/// (full-step units). `None` = infinite (no deceleration available).
fn brake_dist(v: u64, vf: u64, d: u64) -> Option<u128> {
    if v <= vf {
        return Some(0);
    }
    if d == 0 {
        return None;
    }
    let n1 = (v - vf) / d;
    let mut s = s_down(v, d, n1);
    // One more tick clamps the speed to the floor if it did not land on it.
    if v - n1 * d > vf {
        s += u128::from(vf);
    }
    Some(s)
}

/// Smallest `j` in `lo..=hi` with `pred(j)` for a monotone predicate.
fn first_true(lo: u64, hi: u64, pred: impl Fn(u64) -> bool) -> Option<u64> {
    if lo > hi || !pred(hi) {
        return None;
    }
    let (mut lo, mut hi) = (lo, hi);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if pred(mid) {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    Some(lo)
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
            motion: Motion::Idle,
            stck_mod: false,
            sw_closed: false,
            sw_evn: false,
            cmd_error: false,
            uvlo: true,
            ocd: false,
            ocd_lock: false,
            stall: false,
            th_cond: 0,
            th_latched: 0,
            dead: None,
            ns_rem: 0,
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
            match Command::classify(input) {
                CommandByte::Invalid => self.refuse(),
                CommandByte::Takes(0) => self.complete(&[input]),
                CommandByte::Takes(n) => {
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

    fn load_output(&mut self) {
        if self.resp_next < self.resp_len {
            self.out = self
                .resp
                .get(usize::from(self.resp_next))
                .copied()
                .unwrap_or(0);
            self.resp_next += 1;
        } else {
            self.out = 0;
        }
    }

    fn respond(&mut self, value: u32, len: u8) {
        let len = len.clamp(1, 3);
        let be = value.to_be_bytes();
        let start = 4 - usize::from(len);
        for (dst, src) in self.resp.iter_mut().zip(be.iter().skip(start)) {
            *dst = *src;
        }
        self.resp_len = len;
        self.resp_next = 0;
    }

    fn refuse(&mut self) {
        self.cmd_error = true;
        self.command_errors = self.command_errors.saturating_add(1);
    }

    fn complete(&mut self, frame: &[u8]) {
        match Command::decode(frame) {
            Ok(cmd) => {
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
            Err(_) => self.refuse(),
        }
    }

    fn bridges_locked(&self) -> bool {
        self.ocd_lock || self.th_cond >= 2
    }

    /// Common part of every accepted motion or stop command.
    fn enable_bridges(&mut self) {
        self.hiz = false;
        self.stck_mod = false;
    }

    fn execute(&mut self, cmd: Command) {
        let enables_bridges =
            cmd.is_motion() || matches!(cmd, Command::SoftStop | Command::HardStop);
        if enables_bridges && self.bridges_locked() {
            self.refuse();
            return;
        }
        match cmd {
            Command::Nop => {}
            Command::SetParam(r, v) => {
                let allowed = match r.access() {
                    Access::ReadOnly => false,
                    Access::Always => true,
                    Access::WhenStopped => self.is_stopped(),
                    Access::WhenHiZ => self.hiz,
                };
                if allowed {
                    self.write_reg(r, v);
                } else {
                    self.refuse();
                }
            }
            Command::GetParam(r) => {
                let v = self.register(r);
                self.respond(v, r.bytes());
            }
            Command::GetStatus => {
                let s = self.status();
                self.respond(u32::from(s.raw()), 2);
                self.clear_latched();
            }
            Command::Run(dir, spd) => {
                self.enable_bridges();
                self.motion = Motion::Speed {
                    dir,
                    spd: u64::from(spd) << 12,
                    kind: SpeedKind::Run,
                };
            }
            Command::StepClock(dir) => {
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
            Command::Move(dir, n) => {
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
            Command::GoTo(p) => self.go_to(None, wrap_22(p)),
            Command::GoToDir(dir, p) => self.go_to(Some(dir), wrap_22(p)),
            Command::GoHome => self.go_to(None, 0),
            Command::GoMark => {
                let mark = self.reg(Register::Mark);
                self.go_to(None, mark)
            }
            Command::GoUntil(act, dir, spd) => {
                self.enable_bridges();
                self.motion = Motion::Speed {
                    dir,
                    spd: u64::from(spd) << 12,
                    kind: SpeedKind::GoUntil(act),
                };
            }
            Command::ReleaseSw(act, dir) => {
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
            Command::ResetPos => {
                self.set_reg(Register::AbsPos, 0);
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

    /// GoTo family: refused while BUSY; `dir` forces the direction.
    fn go_to(&mut self, dir: Option<Direction>, target: u32) {
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

    fn start_position(&mut self, dir: Direction, target: u32, remaining: u64) {
        self.motion = Motion::Position {
            dir,
            target,
            remaining,
            braking: false,
        };
    }

    fn stop_now(&mut self) {
        self.v = 0;
        self.motion = Motion::Idle;
    }

    fn apply_act(&mut self, act: SwitchAction) {
        match act {
            SwitchAction::ResetAbsPos => {
                self.set_reg(Register::AbsPos, 0);
            }
            SwitchAction::CopyToMark => {
                let p = self.abs_raw();
                self.set_reg(Register::Mark, p);
            }
        }
    }

    fn clear_latched(&mut self) {
        self.sw_evn = false;
        self.cmd_error = false;
        // Event-type conditions are over once injected (module docs, choice 3).
        self.uvlo = false;
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
        let mut s: u16 = bits::UVLO_ADC | bits::STALL_B;
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

    // ---------------------------------------------------- environment ----

    /// Drive the SW input. Closing is the falling edge ("turn-on").
    pub fn set_switch(&mut self, closed: bool) {
        let was = self.sw_closed;
        self.sw_closed = closed;
        if self.dead.is_some() || was == closed {
            return;
        }
        // SW_MODE = 0: every turn-on edge is a HardStop interrupt.
        let hard = !Config::from_reg(self.reg(Register::Config) as u16).sw_user;
        if closed {
            self.sw_evn = true;
            if let Motion::Speed {
                kind: SpeedKind::GoUntil(act),
                ..
            } = self.motion
            {
                self.apply_act(act);
                if hard {
                    self.stop_now();
                } else {
                    self.motion = Motion::Stopping { hiz: false };
                    self.run_engine(0);
                }
            } else if hard && self.motion != Motion::Idle {
                self.stop_now();
            }
        } else if let Motion::Speed {
            kind: SpeedKind::ReleaseSw(act),
            ..
        } = self.motion
        {
            self.apply_act(act);
            self.stop_now();
        }
    }

    /// One STCK pulse: in step-clock mode, one microstep in DIR.
    pub fn step_clock_pulse(&mut self) {
        if self.dead.is_some() || !self.stck_mod || self.hiz {
            return;
        }
        self.frac = 0;
        self.apply_steps(self.dir, 1);
    }

    /// Inject a fault or event.
    pub fn inject(&mut self, fault: Fault) {
        match fault {
            Fault::Revive => {
                if self.dead.take().is_some() {
                    self.need = 0;
                    self.got = 0;
                    self.resp_len = 0;
                    self.resp_next = 0;
                    self.out = 0;
                }
                return;
            }
            Fault::Dead(b) => {
                self.stop_now();
                self.hiz = true;
                self.stck_mod = false;
                self.dead = Some(b);
                return;
            }
            _ => {}
        }
        if self.dead.is_some() {
            // A dead device reacts to nothing but the thermal condition.
            match fault {
                Fault::ThermalWarning => self.th_cond = 1,
                Fault::ThermalShutdown => self.th_cond = 2,
                Fault::ThermalNormal => self.th_cond = 0,
                _ => {}
            }
            return;
        }
        match fault {
            Fault::Uvlo => {
                self.uvlo = true;
                self.hiz_now();
            }
            Fault::PowerCycle => self.power_up(),
            Fault::Overcurrent => {
                self.ocd = true;
                if Config::from_reg(self.reg(Register::Config) as u16).oc_shutdown {
                    self.ocd_lock = true;
                    self.hiz_now();
                }
            }
            Fault::ThermalWarning => {
                self.th_cond = 1;
                self.th_latched = self.th_latched.max(1);
            }
            Fault::ThermalShutdown => {
                self.th_cond = 2;
                self.th_latched = self.th_latched.max(2);
                self.hiz_now();
            }
            Fault::ThermalNormal => self.th_cond = 0,
            Fault::Stall => self.stall = true,
            Fault::Dead(_) | Fault::Revive => {}
        }
    }

    fn hiz_now(&mut self) {
        self.stop_now();
        self.stck_mod = false;
        self.hiz = true;
    }

    // ---------------------------------------------------------- motion ----

    /// Let `dt_ns` nanoseconds pass (exact; see the module docs).
    pub fn advance(&mut self, dt_ns: u64) {
        let total = u128::from(self.ns_rem) + u128::from(dt_ns);
        let ticks = u64::try_from(total / u128::from(TICK_NS)).unwrap_or(u64::MAX);
        self.ns_rem = (total % u128::from(TICK_NS)) as u64;
        if self.dead.is_some() {
            return;
        }
        self.run_engine(ticks);
    }

    fn run_engine(&mut self, mut avail: u64) {
        let mut instant = 0u32;
        while let Some(used) = self.step(avail) {
            avail = avail.saturating_sub(used);
            if used == 0 {
                instant += 1;
                if instant > MAX_INSTANT_STEPS {
                    break;
                }
            } else {
                instant = 0;
            }
        }
    }

    /// Move `steps` microsteps in `dir` (ABS_POS and EL_POS wrap).
    fn apply_steps(&mut self, dir: Direction, steps: u128) {
        let s22 = (steps & u128::from(POS_MASK)) as u32;
        let pos = self.abs_raw();
        let pos = match dir {
            Direction::Forward => pos.wrapping_add(s22),
            Direction::Reverse => pos.wrapping_sub(s22),
        };
        self.set_reg(Register::AbsPos, pos);
        // EL_POS counts 1/128 steps: one microstep = 2^(7 − STEP_SEL).
        let unit = 1u32 << (7u32.saturating_sub(self.step_shift()));
        let el_steps = ((steps & 0x1FF) as u32).wrapping_mul(unit);
        let el = self.reg(Register::ElPos);
        let el = match dir {
            Direction::Forward => el.wrapping_add(el_steps),
            Direction::Reverse => el.wrapping_sub(el_steps),
        };
        self.set_reg(Register::ElPos, el);
    }

    /// Move by `dist` full-step units (2⁻⁴⁰ step) in the current direction.
    /// Returns the number of whole microsteps taken.
    fn move_full(&mut self, dist: u128) -> u128 {
        let micro = dist << self.step_shift();
        let total = u128::from(self.frac) + micro;
        let steps = total >> FRAC_BITS;
        self.frac = (total & FRAC_MASK) as u64;
        if steps > 0 {
            self.apply_steps(self.dir, steps);
        }
        steps
    }

    fn cruise(&mut self, avail: u64) -> Option<u64> {
        if avail == 0 || self.v == 0 {
            return None;
        }
        self.move_full(u128::from(self.v) * u128::from(avail));
        Some(avail)
    }

    fn ramp_up(&mut self, a: u64, n: u64) -> u128 {
        let dist = s_up(self.v, a, n);
        self.v = self.v.saturating_add(a.saturating_mul(n));
        self.move_full(dist)
    }

    fn ramp_down(&mut self, d: u64, n: u64) -> u128 {
        let dist = s_down(self.v, d, n);
        self.v = self.v.saturating_sub(d.saturating_mul(n));
        self.move_full(dist)
    }

    /// Decelerate to the floor speed, then stop.
    fn decel_to_stop(&mut self, avail: u64) -> Ph {
        let vf = self.floor();
        let d = self.dec();
        if self.v <= vf {
            self.v = 0;
            return Ph::Done;
        }
        if d == 0 {
            return match self.cruise(avail) {
                Some(n) => Ph::Used(n),
                None => Ph::Wait,
            };
        }
        let n1 = (self.v - vf) / d;
        if n1 == 0 {
            self.v = 0;
            return Ph::Done;
        }
        if avail == 0 {
            return Ph::Wait;
        }
        let n = n1.min(avail);
        self.ramp_down(d, n);
        Ph::Used(n)
    }

    /// One phase of the engine: `Some(ticks used)` (0 for an instant state
    /// change) or `None` when nothing more happens within `avail` ticks.
    fn step(&mut self, avail: u64) -> Option<u64> {
        match self.motion {
            Motion::Idle => None,
            Motion::Stopping { hiz } => match self.decel_to_stop(avail) {
                Ph::Used(n) => Some(n),
                Ph::Wait => None,
                Ph::Done => {
                    self.motion = Motion::Idle;
                    if hiz {
                        self.hiz = true;
                    }
                    Some(0)
                }
            },
            Motion::Speed { dir, spd, .. } => self.step_speed(dir, spd, avail),
            Motion::Position {
                dir,
                target,
                remaining,
                braking,
            } => self.step_position(dir, target, remaining, braking, avail),
        }
    }

    fn flip(&mut self, dir: Direction) {
        self.dir = dir;
        self.frac = 0;
    }

    fn step_speed(&mut self, dir: Direction, spd: u64, avail: u64) -> Option<u64> {
        if self.dir != dir {
            return match self.decel_to_stop(avail) {
                Ph::Used(n) => Some(n),
                Ph::Wait => None,
                Ph::Done => {
                    self.flip(dir);
                    Some(0)
                }
            };
        }
        let vt = self.speed_target(spd);
        let v = self.v;
        if v == 0 && vt > 0 {
            let start = self.floor().min(vt);
            if start > 0 {
                self.v = start;
                return Some(0);
            }
        }
        if v < vt {
            let a = self.acc();
            if a == 0 {
                return self.cruise(avail);
            }
            let n1 = (vt - v) / a;
            if n1 == 0 {
                self.v = vt;
                return Some(0);
            }
            if avail == 0 {
                return None;
            }
            let n = n1.min(avail);
            self.ramp_up(a, n);
            return Some(n);
        }
        if v > vt {
            let d = self.dec();
            if d == 0 {
                return self.cruise(avail);
            }
            let n1 = (v - vt) / d;
            if n1 == 0 {
                self.v = vt;
                return Some(0);
            }
            if avail == 0 {
                return None;
            }
            let n = n1.min(avail);
            self.ramp_down(d, n);
            return Some(n);
        }
        self.cruise(avail)
    }

    /// Finish a positioning command: `remaining` microsteps in `dir` land
    /// exactly on the target.
    fn land(&mut self, dir: Direction, remaining: u64) {
        self.apply_steps(dir, u128::from(remaining));
        self.frac = 0;
        self.v = 0;
        self.motion = Motion::Idle;
    }

    fn set_position_state(&mut self, dir: Direction, target: u32, remaining: u64, braking: bool) {
        self.motion = Motion::Position {
            dir,
            target,
            remaining,
            braking,
        };
    }

    fn step_position(
        &mut self,
        dir: Direction,
        target: u32,
        remaining: u64,
        braking: bool,
        avail: u64,
    ) -> Option<u64> {
        if self.dir != dir {
            return match self.decel_to_stop(avail) {
                Ph::Used(n) => Some(n),
                Ph::Wait => None,
                Ph::Done => {
                    self.flip(dir);
                    let rem = dist_in_dir(dir, self.abs_raw(), target);
                    self.set_position_state(dir, target, rem, false);
                    Some(0)
                }
            };
        }
        if remaining == 0 {
            self.land(dir, 0);
            return Some(0);
        }
        let ms = 1u128 << self.step_shift();
        // Remaining distance in 2⁻⁴⁰ microsteps (> 0: remaining ≥ 1, frac < 1).
        let r = (u128::from(remaining) << FRAC_BITS).saturating_sub(u128::from(self.frac));
        let v = self.v;
        let vf = self.floor();
        let vmax = self.vmax();
        let d = self.dec();
        // Distance `dist` (full-step units) reaches the target?
        let reaches = |dist: u128| dist.saturating_mul(ms) >= r;

        if braking {
            if v > vf && d > 0 {
                let n1 = (v - vf) / d;
                if n1 == 0 {
                    self.v = vf;
                    return Some(0);
                }
                if avail == 0 {
                    return None;
                }
                let n = n1.min(avail);
                if let Some(j) = first_true(1, n, |j| reaches(s_down(v, d, j))) {
                    self.land(dir, remaining);
                    return Some(j);
                }
                let steps = self.ramp_down(d, n);
                let rem = remaining.saturating_sub(u64::try_from(steps).unwrap_or(u64::MAX));
                self.set_position_state(dir, target, rem, true);
                return Some(n);
            }
            if v == 0 {
                // Braked to a standstill short of the target (floor 0): go on.
                self.set_position_state(dir, target, remaining, false);
                return Some(0);
            }
            return self.cruise_position(dir, target, remaining, r, None, avail);
        }

        // Start braking once the remaining distance is within the braking distance.
        let b = brake_dist(v, vf, d);
        if b.is_none_or(reaches) && v > 0 {
            self.set_position_state(dir, target, remaining, true);
            return Some(0);
        }
        if v == 0 && vf > 0 {
            self.v = vf;
            return Some(0);
        }
        if v > vmax {
            // Over speed (MAX_SPEED lowered): d > 0 here, else b would be None.
            let n1 = (v - vmax) / d.max(1);
            if n1 == 0 {
                self.v = vmax;
                return Some(0);
            }
            if avail == 0 {
                return None;
            }
            let n = n1.min(avail);
            if let Some(j) = first_true(1, n, |j| reaches(s_down(v, d, j))) {
                self.land(dir, remaining);
                return Some(j);
            }
            let steps = self.ramp_down(d, n);
            let rem = remaining.saturating_sub(u64::try_from(steps).unwrap_or(u64::MAX));
            self.set_position_state(dir, target, rem, false);
            return Some(n);
        }
        if v < vmax {
            let a = self.acc();
            if a == 0 {
                return self.cruise_position(dir, target, remaining, r, b, avail);
            }
            let n1 = (vmax - v) / a;
            if n1 == 0 {
                self.v = vmax;
                return Some(0);
            }
            if avail == 0 {
                return None;
            }
            let n = n1.min(avail);
            let trigger = |j: u64| {
                let moved = s_up(v, a, j);
                match brake_dist(v + a * j, vf, d) {
                    None => true,
                    Some(bd) => reaches(moved.saturating_add(bd)),
                }
            };
            if let Some(j) = first_true(1, n, trigger) {
                if reaches(s_up(v, a, j)) {
                    self.land(dir, remaining);
                } else {
                    let steps = self.ramp_up(a, j);
                    let rem = remaining.saturating_sub(u64::try_from(steps).unwrap_or(u64::MAX));
                    self.set_position_state(dir, target, rem, true);
                }
                return Some(j);
            }
            let steps = self.ramp_up(a, n);
            let rem = remaining.saturating_sub(u64::try_from(steps).unwrap_or(u64::MAX));
            self.set_position_state(dir, target, rem, false);
            return Some(n);
        }
        self.cruise_position(dir, target, remaining, r, b, avail)
    }

    /// Constant speed towards the target. `brake`: braking distance at this
    /// speed when braking has not started yet (`None` when already braking
    /// or no braking applies): the phase ends where braking must start.
    fn cruise_position(
        &mut self,
        dir: Direction,
        target: u32,
        remaining: u64,
        r: u128,
        brake: Option<u128>,
        avail: u64,
    ) -> Option<u64> {
        let v = self.v;
        if v == 0 || avail == 0 {
            return None;
        }
        let per = u128::from(v) << self.step_shift();
        let ms = 1u128 << self.step_shift();
        let bs = brake.unwrap_or(0).saturating_mul(ms);
        let braking = matches!(self.motion, Motion::Position { braking: true, .. });
        // First tick after which r − j·per ≤ bs (bs < r: not yet triggered).
        let gap = r.saturating_sub(bs);
        let j = gap.div_ceil(per).max(1);
        if j <= u128::from(avail) {
            let j64 = u64::try_from(j).unwrap_or(avail);
            if per.saturating_mul(j) >= r {
                self.land(dir, remaining);
            } else {
                let steps = self.move_full(u128::from(v) * j);
                let rem = remaining.saturating_sub(u64::try_from(steps).unwrap_or(u64::MAX));
                self.set_position_state(dir, target, rem, true);
            }
            return Some(j64);
        }
        let steps = self.move_full(u128::from(v) * u128::from(avail));
        let rem = remaining.saturating_sub(u64::try_from(steps).unwrap_or(u64::MAX));
        self.set_position_state(dir, target, rem, braking);
        Some(avail)
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use std::vec;
    use std::vec::Vec;

    use super::*;
    use crate::powerstep::commands::Direction::{Forward, Reverse};

    const MS: u64 = 1_000_000;
    const TICK: u64 = TICK_NS;

    fn send(d: &mut Powerstep01, bytes: &[u8]) -> Vec<u8> {
        bytes.iter().map(|b| d.exchange(*b)).collect()
    }

    fn cmd(d: &mut Powerstep01, c: Command) -> Vec<u8> {
        send(d, c.encode().as_slice())
    }

    fn get_status(d: &mut Powerstep01) -> Status {
        let rx = send(d, &[0xD0, 0, 0]);
        Status::from_bytes(rx[1], rx[2])
    }

    fn get_param(d: &mut Powerstep01, r: Register) -> u32 {
        let mut tx = vec![0x20 | r.address()];
        tx.extend(core::iter::repeat_n(0u8, usize::from(r.bytes())));
        let rx = send(d, &tx);
        rx[1..].iter().fold(0u32, |a, b| (a << 8) | u32::from(*b))
    }

    /// Powered up, first GetStatus done (UVLO released), still in HiZ.
    fn ready() -> Powerstep01 {
        let mut d = Powerstep01::new();
        get_status(&mut d);
        d.clear_log();
        d
    }

    /// Advance in `chunk` steps until BUSY is released (at most `limit_ms`).
    fn settle(d: &mut Powerstep01, chunk: u64, limit_ms: u64) -> u64 {
        let mut t = 0;
        while d.is_busy() {
            assert!(t < limit_ms * MS, "still busy after {limit_ms} ms");
            d.advance(chunk);
            t += chunk;
        }
        t
    }

    fn error(d: &Powerstep01) -> bool {
        d.status().command_error()
    }

    // ------------------------------------------------------------ power-up

    #[test]
    fn power_up_registers_hold_their_table_reset_values() {
        let d = Powerstep01::new();
        for info in REGISTERS.iter().filter(|i| i.register != Register::Status) {
            assert_eq!(
                d.register(info.register),
                info.reset,
                "{}",
                info.voltage_mode_name
            );
        }
        assert!(d.is_hiz());
        assert!(!d.is_busy());
        assert_eq!(d.abs_pos(), 0);
    }

    #[test]
    fn uvlo_reads_asserted_after_power_up_until_the_first_get_status() {
        let mut d = Powerstep01::new();
        let p = Status(get_param(&mut d, Register::Status) as u16);
        assert!(p.uvlo());
        assert_eq!(p.raw(), 0xE413, "HiZ, idle, forward, UVLO low");
        assert!(Status(get_param(&mut d, Register::Status) as u16).uvlo());
        let s = get_status(&mut d);
        assert!(s.uvlo());
        let s = get_status(&mut d);
        assert!(!s.uvlo());
        assert_eq!(s.raw(), 0xE613);
    }

    // ------------------------------------------------------ failure flags

    #[test]
    fn set_param_to_a_read_only_register_is_refused_at_the_command_byte() {
        for reg in [Register::Speed, Register::AdcOut, Register::Status] {
            let mut d = ready();
            // SetParam(reg), then what would be its argument is a GetParam(KVAL_HOLD).
            let rx = send(&mut d, &[reg.address(), 0x29, 0x00]);
            assert_eq!(rx, [0x00, 0x00, 0x29], "{reg:?}");
            assert!(error(&d));
            assert_eq!(d.command_errors(), 1);
            assert_eq!(
                d.received().last(),
                Some(&Command::GetParam(Register::KvalHold))
            );
        }
    }

    #[test]
    fn set_param_to_a_non_existent_register_is_refused_at_the_command_byte() {
        for b in [0x1C, 0x1D, 0x1E, 0x1F] {
            let mut d = ready();
            let rx = send(&mut d, &[b, 0x29, 0x00]);
            assert_eq!(rx, [0x00, 0x00, 0x29], "{b:#04x}");
            assert!(error(&d));
            assert_eq!(d.received_count(), 1);
        }
    }

    #[test]
    fn get_param_of_a_non_existent_register_is_an_unknown_command() {
        for b in [0x20, 0x3C, 0x3F] {
            let mut d = ready();
            assert_eq!(send(&mut d, &[b, 0x00]), [0, 0]);
            assert!(error(&d));
        }
    }

    #[test]
    fn ws_register_written_while_moving_is_refused_after_the_last_argument() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 20_000));
        d.advance(MS);
        send(&mut d, &[0x05]); // SetParam(ACC)
        assert!(!error(&d));
        send(&mut d, &[0x01]);
        assert!(!error(&d));
        send(&mut d, &[0x23]);
        assert!(error(&d), "refused after the last argument byte");
        assert_eq!(d.register(Register::Acc), 0x08A);
        assert_eq!(d.command_errors(), 1);
        // Stopped: accepted.
        cmd(&mut d, Command::HardStop);
        get_status(&mut d);
        cmd(&mut d, Command::SetParam(Register::Acc, 0x123));
        assert!(!error(&d));
        assert_eq!(d.register(Register::Acc), 0x123);
    }

    #[test]
    fn wh_register_written_while_not_in_hiz_is_refused() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::StepMode, 0x04));
        assert!(!error(&d));
        assert_eq!(d.register(Register::StepMode), 0x04);
        cmd(&mut d, Command::HardStop); // bridges on, motor stopped
        assert!(!d.is_hiz());
        send(&mut d, &[0x16]);
        assert!(!error(&d));
        send(&mut d, &[0x02]);
        assert!(error(&d));
        assert_eq!(d.register(Register::StepMode), 0x04);
        cmd(&mut d, Command::SetParam(Register::Config, 0x2C98));
        assert_eq!(d.register(Register::Config), 0x2C88);
        assert_eq!(d.command_errors(), 2);
        cmd(&mut d, Command::HardHiZ);
        cmd(&mut d, Command::SetParam(Register::Config, 0x2C98));
        assert_eq!(d.register(Register::Config), 0x2C98);
    }

    #[test]
    fn a_response_producing_command_abandons_the_pending_response() {
        let mut d = ready();
        d.set_register_raw(Register::AbsPos, 0x12_3456);
        // GetParam(ABS_POS), then GetParam(KVAL_HOLD) before the first response is out.
        let rx = send(&mut d, &[0x21, 0x29, 0x00, 0x00]);
        assert_eq!(rx, [0x00, 0x12, 0x29, 0x00]);
    }

    #[test]
    fn commands_without_response_do_not_disturb_a_pending_response() {
        let mut d = ready();
        d.set_register_raw(Register::AbsPos, 0x12_3456);
        let rx = send(&mut d, &[0x21, 0x51, 0x00, 0x10, 0x00, 0x00]);
        assert_eq!(rx, [0x00, 0x12, 0x34, 0x56, 0x00, 0x00]);
        assert_eq!(d.received().last(), Some(&Command::Run(Forward, 0x1000)));
    }

    #[test]
    fn get_param_value_is_captured_when_the_command_byte_is_decoded() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 50_000));
        d.advance(100 * MS);
        let at_decode = d.abs_pos();
        assert!(at_decode > 0);
        send(&mut d, &[0x21]);
        d.advance(100 * MS);
        let rx = send(&mut d, &[0, 0, 0]);
        let v = rx.iter().fold(0u32, |a, b| (a << 8) | u32::from(*b));
        assert_eq!(sign_extend_22(v), at_decode);
        assert!(d.abs_pos() > at_decode);
    }

    #[test]
    fn get_status_clears_latched_flags_but_get_param_status_does_not() {
        let mut d = ready();
        send(&mut d, &[0xEB]);
        d.set_switch(true);
        d.inject(Fault::Stall);
        d.inject(Fault::Overcurrent);
        d.inject(Fault::Uvlo);
        for _ in 0..2 {
            let p = Status(get_param(&mut d, Register::Status) as u16);
            assert!(p.command_error() && p.switch_event() && p.stalled());
            assert!(p.overcurrent() && p.uvlo());
        }
        let s = get_status(&mut d);
        assert!(s.command_error() && s.switch_event() && s.stalled());
        assert!(s.overcurrent() && s.uvlo());
        let s = get_status(&mut d);
        assert!(!s.command_error() && !s.switch_event() && !s.stalled());
        assert!(!s.overcurrent() && !s.uvlo());
        assert!(s.switch_closed(), "SW_F is a level, not a latch");
    }

    #[test]
    fn latched_thermal_status_stays_while_the_condition_persists() {
        let mut d = ready();
        d.inject(Fault::ThermalWarning);
        assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Warning);
        assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Warning);
        d.inject(Fault::ThermalNormal);
        assert_eq!(d.status().thermal(), ThermalStatus::Warning, "latched");
        assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Warning);
        assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Normal);
    }

    #[test]
    fn move_while_moving_is_refused() {
        let mut d = ready();
        cmd(&mut d, Command::Move(Forward, 100_000));
        d.advance(10 * MS);
        let pos = d.abs_pos();
        cmd(&mut d, Command::Move(Reverse, 5));
        assert!(error(&d));
        assert!(d.is_busy());
        settle(&mut d, 10 * MS, 600_000);
        assert_eq!(d.abs_pos(), 100_000);
        assert!(pos > 0);
    }

    #[test]
    fn move_while_running_at_constant_speed_is_refused() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 10_000));
        d.advance(500 * MS);
        assert!(!d.is_busy(), "Run at target speed releases BUSY");
        cmd(&mut d, Command::Move(Forward, 5));
        assert!(error(&d));
    }

    #[test]
    fn goto_family_while_busy_is_refused() {
        let mut d = ready();
        cmd(&mut d, Command::Move(Forward, 100_000));
        d.advance(MS);
        for c in [
            Command::GoTo(5),
            Command::GoToDir(Reverse, 5),
            Command::GoHome,
            Command::GoMark,
        ] {
            let before = d.command_errors();
            cmd(&mut d, c);
            assert_eq!(d.command_errors(), before + 1, "{c:?}");
        }
        settle(&mut d, 10 * MS, 600_000);
        assert_eq!(d.abs_pos(), 100_000);
    }

    #[test]
    fn unknown_byte_sets_cmd_error_and_consumes_no_arguments() {
        for b in [0xEB, 0xF8, 0xFF, 0x61, 0x80, 0xE0] {
            let mut d = ready();
            let rx = send(&mut d, &[b, 0x29, 0x00]);
            assert_eq!(rx, [0x00, 0x00, 0x29], "{b:#04x}");
            assert!(error(&d));
        }
    }

    #[test]
    fn a_half_received_command_swallows_the_next_bytes() {
        let mut d = ready();
        send(&mut d, &[0x51]); // Run forward: 3 argument bytes pending
        let rx = send(&mut d, &[0x29, 0xD0, 0x00]); // GetParam, GetStatus, NOP...
        assert_eq!(rx, [0, 0, 0], "no response: they were arguments");
        assert_eq!(d.received_count(), 1);
        assert_eq!(d.received().last(), Some(&Command::Run(Forward, 0x9_D000)));
        assert!(!d.received().any(|c| *c == Command::GetStatus));
        assert!(!error(&d));
    }

    #[test]
    fn reset_device_outside_hiz_is_refused() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::KvalRun, 0x40));
        cmd(&mut d, Command::HardStop);
        cmd(&mut d, Command::ResetDevice);
        assert!(error(&d));
        assert_eq!(d.register(Register::KvalRun), 0x40);
        assert!(!d.status().uvlo());
    }

    #[test]
    fn reset_device_in_hiz_restores_the_power_up_state() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::KvalRun, 0x40));
        cmd(&mut d, Command::Move(Forward, 1000));
        settle(&mut d, MS, 10_000);
        cmd(&mut d, Command::HardHiZ);
        cmd(&mut d, Command::ResetDevice);
        assert!(!error(&d));
        assert_eq!(d.register(Register::KvalRun), 0x29);
        assert_eq!(d.abs_pos(), 0);
        assert!(d.is_hiz());
        assert!(get_status(&mut d).uvlo());
    }

    #[test]
    fn register_writes_are_masked_to_the_register_width() {
        let mut d = ready();
        send(&mut d, &[0x05, 0xFF, 0xFF]);
        assert_eq!(d.register(Register::Acc), 0xFFF);
        send(&mut d, &[0x03, 0xFF, 0xFF, 0xFF]);
        assert_eq!(d.register(Register::Mark), 0x3F_FFFF);
        send(&mut d, &[0x11, 0xFF]);
        assert_eq!(d.register(Register::KTherm), 0xF);
        assert!(!error(&d));
    }

    #[test]
    fn receive_log_keeps_the_last_32_commands() {
        let mut d = ready();
        d.clear_log();
        for i in 0..40u32 {
            cmd(&mut d, Command::SetParam(Register::Mark, i));
        }
        assert_eq!(d.received_count(), 40);
        let log: Vec<_> = d.received().copied().collect();
        assert_eq!(log.len(), LOG_LEN);
        assert_eq!(log[0], Command::SetParam(Register::Mark, 8));
        assert_eq!(log[31], Command::SetParam(Register::Mark, 39));
    }

    #[test]
    fn random_byte_streams_never_panic() {
        let mut rng = Rng(0x1234_5678_9ABC_DEF1);
        for _ in 0..20 {
            let mut d = Powerstep01::new();
            for i in 0..5_000u32 {
                let b = rng.next() as u8;
                d.exchange(b);
                if i % 7 == 0 {
                    d.advance(rng.below(50 * MS));
                }
                if i % 97 == 0 {
                    d.set_switch(rng.next() & 1 == 1);
                }
                if i % 131 == 0 {
                    d.step_clock_pulse();
                }
            }
            d.advance(u64::MAX);
            d.advance(u64::MAX);
            let _ = d.status();
        }
    }

    // -------------------------------------------------------------- motion

    /// Deterministic xorshift64*.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        fn below(&mut self, n: u64) -> u64 {
            if n == 0 {
                0
            } else {
                self.next() % n
            }
        }
        fn range(&mut self, lo: u64, hi: u64) -> u64 {
            lo + self.below(hi - lo + 1)
        }
    }

    #[test]
    fn run_reaches_speed_after_the_analytic_acceleration_time() {
        let mut d = ready();
        let spd = 33_554u32; // ≈ 500 step/s
        cmd(&mut d, Command::Run(Forward, spd));
        // Speed rises by ACC (2⁻⁴⁰ step/tick²) per tick; SPD is 2⁻²⁸ step/tick.
        let acc = 0x08Au64;
        let analytic = (u64::from(spd) << 12) as f64 / acc as f64; // ticks
        let whole = analytic.floor() as u64;
        d.advance((whole - 1) * TICK);
        assert!(d.is_busy());
        assert_eq!(d.status().motor_status(), MotorStatus::Accelerating);
        d.advance(2 * TICK);
        assert!(!d.is_busy());
        assert_eq!(d.speed_reg(), spd);
        assert_eq!(d.status().motor_status(), MotorStatus::ConstantSpeed);
        // The speed ramp itself is exact: v = k·ACC after k ticks.
        let mut e = ready();
        cmd(&mut e, Command::Run(Forward, spd));
        e.advance(1000 * TICK);
        assert_eq!(e.speed_internal(), 1000 * acc);
    }

    #[test]
    fn run_speed_is_clamped_to_min_and_max_speed() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::MinSpeed, 0x100));
        cmd(&mut d, Command::Run(Forward, 0xF_FFFF));
        d.advance(2000 * MS);
        assert_eq!(d.speed_internal(), 0x041 << 22, "MAX_SPEED");
        cmd(&mut d, Command::Run(Forward, 1));
        d.advance(2000 * MS);
        assert_eq!(d.speed_internal(), 0x100 << 16, "MIN_SPEED");
    }

    #[test]
    fn speeds_count_full_steps_and_positions_microsteps() {
        for ss in [0u32, 4, 7] {
            let mut d = ready();
            cmd(&mut d, Command::SetParam(Register::StepMode, ss));
            cmd(&mut d, Command::SetParam(Register::Acc, 0xFFF)); // infinite
                                                                  // 0x10000 SPEED units = 2⁻¹² step/tick = 976.5625 step/s exactly.
            cmd(&mut d, Command::Run(Forward, 0x1_0000));
            d.advance(1_000 * MS); // 4 000 000 ticks
            assert_eq!(
                i64::from(d.abs_pos()),
                (4_000_000i64 << ss) >> 12,
                "STEP_SEL {ss}"
            );
        }
    }

    #[test]
    fn abs_pos_wraps_at_22_bits() {
        let mut d = ready();
        cmd(
            &mut d,
            Command::SetParam(Register::AbsPos, wrap_22((1 << 21) - 10)),
        );
        cmd(&mut d, Command::Move(Forward, 20));
        settle(&mut d, MS, 10_000);
        assert_eq!(d.abs_pos(), -(1 << 21) + 10);
        assert_eq!(get_param(&mut d, Register::AbsPos), 0x20_000A);
        cmd(&mut d, Command::ResetPos);
        cmd(&mut d, Command::Move(Reverse, 1));
        settle(&mut d, MS, 10_000);
        assert_eq!(get_param(&mut d, Register::AbsPos), 0x3F_FFFF);
        assert_eq!(d.abs_pos(), -1);
    }

    /// Drive one positioning command to its end, checking it never passes
    /// the target and never exceeds MAX_SPEED. Returns the time taken.
    fn land(d: &mut Powerstep01, dir: Direction, target: u32, rng: &mut Rng) -> u64 {
        let vmax = d.vmax();
        let mut left = dist_in_dir(dir, d.abs_raw(), target);
        let mut t = 0u64;
        while d.is_busy() {
            let chunk = rng.range(MS, 60 * MS) + rng.below(250);
            d.advance(chunk);
            t += chunk;
            let now = dist_in_dir(dir, d.abs_raw(), target);
            assert!(now <= left, "passed the target: {left} -> {now}");
            assert!(d.speed_internal() <= vmax.max(d.floor()));
            left = now;
            assert!(t < 3_600_000 * MS, "move does not end");
        }
        assert_eq!(d.abs_raw(), target);
        assert_eq!(d.speed_reg(), 0);
        assert_eq!(d.status().motor_status(), MotorStatus::Stopped);
        assert!(!error(d));
        t
    }

    #[test]
    fn go_to_and_move_land_exactly_on_random_targets() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        for _ in 0..300 {
            let mut d = ready();
            let ss = rng.below(8) as u32;
            cmd(&mut d, Command::SetParam(Register::StepMode, ss));
            cmd(
                &mut d,
                Command::SetParam(Register::MaxSpeed, rng.range(0x10, 0x3FF) as u32),
            );
            let acc = if rng.below(10) == 0 {
                0xFFF
            } else {
                rng.range(0x10, 0xFFE)
            };
            cmd(&mut d, Command::SetParam(Register::Acc, acc as u32));
            cmd(
                &mut d,
                Command::SetParam(Register::Dec, rng.range(0x10, 0xFFE) as u32),
            );
            let min = match rng.below(3) {
                0 => 0,
                1 => rng.below(0x100),
                _ => rng.below(0x2000), // with LSPD_OPT sometimes set
            };
            cmd(&mut d, Command::SetParam(Register::MinSpeed, min as u32));
            cmd(
                &mut d,
                Command::SetParam(Register::AbsPos, rng.next() as u32),
            );
            assert!(!error(&d));
            // At most ~20 000 full steps so the test stays fast.
            let span = (20_000u64 << ss).min(1 << 21);
            let dist = if rng.below(8) == 0 {
                rng.below(4)
            } else {
                rng.below(span)
            };
            let pos = d.abs_raw();
            let (c, dir, target) = match rng.below(3) {
                0 => {
                    let dir = if rng.next() & 1 == 0 {
                        Forward
                    } else {
                        Reverse
                    };
                    let t = match dir {
                        Forward => pos.wrapping_add(dist as u32),
                        Reverse => pos.wrapping_sub(dist as u32),
                    } & POS_MASK;
                    (Command::Move(dir, dist as u32), dir, t)
                }
                1 => {
                    let delta = if rng.next() & 1 == 0 {
                        dist as i64
                    } else {
                        -(dist as i64)
                    };
                    let t = wrap_22((i64::from(sign_extend_22(pos)) + delta) as i32);
                    let dir = if delta >= 0 { Forward } else { Reverse };
                    (Command::GoTo(sign_extend_22(t)), dir, t)
                }
                _ => {
                    let t = (rng.next() as u32) & POS_MASK;
                    let dir = if rng.next() & 1 == 0 {
                        Forward
                    } else {
                        Reverse
                    };
                    // Keep the forced path short enough.
                    let t = if dist_in_dir(dir, pos, t) > span {
                        match dir {
                            Forward => pos.wrapping_add(dist as u32) & POS_MASK,
                            Reverse => pos.wrapping_sub(dist as u32) & POS_MASK,
                        }
                    } else {
                        t
                    };
                    (Command::GoToDir(dir, sign_extend_22(t)), dir, t)
                }
            };
            cmd(&mut d, c);
            assert!(!error(&d), "{c:?}");
            land(&mut d, dir, target, &mut rng);
        }
    }

    /// (ABS_POS, speed, STATUS, EL_POS) at a time.
    fn snapshot(d: &Powerstep01) -> (i32, u64, u16, u32) {
        (
            d.abs_pos(),
            d.speed_internal(),
            d.status().raw(),
            d.register(Register::ElPos),
        )
    }

    /// A scenario with several phase changes, sampled every 7 ms; `chunk`
    /// is how `advance` is sliced between samples.
    fn scenario(chunk: u64) -> Vec<(i32, u64, u16, u32)> {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::StepMode, 4));
        cmd(&mut d, Command::SetParam(Register::MinSpeed, 0x40));
        cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x80));
        cmd(&mut d, Command::Move(Forward, 123_457));
        let mut out = Vec::new();
        for sample in 0..2_300u64 {
            let mut left = 7 * MS;
            while left > 0 {
                let c = chunk.min(left);
                d.advance(c);
                left -= c;
            }
            out.push(snapshot(&d));
            match sample {
                // Retarget, reverse, run, stop: commands at the same instants.
                800 => {
                    cmd(&mut d, Command::GoTo(-5_000));
                }
                1_600 => {
                    cmd(&mut d, Command::Run(Forward, 30_000));
                }
                1_800 => {
                    cmd(&mut d, Command::GoTo(-77));
                }
                2_250 => {
                    cmd(&mut d, Command::SoftStop);
                }
                _ => {}
            }
        }
        out
    }

    #[test]
    fn slicing_advance_in_1_ms_or_7_ms_chunks_gives_the_same_motion() {
        let a = scenario(MS);
        let b = scenario(7 * MS);
        let c = scenario(333_333);
        assert_eq!(a, b);
        assert_eq!(a, c);
        // The scenario really moved and landed.
        assert!(a.iter().any(|s| s.0 == 123_457));
        assert!(a.iter().any(|s| s.0 == -5_000));
        assert_eq!(a.last().map(|s| (s.0, s.1)), Some((-77, 0)));
    }

    #[test]
    fn long_runs_at_full_speed_do_not_overflow_or_depend_on_slicing() {
        let mut a = ready();
        let mut b = ready();
        for d in [&mut a, &mut b] {
            cmd(d, Command::SetParam(Register::MaxSpeed, 0x3FF));
            cmd(d, Command::Run(Reverse, 0xF_FFFF));
        }
        a.advance(3_600_000 * MS);
        for _ in 0..3_600 {
            b.advance(1_000 * MS);
        }
        assert_eq!(snapshot(&a), snapshot(&b));
        assert_eq!(a.speed_internal(), 0x3FF << 22);
    }

    #[test]
    fn soft_stop_decelerates_with_dec() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::Dec, 0x100));
        cmd(&mut d, Command::Run(Forward, 40_000));
        settle(&mut d, MS, 10_000);
        let v0 = d.speed_internal();
        cmd(&mut d, Command::SoftStop);
        assert!(d.is_busy());
        d.advance(1_000 * TICK);
        assert_eq!(d.speed_internal(), v0 - 1_000 * 0x100);
        assert_eq!(d.status().motor_status(), MotorStatus::Decelerating);
        let n = v0 / 0x100; // ticks until below one DEC step
        d.advance((n - 1_000 - 1) * TICK);
        assert!(d.is_busy());
        d.advance(TICK);
        assert!(!d.is_busy());
        assert_eq!(d.speed_reg(), 0);
        assert!(!d.is_hiz(), "SoftStop holds");
        let p = d.abs_pos();
        d.advance(100 * MS);
        assert_eq!(d.abs_pos(), p);
    }

    #[test]
    fn soft_hiz_decelerates_then_releases_the_bridges() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        settle(&mut d, MS, 10_000);
        cmd(&mut d, Command::SoftHiZ);
        assert!(!d.is_hiz());
        settle(&mut d, MS, 10_000);
        assert!(d.is_hiz());
        assert_eq!(d.speed_reg(), 0);
    }

    #[test]
    fn hard_stop_stops_at_once() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(300 * MS);
        assert!(d.speed_reg() > 0);
        cmd(&mut d, Command::HardStop);
        assert_eq!(d.speed_reg(), 0);
        assert!(!d.is_busy());
        assert!(!d.is_hiz());
        let p = d.abs_pos();
        d.advance(100 * MS);
        assert_eq!(d.abs_pos(), p);
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(MS);
        cmd(&mut d, Command::HardHiZ);
        assert_eq!(d.speed_reg(), 0);
        assert!(d.is_hiz());
    }

    #[test]
    fn stop_commands_in_hiz_enable_the_bridges_without_moving() {
        let mut d = ready();
        cmd(&mut d, Command::SoftStop);
        assert!(!d.is_hiz());
        assert!(!d.is_busy());
        cmd(&mut d, Command::HardHiZ);
        cmd(&mut d, Command::HardStop);
        assert!(!d.is_hiz());
        assert_eq!(d.abs_pos(), 0);
    }

    fn sw_user_mode(d: &mut Powerstep01) {
        cmd(
            d,
            Command::SetParam(Register::Config, 0x2C88 | u32::from(Config::SW_MODE)),
        );
    }

    #[test]
    fn go_until_resets_abs_pos_on_switch_closing_then_soft_stops() {
        let mut d = ready();
        sw_user_mode(&mut d);
        cmd(
            &mut d,
            Command::GoUntil(SwitchAction::ResetAbsPos, Forward, 20_000),
        );
        d.advance(500 * MS);
        assert!(d.is_busy(), "GoUntil keeps BUSY low while searching");
        assert!(d.abs_pos() > 0);
        let v = d.speed_internal();
        d.set_switch(true);
        assert_eq!(d.abs_pos(), 0);
        assert_eq!(d.speed_internal(), v, "soft stop: no speed jump");
        assert!(d.status().switch_event());
        settle(&mut d, MS, 10_000);
        assert_eq!(d.speed_reg(), 0);
        assert!(d.abs_pos() > 0, "decelerated past the switch");
        assert!(!d.is_hiz());
    }

    #[test]
    fn go_until_copies_abs_pos_to_mark_with_act_1() {
        let mut d = ready();
        sw_user_mode(&mut d);
        cmd(
            &mut d,
            Command::GoUntil(SwitchAction::CopyToMark, Reverse, 20_000),
        );
        d.advance(500 * MS);
        let p = d.abs_pos();
        assert!(p < 0);
        d.set_switch(true);
        assert_eq!(sign_extend_22(d.register(Register::Mark)), p);
        settle(&mut d, MS, 10_000);
        assert!(d.abs_pos() < p);
    }

    #[test]
    fn go_until_hard_stops_when_sw_mode_is_0() {
        let mut d = ready();
        cmd(
            &mut d,
            Command::GoUntil(SwitchAction::ResetAbsPos, Forward, 20_000),
        );
        d.advance(500 * MS);
        d.set_switch(true);
        assert_eq!(d.abs_pos(), 0);
        assert_eq!(d.speed_reg(), 0);
        assert!(!d.is_busy());
    }

    #[test]
    fn release_sw_runs_slowly_until_the_switch_opens_then_hard_stops() {
        let mut d = ready();
        sw_user_mode(&mut d);
        d.set_switch(true);
        cmd(
            &mut d,
            Command::ReleaseSw(SwitchAction::CopyToMark, Reverse),
        );
        d.advance(1_000 * MS);
        assert!(d.is_busy());
        assert_eq!(d.speed_reg(), 335, "5 step/s");
        let p = d.abs_pos();
        // 5 step/s · 128 microsteps for ~1 s (acceleration takes ~2.5 ms).
        assert!((-640..=-630).contains(&p), "{p}");
        d.set_switch(false);
        assert_eq!(sign_extend_22(d.register(Register::Mark)), p);
        assert_eq!(d.speed_reg(), 0);
        assert!(!d.is_busy());
        d.advance(100 * MS);
        assert_eq!(d.abs_pos(), p);
    }

    #[test]
    fn release_sw_uses_min_speed_when_it_is_faster() {
        let mut d = ready();
        sw_user_mode(&mut d);
        cmd(&mut d, Command::SetParam(Register::MinSpeed, 0x200)); // ≈ 122 step/s
        d.set_switch(true);
        cmd(
            &mut d,
            Command::ReleaseSw(SwitchAction::ResetAbsPos, Forward),
        );
        d.advance(100 * MS);
        assert_eq!(d.speed_internal(), 0x200 << 16);
        d.set_switch(false);
        assert_eq!(d.abs_pos(), 0);
    }

    #[test]
    fn switch_closing_hard_stops_the_motor_when_sw_mode_is_0() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(300 * MS);
        d.set_switch(true);
        assert_eq!(d.speed_reg(), 0);
        assert!(!d.is_busy());
        let s = d.status();
        assert!(s.switch_event() && s.switch_closed());
    }

    #[test]
    fn switch_closing_only_latches_the_event_when_sw_mode_is_1() {
        let mut d = ready();
        sw_user_mode(&mut d);
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(300 * MS);
        let v = d.speed_internal();
        d.set_switch(true);
        assert_eq!(d.speed_internal(), v);
        assert!(d.status().switch_event());
        d.set_switch(false);
        assert!(!d.status().switch_closed());
        assert!(d.status().switch_event(), "latched");
    }

    #[test]
    fn run_in_the_opposite_direction_decelerates_then_reverses() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        settle(&mut d, MS, 10_000);
        let v0 = d.speed_internal();
        cmd(&mut d, Command::Run(Reverse, 40_000));
        assert!(d.is_busy());
        assert_eq!(d.status().direction(), Forward);
        assert_eq!(d.status().motor_status(), MotorStatus::Decelerating);
        d.advance(1_000 * TICK);
        assert_eq!(d.speed_internal(), v0 - 1_000 * 0x08A);
        let peak = d.abs_pos();
        settle(&mut d, MS, 10_000);
        assert_eq!(d.status().direction(), Reverse);
        assert_eq!(d.speed_internal(), v0);
        let p = d.abs_pos();
        assert!(p < peak + 10_000);
        d.advance(100 * MS);
        assert!(d.abs_pos() < p);
    }

    #[test]
    fn go_to_takes_the_shortest_path_across_the_wrap() {
        let mut d = ready();
        cmd(
            &mut d,
            Command::SetParam(Register::AbsPos, wrap_22((1 << 21) - 100)),
        );
        cmd(&mut d, Command::GoTo(-(1 << 21) + 100));
        assert_eq!(d.status().direction(), Forward);
        let mut rng = Rng(7);
        land(&mut d, Forward, wrap_22(-(1 << 21) + 100), &mut rng);
        cmd(&mut d, Command::GoTo((1 << 21) - 100));
        assert_eq!(d.status().direction(), Reverse);
        land(&mut d, Reverse, wrap_22((1 << 21) - 100), &mut rng);
    }

    #[test]
    fn go_to_dir_forces_the_direction() {
        let mut d = ready();
        cmd(&mut d, Command::GoToDir(Reverse, 10)); // 2²² − 10 microsteps the long way
        assert_eq!(d.status().direction(), Reverse);
        let mut rng = Rng(11);
        land(&mut d, Reverse, 10, &mut rng);
    }

    #[test]
    fn go_home_and_go_mark_go_to_zero_and_mark() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::Mark, wrap_22(-3_000)));
        cmd(&mut d, Command::GoMark);
        let mut rng = Rng(3);
        land(&mut d, Reverse, wrap_22(-3_000), &mut rng);
        cmd(&mut d, Command::GoHome);
        land(&mut d, Forward, 0, &mut rng);
    }

    #[test]
    fn go_to_while_running_away_brakes_reverses_and_lands_exactly() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        settle(&mut d, MS, 10_000);
        let p = d.abs_pos();
        cmd(&mut d, Command::GoTo(p - 1_000));
        assert!(!error(&d), "accepted: BUSY was released");
        assert!(d.is_busy());
        let mut max = p;
        while d.is_busy() {
            d.advance(MS);
            max = max.max(d.abs_pos());
        }
        assert!(max > p, "kept going forward while braking");
        assert_eq!(d.abs_pos(), p - 1_000);
        assert_eq!(d.speed_reg(), 0);
    }

    #[test]
    fn go_to_too_close_ahead_while_running_stops_on_the_target() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        settle(&mut d, MS, 10_000);
        let p = d.abs_pos();
        cmd(&mut d, Command::GoTo(p + 10));
        settle(&mut d, MS, 10_000);
        assert_eq!(d.abs_pos(), p + 10);
    }

    #[test]
    fn positioning_arrives_slowly_and_brakes_with_dec() {
        for (min, dec) in [(0u32, 0x08Au64), (0x100, 0x08A), (0, 0xFFE), (0x40, 0x200)] {
            let mut d = ready();
            cmd(&mut d, Command::SetParam(Register::MinSpeed, min));
            cmd(&mut d, Command::SetParam(Register::Dec, dec as u32));
            cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x3FF));
            cmd(&mut d, Command::Move(Forward, 400_000));
            while d.status().motor_status() != MotorStatus::Decelerating {
                d.advance(MS);
            }
            // Tick by tick while braking: speed falls by exactly DEC per tick.
            let mut last = d.speed_internal();
            while d.is_busy() {
                d.advance(TICK);
                let v = d.speed_internal();
                if v > 0 && v > d.floor() {
                    assert_eq!(last - v, dec);
                }
                if v > 0 {
                    last = v;
                }
            }
            assert_eq!(d.abs_pos(), 400_000);
            // Arrival speed: the floor, or a few step/s above it (the
            // braking start is rounded to whole ticks).
            let few_steps_per_s = 20 * 1_099_512; // 20 step/s in 2⁻⁴⁰ step/tick
            assert!(
                last <= d.floor() + few_steps_per_s,
                "min {min:#x} dec {dec:#x}: {last}"
            );
        }
    }

    #[test]
    fn min_speed_is_the_start_speed_and_moves_still_land_exactly() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::MinSpeed, 0x300));
        cmd(&mut d, Command::Move(Forward, 50_000));
        assert_eq!(d.speed_internal(), 0x300 << 16, "starts at MIN_SPEED");
        let mut rng = Rng(5);
        land(&mut d, Forward, 50_000, &mut rng);
    }

    #[test]
    fn lowering_max_speed_while_running_decelerates_to_it() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x80));
        cmd(&mut d, Command::Move(Forward, 1_000_000));
        d.advance(2_000 * MS);
        cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x20));
        assert!(!error(&d), "MAX_SPEED is writable any time");
        assert_eq!(d.status().motor_status(), MotorStatus::Decelerating);
        d.advance(2_000 * MS);
        assert_eq!(d.speed_internal(), 0x20 << 22);
        let mut rng = Rng(9);
        land(&mut d, Forward, 1_000_000, &mut rng);
    }

    #[test]
    fn step_clock_pulses_move_one_microstep_each() {
        let mut d = ready();
        cmd(&mut d, Command::StepClock(Reverse));
        assert!(d.status().step_clock_mode());
        assert!(!d.is_hiz());
        for _ in 0..5 {
            d.step_clock_pulse();
        }
        assert_eq!(d.abs_pos(), -5);
        cmd(&mut d, Command::HardStop);
        assert!(!d.status().step_clock_mode());
        d.step_clock_pulse();
        assert_eq!(d.abs_pos(), -5);
    }

    #[test]
    fn step_clock_while_moving_is_refused() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 1000));
        d.advance(MS);
        cmd(&mut d, Command::StepClock(Forward));
        assert!(error(&d));
        assert!(!d.status().step_clock_mode());
    }

    #[test]
    fn el_pos_follows_the_microsteps() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::StepMode, 2)); // 1/4: 32/128 per microstep
        cmd(&mut d, Command::Move(Forward, 5));
        settle(&mut d, MS, 10_000);
        assert_eq!(d.register(Register::ElPos), 5 * 32);
    }

    // -------------------------------------------------------------- faults

    #[test]
    fn uvlo_fault_stops_motion_and_puts_bridges_in_hiz() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(100 * MS);
        d.inject(Fault::Uvlo);
        assert!(d.is_hiz());
        assert_eq!(d.speed_reg(), 0);
        assert!(get_status(&mut d).uvlo());
        assert!(!get_status(&mut d).uvlo());
    }

    #[test]
    fn overcurrent_with_oc_sd_goes_hiz_and_locks_the_bridges_until_get_status() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(100 * MS);
        d.inject(Fault::Overcurrent);
        assert!(d.is_hiz());
        assert!(d.status().overcurrent());
        cmd(&mut d, Command::Run(Forward, 40_000));
        assert!(error(&d));
        assert!(d.is_hiz());
        assert!(get_status(&mut d).overcurrent());
        cmd(&mut d, Command::Run(Forward, 40_000));
        assert!(!error(&d));
        assert!(!d.is_hiz());
    }

    #[test]
    fn overcurrent_without_oc_sd_only_latches_the_flag() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::Config, 0x2C08));
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(100 * MS);
        d.inject(Fault::Overcurrent);
        assert!(!d.is_hiz());
        assert!(d.speed_reg() > 0);
        assert!(d.status().overcurrent());
    }

    #[test]
    fn thermal_shutdown_puts_bridges_in_hiz_until_the_condition_clears() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(100 * MS);
        d.inject(Fault::ThermalShutdown);
        assert!(d.is_hiz());
        assert_eq!(get_status(&mut d).thermal(), ThermalStatus::BridgeShutdown);
        cmd(&mut d, Command::HardStop);
        assert!(error(&d));
        d.inject(Fault::ThermalNormal);
        assert_eq!(get_status(&mut d).thermal(), ThermalStatus::BridgeShutdown);
        assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Normal);
        cmd(&mut d, Command::HardStop);
        assert!(!d.is_hiz());
    }

    #[test]
    fn stall_latches_stall_a_without_stopping() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(100 * MS);
        d.inject(Fault::Stall);
        let s = d.status();
        assert!(s.stall_a() && !s.stall_b());
        assert!(d.speed_reg() > 0);
    }

    #[test]
    fn power_cycle_restores_reset_registers_and_asserts_uvlo() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::Acc, 0x200));
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(100 * MS);
        d.inject(Fault::PowerCycle);
        assert_eq!(d.register(Register::Acc), 0x08A);
        assert_eq!(d.abs_pos(), 0);
        assert_eq!(d.speed_reg(), 0);
        assert!(d.is_hiz());
        assert!(get_status(&mut d).uvlo());
    }

    #[test]
    fn dead_device_drives_its_stuck_byte_and_ignores_input_until_revived() {
        for stuck in [0xFF, 0x00] {
            let mut d = ready();
            cmd(&mut d, Command::Run(Forward, 40_000));
            d.advance(100 * MS);
            d.inject(Fault::Dead(stuck));
            assert!(d.is_dead());
            assert_eq!(send(&mut d, &[0xD0, 0x00, 0x00]), [stuck; 3]);
            assert_eq!(d.speed_reg(), 0);
            let n = d.received_count();
            cmd(&mut d, Command::Run(Forward, 40_000));
            assert_eq!(d.received_count(), n);
            d.inject(Fault::Revive);
            assert!(!d.is_dead());
            let s = get_status(&mut d);
            assert!(s.hiz() && !s.looks_dead());
        }
    }

    #[test]
    fn a_slower_run_decelerates_with_dec_not_at_once() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x3FF));
        cmd(&mut d, Command::Run(Forward, 60_000));
        d.advance(2000 * MS);
        assert_eq!(d.speed_reg(), 60_000);
        cmd(&mut d, Command::Run(Forward, 20_000));
        d.advance(1000 * TICK);
        // DEC (0x08A) per tick, never a jump to the new speed.
        assert_eq!(d.speed_internal(), (60_000u64 << 12) - 1000 * 0x08A);
        assert!(d.is_busy());
        assert_eq!(d.status().motor_status(), MotorStatus::Decelerating);
    }

    #[test]
    fn a_faster_run_accelerates_with_acc_up_to_max_speed_only() {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::Acc, 0x20));
        cmd(&mut d, Command::Run(Reverse, 0xF_FFFF));
        d.advance(100 * TICK);
        assert_eq!(d.speed_internal(), 100 * 0x20);
        d.advance(10_000 * MS);
        assert_eq!(d.speed_internal(), 0x041 << 22, "clamped to MAX_SPEED");
    }

    #[test]
    fn power_cycle_restores_every_register_including_the_currents() {
        let mut d = ready();
        for (r, v) in [
            (Register::KvalHold, 0x10),
            (Register::KvalRun, 0x80),
            (Register::KvalAcc, 0x80),
            (Register::KvalDec, 0x80),
            (Register::StepMode, 0x04),
            (Register::Config, 0x2C98),
            (Register::OcdTh, 0x1F),
            (Register::MaxSpeed, 0x200),
            (Register::Dec, 0x300),
        ] {
            d.set_register_raw(r, v);
            assert_eq!(d.register(r), v);
        }
        d.inject(Fault::PowerCycle);
        for info in REGISTERS.iter().filter(|i| i.register != Register::Status) {
            assert_eq!(d.register(info.register), info.reset, "{}", info.voltage_mode_name);
        }
    }

    #[test]
    fn move_is_refused_while_a_run_is_still_accelerating() {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 20_000));
        d.advance(MS);
        assert!(d.is_busy());
        let before = d.command_errors();
        cmd(&mut d, Command::Move(Forward, 100));
        cmd(&mut d, Command::GoTo(100));
        assert_eq!(d.command_errors(), before + 2);
    }
}
