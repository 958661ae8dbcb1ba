//! One emulated PoStep60: the behaviour behind the command set of manual §8.3
//! and §9.3, for one axis, whatever bus the command came on.
//!
//! # What it guarantees
//!
//! * **Commands** arrive typed ([`Request`], [`Query`]); transports only
//!   translate bytes. A request that cannot be performed returns a
//!   [`CommandError`] and changes nothing (I2C ignores and counts it, Modbus
//!   answers an exception).
//! * **Mode gating** (manual 8.3.32, 8.3.36): Set position only in position
//!   or BINx mode, Set requested speed / invert only in auto run. Set driver
//!   mode accepts 1, 4, 5, 6 (the product rules (`docs/PRODUCT.md`)); 1 needs a board that routes STEP to
//!   the chips (the reference board does not: [`CommandError::Unsupported`]);
//!   3 (DC) and Set PWM are always unsupported: a powerSTEP01 cannot drive a
//!   DC motor.
//! * **Run/Sleep**: 0xDA runs, 0x0F sleeps (bridges off, motion ignored),
//!   anything else is ignored. The bridge starts every axis running, with the
//!   bridges in HiZ until the first motion.
//! * **Faults** (0x25) are latched from the chip's STATUS: OTS ← thermal
//!   bridge/device shutdown, AOCP and BOCP ← OCD (the chip has one detector
//!   for both bridges), UVLO ← UVLO or a detected chip reset (not ADC UVLO:
//!   an unused ADCIN may read as undervoltage for good), STD ← stall now, STDLAT ←
//!   stall since the last reset. APDF/BPDF never set. Faults 0–5 stop the axis
//!   and refuse motion: 1–5 until Reset faults (0x35); OTS while the chip is
//!   in thermal shutdown — it clears by itself once the chip has cooled (the
//!   manual), Reset faults cannot clear it; STD/STDLAT do not stop anything.
//! * **Currents**: full-scale current while active; the hold current drops to
//!   the idle current 10 s after the last motion (driver status 3); above the
//!   temperature limit run and hold currents drop to the overheat current
//!   (driver status 4) until the temperature is 2 °C below the limit.
//! * **End switch** (when enabled): the switch becoming pressed (closed for
//!   normally open, open for normally closed) stops the axis at once; its
//!   release does not, so a move off the switch completes. A new target in
//!   either direction is accepted after the stop (manual §6 and 7.5.1).
//! * **BINx** (mode 5): a press (falling edge) of BIN1/BIN2 moves by BIN1/BIN2
//!   steps from the current target.
//! * **Auto run** (mode 6): at power-up the axis runs at max speed; Set
//!   requested speed runs at that speed; invert flips the direction; Stop
//!   stops until the next requested speed. A wired run/stop switch has the
//!   last word: while it is off nothing runs (a requested speed or invert
//!   is stored for when it turns on), turning it off soft-stops.

use super::current::Current;
use super::drv8711::{Drv8711Regs, Mapped};
use super::power_stage::PowerStage;
use super::settings::{AxisSettings, DriverMode, TEMPERATURE_LIMIT_MAX};
use crate::motion::axis::logical_to_physical;
use crate::motion::units::full_steps_q16_from_logical;
use crate::motion::{Axis, Limits};
use crate::motion::{HomingError, HomingParams};
use crate::powerstep::commands::Direction;
use crate::powerstep::registers::Register;
use crate::powerstep::status::ThermalStatus;
use crate::powerstep::units;

/// The clock of USB 0x90's StepValue: step frequency = 480 000 Hz / StepValue.
pub const STEP_DIR_CLOCK_HZ: u32 = 480_000;

/// Idle current after this long without motion (manual 7.2).
pub const IDLE_AFTER_MS: u64 = 10_000;
/// Overheat ends this many °C below the limit.
pub const OVERHEAT_HYSTERESIS_C: u16 = 2;

pub use super::command::{
    fault, CommandError, DriverStatus, Effect, Query, Request, Trajectory, Value,
};

/// This firmware's own version (major, minor): the extension space's
/// diagnostics (0x0343) report it.
pub const FW_VERSION: (u8, u8) = (0, 1);
/// The firmware version the PoStep60-facing fields report (I2C/Modbus 0x0A,
/// USB 0x01's bootloader and application versions): 1.9 = 0x0109, the
/// newest PoStep60 firmware the manual (18/5/2021) names — its errata list
/// fixes up to 0x0109 — so the PoStep60 application neither pushes its own
/// firmware at the box (which is not a PoStep60 and could not take it) nor
/// works around bugs the box does not have. The box's own version is
/// [`FW_VERSION`].
pub const POSTEP60_FW_VERSION: (u8, u8) = (1, 9);
/// PoStep60 driver id (0x0A byte 0).
pub const DRIVER_ID: u8 = 0x41;

/// Inputs the bridge measures for every axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Inputs {
    /// BIN1 / BIN2 buttons pressed (buttons to GND).
    pub bin1: bool,
    pub bin2: bool,
    /// The end switch's contact is closed, where it is wired to the I/O
    /// extension (`None`: it is on the chip's SW input).
    pub end_switch: Option<bool>,
    /// The auto-run run/stop switch is on (`None`: there is none, auto run
    /// runs from power-up; a wired switch whose level is not known yet
    /// reads `Some(false)`).
    pub run: Option<bool>,
}

/// One PoStep60.
#[derive(Clone, Debug)]
pub struct Device {
    pub settings: AxisSettings,
    running: bool,
    faults: u8,
    last_motion_ms: u64,
    idle: bool,
    overheated: bool,
    switch_closed: Option<bool>,
    inputs: Inputs,
    loopback: [u8; 4],
    auto_started: bool,
    /// Chip resets seen so far (a new one latches UVLO).
    resets_seen: u32,
    /// Requests refused or ignored since boot (diagnostics).
    pub refused: u32,
    /// Limits clamped to what the chip can follow (diagnostics).
    pub clamps: u32,
    /// Why the last homing start was refused (until the next start).
    homing_refusal: Option<HomingError>,
}

impl Device {
    pub fn new(settings: AxisSettings) -> Device {
        Device {
            settings,
            running: true,
            faults: 0,
            last_motion_ms: 0,
            idle: false,
            overheated: false,
            switch_closed: None,
            inputs: Inputs::default(),
            loopback: [0; 4],
            auto_started: false,
            resets_seen: 0,
            refused: 0,
            clamps: 0,
            homing_refusal: None,
        }
    }

    /// Why the last homing start was refused, if it was.
    pub fn homing_refusal(&self) -> Option<HomingError> {
        self.homing_refusal
    }

    pub fn note_homing_refusal(&mut self, e: HomingError) {
        self.homing_refusal = Some(e);
    }

    /// Clamp the speed/acceleration settings to what the axis's chip can
    /// follow in its step mode (product rules, "Limits" (`docs/PRODUCT.md`)), hand them to the axis,
    /// and count a clamp. The clamped values are what reads return.
    pub fn clamp_limits(&mut self, axis: &mut Axis) {
        let cap = axis.limit_cap();
        let s = &mut self.settings;
        let clamped = [
            (&mut s.max_speed, cap.max_speed),
            (&mut s.acc, cap.acc),
            (&mut s.dec, cap.dec),
        ]
        .into_iter()
        .fold(false, |any, (v, max)| {
            let over = *v > max;
            *v = (*v).min(max);
            any | over
        });
        if clamped {
            self.clamps = self.clamps.saturating_add(1);
        }
        axis.set_limits(self.limits());
    }

    /// The profile limits of the settings.
    pub fn limits(&self) -> Limits {
        Limits {
            max_speed: self.settings.max_speed,
            acc: self.settings.acc,
            dec: self.settings.dec,
        }
    }

    pub fn status(&self) -> DriverStatus {
        if !self.running {
            DriverStatus::Sleep
        } else if self.overheated {
            DriverStatus::Overheated
        } else if self.idle {
            DriverStatus::Idle
        } else {
            DriverStatus::Active
        }
    }

    pub fn faults(&self) -> u8 {
        self.faults
    }

    /// One control tick: faults, idle and overheat currents, end switch,
    /// auto run start. `temperature` in 1/8 °C.
    pub fn tick(&mut self, now_ms: u64, axis: &mut Axis, stage: &PowerStage, temperature: u16) {
        if axis.chip_resets() != self.resets_seen {
            // An undervoltage or reset of the chip: the axis has already
            // stopped and re-configured the chip.
            self.resets_seen = axis.chip_resets();
            self.faults |= fault::UVLO;
        }
        if axis.is_configured() {
            self.latch_faults(axis);
            self.watch_end_switch(axis);
            if !self.auto_started {
                self.auto_started = true;
                let run = self.inputs.run != Some(false);
                if self.settings.mode == DriverMode::AutoRun && self.blocked().is_ok() && run {
                    // Power-up: max speed applies, not the requested speed (7.5.3).
                    self.run_auto(axis, self.settings.max_speed);
                }
            }
        }
        if !axis.is_at_rest() {
            self.last_motion_ms = now_ms;
        }
        self.idle = now_ms.saturating_sub(self.last_motion_ms) >= IDLE_AFTER_MS;
        let celsius = temperature / 8;
        let limit = u16::from(self.settings.temperature_limit);
        if celsius > limit {
            self.overheated = true;
        } else if celsius.saturating_add(OVERHEAT_HYSTERESIS_C) <= limit {
            self.overheated = false;
        }
        self.apply_currents(axis, stage);
    }

    /// New BIN button levels (mode 5: a press moves).
    /// The input levels last handed over.
    pub fn inputs(&self) -> Inputs {
        self.inputs
    }

    pub fn set_inputs(&mut self, inputs: Inputs, axis: &mut Axis) {
        let pressed1 = inputs.bin1 && !self.inputs.bin1;
        let pressed2 = inputs.bin2 && !self.inputs.bin2;
        let run_on = inputs.run == Some(true) && self.inputs.run != Some(true);
        let run_off = inputs.run == Some(false) && self.inputs.run == Some(true);
        self.inputs = inputs;
        if self.settings.mode == DriverMode::AutoRun && self.auto_started {
            // Manual 7.5.3: the run/stop switch turns the motion on and off.
            if run_on && self.blocked().is_ok() {
                self.run_auto(axis, self.settings.requested_speed.max(1));
            } else if run_off {
                axis.soft_stop();
            }
        }
        if self.settings.mode != DriverMode::BinButtons || self.blocked().is_err() {
            return;
        }
        for (pressed, steps) in [
            (pressed1, self.settings.bin1_steps),
            (pressed2, self.settings.bin2_steps),
        ] {
            if pressed {
                let target = axis.required_position().saturating_add(i64::from(steps));
                axis.move_to(target);
            }
        }
    }

    fn latch_faults(&mut self, axis: &mut Axis) {
        let s = axis.status();
        let mut f = 0;
        if matches!(
            s.thermal(),
            ThermalStatus::BridgeShutdown | ThermalStatus::DeviceShutdown
        ) {
            f |= fault::OTS;
        }
        if s.overcurrent() {
            f |= fault::AOCP | fault::BOCP;
        }
        // UVLO_ADC is not a fault here: with ADCIN unused it may read
        // asserted for good (datasheet, the 0xE012 observation).
        if s.uvlo() {
            f |= fault::UVLO;
        }
        let newly = f & !self.faults & fault::STOPPING;
        self.faults |= f;
        // OTS follows the chip: it "will clear once temperature has fallen
        // to safe levels" (manual 8.3.17) and Reset faults cannot clear it.
        // The axis stays stopped until a new motion command.
        if f & fault::OTS == 0 {
            self.faults &= !fault::OTS;
        }
        // STD follows the stall flag; STDLAT keeps it until Reset faults.
        if s.stalled() {
            self.faults |= fault::STD | fault::STDLAT;
        } else {
            self.faults &= !fault::STD;
        }
        if newly != 0 && !axis.is_at_rest() {
            axis.stop_now();
        }
    }

    /// The end switch's level: from the I/O extension where it is wired
    /// there, else the chip's SW input.
    fn end_switch_closed(&self, axis: &Axis) -> bool {
        self.inputs
            .end_switch
            .unwrap_or(axis.status().switch_closed())
    }

    /// Stop when the end switch becomes pressed — closed for a normally
    /// open switch, open for a normally closed one — and only then: a move
    /// off a pressed switch runs to its target (manual §6: "End switch
    /// reacts only on change of end switch state. Position change request
    /// after end switch touched can be set in either direction").
    fn watch_end_switch(&mut self, axis: &mut Axis) {
        let closed = self.end_switch_closed(axis);
        let nc = self.settings.end_switch_nc;
        let pressed_now = self
            .switch_closed
            .is_some_and(|prev| prev != closed && closed != nc);
        self.switch_closed = Some(closed);
        // Homing runs into the switch on purpose.
        if pressed_now && self.settings.end_switch && !axis.is_homing() {
            axis.stop_now();
        }
    }

    /// Start homing with the stored parameters (extension): the end switch
    /// must be enabled, the axis awake, unfaulted and at rest, and the
    /// sequence bounded (a max travel or a timeout). The search and release
    /// speeds are capped at the axis's max speed (the chip's ACC/DEC during
    /// homing are the axis's acceleration and deceleration).
    pub fn start_homing(&mut self, axis: &mut Axis) -> Result<(), HomingError> {
        if !self.settings.end_switch {
            return Err(HomingError::SwitchDisabled);
        }
        if self.blocked().is_err() {
            return Err(HomingError::NotReady);
        }
        let h = self.settings.homing;
        if h.max_travel == 0 && h.timeout_s == 0 {
            return Err(HomingError::Unbounded);
        }
        let cfg = axis.config();
        let vmax = self.settings.max_speed.max(1);
        let full = |v: u32| full_steps_q16_from_logical(v.min(vmax), cfg.logical_shift);
        // ReleaseSW moves at max(MIN_SPEED, 5 full steps/s).
        let release = full(h.release_speed).max(5 << 16);
        let params = HomingParams {
            toward: if h.forward {
                Direction::Forward
            } else {
                Direction::Reverse
            },
            search_speed: units::speed_from_steps_per_s(full(h.search_speed)).max(1),
            release_min_speed: units::min_speed_from_steps_per_s(release),
            release_speed: units::speed_from_steps_per_s(release),
            max_travel: logical_to_physical(i64::from(h.max_travel), cfg.logical_shift, cfg.step)
                .unsigned_abs(),
            timeout_ticks: u64::from(h.timeout_s)
                .saturating_mul(1_000_000)
                .checked_div(u64::from(cfg.tick_us))
                .unwrap_or(0),
            nc: self.settings.end_switch_nc,
        };
        self.homing_refusal = None;
        axis.start_homing(params)
    }

    /// Write a tunable chip register (extension 0x01nn): stored in the
    /// settings and in the axis's chip image (so it survives chip resets).
    pub fn set_tuning(&mut self, reg: Register, value: u16, axis: &mut Axis) -> bool {
        self.settings.tuning.set(reg, value) && axis.set_register(reg, u32::from(value))
    }

    /// Hand every stored tuning value to the axis (at boot).
    pub fn apply_tuning(&self, axis: &mut Axis) {
        for (reg, v) in self.settings.tuning.iter() {
            let _ = axis.set_register(reg, u32::from(v));
        }
    }

    fn apply_currents(&mut self, axis: &mut Axis, stage: &PowerStage) {
        let ma = |c: Current| c.milliamps().unwrap_or(0);
        let (hold, run) = if self.overheated {
            let o = ma(self.settings.overheat);
            (o, o)
        } else if self.idle {
            (ma(self.settings.idle), ma(self.settings.full_scale))
        } else {
            let f = ma(self.settings.full_scale);
            (f, f)
        };
        // The axis keeps them in its chip image: written when they change
        // and again after every chip reset.
        axis.set_currents(stage.current_register(hold), stage.current_register(run));
    }

    fn blocked(&self) -> Result<(), CommandError> {
        if !self.running {
            Err(CommandError::Asleep)
        } else if self.faults & fault::STOPPING != 0 {
            Err(CommandError::Faulted)
        } else {
            Ok(())
        }
    }

    /// Auto run at `speed` — unless a run/stop switch is wired and off: the
    /// switch has the last word (a requested speed or an invert is stored
    /// and applies when the switch turns on).
    fn run_auto(&mut self, axis: &mut Axis, speed: u32) {
        if self.inputs.run == Some(false) {
            return;
        }
        let speed = i32::try_from(speed).unwrap_or(i32::MAX);
        let v = if self.settings.invert {
            speed.saturating_neg()
        } else {
            speed
        };
        axis.run_at(v);
    }

    /// The mode change of 0x05 (and of USB's CONFIG_SET): leaving auto run
    /// soft-stops, entering it runs at the requested speed, entering step
    /// control stands still until 0x90.
    fn set_mode(&mut self, m: DriverMode, axis: &mut Axis) {
        let was = self.settings.mode;
        self.settings.mode = m;
        if was == m {
            return;
        }
        if matches!(was, DriverMode::AutoRun | DriverMode::StepControl) {
            axis.soft_stop();
        }
        if m == DriverMode::AutoRun && self.blocked().is_ok() {
            self.run_auto(axis, self.settings.requested_speed);
        }
    }

    /// The DRV8711 image a PoStep60 would show now (USB 0x81, 0x85).
    pub fn driver_registers(&self) -> Drv8711Regs {
        self.settings.drv.live(&Mapped {
            enable: self.running,
            reverse_step_dir: self.settings.drv.mapped().reverse_step_dir,
            step_mode: Some(self.settings.step_mode),
            full_scale: self.settings.full_scale,
            status: self.faults,
        })
    }

    /// Motion requests would be taken now: awake, no stopping fault
    /// latched.
    pub fn can_move(&self) -> bool {
        self.blocked().is_ok()
    }

    /// Whether the axis runs (not asleep).
    pub fn is_running(&self) -> bool {
        self.running
    }

    fn refuse(&mut self, e: CommandError) -> Result<Effect, CommandError> {
        self.refused = self.refused.saturating_add(1);
        Err(e)
    }

    /// Execute a request. `board` says what the hardware can do.
    pub fn apply(
        &mut self,
        req: Request,
        axis: &mut Axis,
        stage: &PowerStage,
    ) -> Result<Effect, CommandError> {
        let limit = stage.current_limit_ma;
        // While homing, motion requests wait (Stop, soft stop, Set zero
        // and sleep end the homing instead), and so does a step-mode change
        // (it would stop the search and re-express its position).
        let disturbs_homing = req.commands_motion() || matches!(req, Request::SetStepMode(_));
        if disturbs_homing && axis.is_homing() {
            return self.refuse(CommandError::Busy);
        }
        match req {
            Request::Loopback(b) => self.loopback = b,
            Request::RunSleep(code) => return self.run_sleep(code, axis),
            Request::SetAddress { current, new } => {
                return Ok(Effect::SetAddress { current, new });
            }
            Request::SetMode(code) => return self.select_mode(code, false, axis, stage),
            Request::SetModeUsb(code) => return self.select_mode(code, true, axis, stage),
            Request::SetPwm => return self.refuse(CommandError::Unsupported),
            Request::SetFullScaleCurrent(c) => self.settings.full_scale = c.clamped(limit),
            Request::SetIdleCurrent(c) => self.settings.idle = c.clamped(limit),
            Request::SetOverheatCurrent(c) => self.settings.overheat = c.clamped(limit),
            Request::SetStepMode(m) => return self.set_step_mode(m, axis),
            Request::SetTemperatureLimit(t) => {
                self.settings.temperature_limit = t.min(TEMPERATURE_LIMIT_MAX)
            }
            // OTS cannot be cleared while the chip is hot: it is re-latched
            // from STATUS at the next tick if so.
            Request::ResetFaults => self.faults = 0,
            Request::WriteSettings => return Ok(Effect::SaveSettings),
            Request::SetPosition(p) => return self.set_position(p, axis),
            Request::SetMaxSpeed(v) => {
                self.settings.max_speed = v;
                self.clamp_limits(axis);
            }
            Request::SetAcceleration(v) => {
                self.settings.acc = v;
                self.clamp_limits(axis);
            }
            Request::SetDeceleration(v) => {
                self.settings.dec = v;
                self.clamp_limits(axis);
            }
            Request::SetRequestedSpeed(v) => return self.set_requested_speed(v, axis),
            Request::SetInvert(b) => return self.set_invert(b, axis),
            Request::SetZero => axis.set_zero(),
            Request::Stop => axis.stop_now(),
            Request::SoftStop => axis.soft_stop(),
            Request::SystemReset => return Ok(Effect::SystemReset),
            Request::SetDriverRegisters(regs) => {
                return self.set_driver_registers(regs, axis, stage)
            }
            Request::StepDir {
                step_value,
                reverse,
            } => return self.step_dir(step_value, reverse, axis),
            Request::Trajectory(t) => return self.trajectory(t, axis),
            Request::SetName(name) => self.settings.name = name,
        }
        Ok(Effect::None)
    }

    /// 0x03: 0xDA runs (wakes), 0x0F sleeps, anything else is ignored.
    fn run_sleep(&mut self, code: u8, axis: &mut Axis) -> Result<Effect, CommandError> {
        match code {
            0xDA => {
                self.running = true;
                axis.wake();
            }
            0x0F => {
                self.running = false;
                axis.sleep();
            }
            _ => return self.refuse(CommandError::Ignored),
        }
        Ok(Effect::None)
    }

    /// 0x05 (or USB's CONFIG_SET, which also takes 2, step control).
    fn select_mode(
        &mut self,
        code: u8,
        usb: bool,
        axis: &mut Axis,
        stage: &PowerStage,
    ) -> Result<Effect, CommandError> {
        match DriverMode::from_code(code) {
            Some(DriverMode::External) if !stage.step_dir_routed => {
                return self.refuse(CommandError::Unsupported)
            }
            Some(DriverMode::DcMotor) => return self.refuse(CommandError::Unsupported),
            Some(DriverMode::StepControl) if usb => self.set_mode(DriverMode::StepControl, axis),
            Some(
                m @ (DriverMode::External
                | DriverMode::Position
                | DriverMode::BinButtons
                | DriverMode::AutoRun),
            ) => self.set_mode(m, axis),
            _ => return self.refuse(CommandError::Ignored),
        }
        Ok(Effect::None)
    }

    /// 0x33: 0..=8 (others ignored); the limits are clamped again, since the
    /// same numbers mean other speeds in the new unit.
    fn set_step_mode(&mut self, m: u8, axis: &mut Axis) -> Result<Effect, CommandError> {
        if m > 8 {
            return self.refuse(CommandError::Ignored);
        }
        self.settings.step_mode = m;
        axis.set_logical_shift(m);
        self.clamp_limits(axis);
        Ok(Effect::None)
    }

    /// 0x50, in position and BINx modes.
    fn set_position(&mut self, p: i32, axis: &mut Axis) -> Result<Effect, CommandError> {
        if !matches!(
            self.settings.mode,
            DriverMode::Position | DriverMode::BinButtons
        ) {
            return self.refuse(CommandError::WrongMode);
        }
        if let Err(e) = self.blocked() {
            return self.refuse(e);
        }
        axis.move_to(i64::from(p));
        Ok(Effect::None)
    }

    /// 0x54, in auto run.
    fn set_requested_speed(&mut self, v: u32, axis: &mut Axis) -> Result<Effect, CommandError> {
        if self.settings.mode != DriverMode::AutoRun {
            return self.refuse(CommandError::WrongMode);
        }
        if let Err(e) = self.blocked() {
            return self.refuse(e);
        }
        self.settings.requested_speed = v;
        self.run_auto(axis, v);
        Ok(Effect::None)
    }

    /// 0x55, in auto run: a running axis turns round.
    fn set_invert(&mut self, b: u8, axis: &mut Axis) -> Result<Effect, CommandError> {
        if self.settings.mode != DriverMode::AutoRun {
            return self.refuse(CommandError::WrongMode);
        }
        self.settings.invert = b & 1 != 0;
        if self.blocked().is_ok() && !axis.profile().is_settled() {
            self.run_auto(axis, self.settings.requested_speed);
        }
        Ok(Effect::None)
    }

    /// USB 0x90 in step control: 480 000 Hz / StepValue (manual 10.2.11; 0
    /// stops), the direction inverted again by CTRL.RDIR.
    fn step_dir(
        &mut self,
        step_value: u32,
        reverse: bool,
        axis: &mut Axis,
    ) -> Result<Effect, CommandError> {
        if self.settings.mode != DriverMode::StepControl {
            return self.refuse(CommandError::WrongMode);
        }
        if let Err(e) = self.blocked() {
            return self.refuse(e);
        }
        let reverse = reverse != self.settings.drv.mapped().reverse_step_dir;
        match STEP_DIR_CLOCK_HZ.checked_div(step_value) {
            None => axis.soft_stop(),
            Some(f) => {
                let v = i32::try_from(f).unwrap_or(i32::MAX);
                axis.run_at(if reverse { v.saturating_neg() } else { v });
            }
        }
        Ok(Effect::None)
    }

    /// USB 0x80's register image: the mapped fields take effect (step mode,
    /// full-scale current, run/sleep, faults cleared by writing STATUS 0);
    /// the rest is stored.
    fn set_driver_registers(
        &mut self,
        regs: Drv8711Regs,
        axis: &mut Axis,
        stage: &PowerStage,
    ) -> Result<Effect, CommandError> {
        let m = regs.mapped();
        self.settings.drv = regs.stored();
        self.settings.full_scale = m.full_scale.clamped(stage.current_limit_ma);
        if let Some(mode) = m.step_mode {
            self.settings.step_mode = mode;
            axis.set_logical_shift(mode);
            self.clamp_limits(axis);
        }
        // DRV8711: a latched STATUS bit is cleared by writing 0 to it.
        self.faults &= m.status | !fault::STOPPING_AND_STALL_LATCH;
        if m.enable && !self.running {
            self.running = true;
            axis.wake();
        } else if !m.enable && self.running {
            self.running = false;
            axis.sleep();
        }
        Ok(Effect::None)
    }

    /// USB 0xB1: the profile selector picks the mode; limits, end switch,
    /// invert, BINx steps and requested speed are stored; then the mode's
    /// motion starts: trajectory moves to the final position, auto run runs
    /// at the requested speed, BINx waits for a button.
    fn trajectory(&mut self, t: Trajectory, axis: &mut Axis) -> Result<Effect, CommandError> {
        let mode = match t.profile {
            0 => DriverMode::Position,
            1 => DriverMode::BinButtons,
            2 => DriverMode::AutoRun,
            _ => return self.refuse(CommandError::Ignored),
        };
        let s = &mut self.settings;
        s.max_speed = t.max_speed;
        s.acc = t.acc;
        s.dec = t.dec;
        s.end_switch = t.end_switch;
        s.end_switch_nc = t.end_switch_nc;
        s.invert = t.invert;
        s.bin1_steps = t.bin1_steps;
        s.bin2_steps = t.bin2_steps;
        s.requested_speed = t.requested_speed;
        self.clamp_limits(axis);
        let was = self.settings.mode;
        self.set_mode(mode, axis);
        if let Err(e) = self.blocked() {
            return self.refuse(e);
        }
        match mode {
            DriverMode::Position => axis.move_to(i64::from(t.final_position)),
            DriverMode::AutoRun if was == DriverMode::AutoRun => {
                self.run_auto(axis, self.settings.requested_speed)
            }
            _ => {}
        }
        Ok(Effect::None)
    }

    /// Answer a query. `supply` and `temperature` are the bridge's
    /// measurements in PoStep60 units.
    pub fn query(
        &self,
        q: Query,
        axis: &Axis,
        stage: &PowerStage,
        supply: u16,
        temperature: u16,
    ) -> Value {
        let s = &self.settings;
        let sat16 = |v: u32| Value::U16(u16::try_from(v).unwrap_or(u16::MAX));
        match q {
            Query::Loopback => {
                let [a, b, c, d] = self.loopback;
                Value::Bytes([a, b, c, d, 0], 4)
            }
            Query::HwFwInfo => Value::Bytes(
                [
                    DRIVER_ID,
                    stage.hw_version.0,
                    stage.hw_version.1,
                    POSTEP60_FW_VERSION.0,
                    POSTEP60_FW_VERSION.1,
                ],
                5,
            ),
            Query::Voltage => Value::U16(supply),
            Query::Temperature => Value::U16(temperature),
            Query::Pins => {
                // bit 0 bootloader override (always high), 1 enable (run),
                // 4/5 BIN1/BIN2 level (buttons pull low), 6 end switch level
                // (the chip's SW input: closed = low).
                let mut p = 0x01;
                if self.running {
                    p |= 0x02;
                }
                if !self.inputs.bin1 {
                    p |= 0x10;
                }
                if !self.inputs.bin2 {
                    p |= 0x20;
                }
                if !self.end_switch_closed(axis) {
                    p |= 0x40;
                }
                Value::U8(p)
            }
            Query::DriverStatus => Value::U8(self.status() as u8),
            Query::DriverMode => Value::U8(s.mode.code()),
            Query::FullScaleCurrent => Value::Current(s.full_scale),
            Query::IdleCurrent => Value::Current(s.idle),
            Query::OverheatCurrent => Value::Current(s.overheat),
            Query::StepMode => Value::U8(s.step_mode),
            Query::TemperatureLimit => Value::U8(s.temperature_limit),
            Query::Faults => Value::U8(self.faults),
            Query::Position => Value::I32(
                axis.actual_position()
                    .clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32,
            ),
            Query::MaxSpeed => sat16(s.max_speed),
            Query::Acceleration => sat16(s.acc),
            Query::Deceleration => sat16(s.dec),
            // Manual: BYTE1·256 + BYTE0, a magnitude: every speed up to
            // 65 535 steps/s reads as it is (the sign is in the extensions).
            Query::CurrentSpeed => Value::U16(
                u16::try_from(axis.profile().velocity().unsigned_abs()).unwrap_or(u16::MAX),
            ),
            Query::RequestedSpeed => sat16(s.requested_speed),
            Query::Invert => Value::U8(u8::from(s.invert)),
        }
    }
}
