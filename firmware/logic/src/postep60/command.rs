//! The PoStep60 command set as types: the requests that change an axis
//! ([`Request`]), the queries that read one ([`Query`] → [`Value`]), why a
//! request is refused ([`CommandError`]) and what the bridge must do after
//! one ([`Effect`]). The transports decode bytes into these; [`super::device`]
//! performs them.

use super::current::Current;
use super::drv8711::Drv8711Regs;
use super::settings::NAME_LEN;

/// Fault bits of 0x25 (manual 8.3.17).
pub mod fault {
    pub const OTS: u8 = 1 << 0;
    pub const AOCP: u8 = 1 << 1;
    pub const BOCP: u8 = 1 << 2;
    pub const APDF: u8 = 1 << 3;
    pub const BPDF: u8 = 1 << 4;
    pub const UVLO: u8 = 1 << 5;
    pub const STD: u8 = 1 << 6;
    pub const STDLAT: u8 = 1 << 7;
    /// Faults that stop the axis until reset.
    pub const STOPPING: u8 = OTS | AOCP | BOCP | APDF | BPDF | UVLO;
    /// The latched bits a DRV8711 STATUS write of 0 clears.
    pub const STOPPING_AND_STALL_LATCH: u8 = STOPPING | STDLAT;
}

/// Driver status (manual 8.3.10).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DriverStatus {
    Sleep = 1,
    Active = 2,
    Idle = 3,
    Overheated = 4,
}

/// A PoStep60 command that changes something.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Request {
    /// 0x01 (I2C): remember 4 bytes for the next read.
    Loopback([u8; 4]),
    /// 0x03: 0xDA run, 0x0F sleep.
    RunSleep(u8),
    /// 0x04: `current` must be the address this axis answers now.
    SetAddress {
        current: u8,
        new: u8,
    },
    /// 0x05.
    SetMode(u8),
    /// 0x06 (DC motor PWM).
    SetPwm,
    SetFullScaleCurrent(Current),
    SetIdleCurrent(Current),
    SetOverheatCurrent(Current),
    /// 0x33: 0..=8, others ignored.
    SetStepMode(u8),
    /// 0x34: °C.
    SetTemperatureLimit(u8),
    ResetFaults,
    /// 0x3F.
    WriteSettings,
    /// 0x50.
    SetPosition(i32),
    /// 0x51–0x53 (16 bits on I2C and Modbus, 32 on USB): logical steps/s,
    /// steps/s²; clamped to what the chip can follow.
    SetMaxSpeed(u32),
    SetAcceleration(u32),
    SetDeceleration(u32),
    /// 0x54 (USB: 0xB1 bytes 48..51).
    SetRequestedSpeed(u32),
    /// 0x55: bit 0.
    SetInvert(u8),
    /// 0x5E.
    SetZero,
    /// 0x5F: immediate stop, no ramp.
    Stop,
    /// 0x60.
    SystemReset,
    /// Extension: decelerate to a stop with the deceleration ramp.
    SoftStop,
    /// USB 0x80 byte 37 (CONFIG_SET): any mode 1..=6; 2 (step control) is
    /// accepted here, 3 (DC) is not.
    SetModeUsb(u8),
    /// USB 0x80 bytes 20..35: the DRV8711 register image.
    SetDriverRegisters(Drv8711Regs),
    /// USB 0x90 in mode 2: run at 480 000 / `step_value` steps/s (0 stops)
    /// in the direction `reverse` gives (inverted again by CTRL.RDIR).
    StepDir {
        step_value: u32,
        reverse: bool,
    },
    /// USB 0xB1: the trajectory profile, all at once.
    Trajectory(Trajectory),
    /// USB 0xC0: the custom name.
    SetName([u8; NAME_LEN]),
}

impl Request {
    /// The request starts or changes motion: a target, a speed, a
    /// direction, or a mode or trajectory that runs. The one list of them:
    /// refused while homing (with a step-mode change), and the bus it came
    /// on becomes the one the communication watchdog watches for the axis.
    pub const fn commands_motion(&self) -> bool {
        matches!(
            self,
            Request::SetPosition(_)
                | Request::SetRequestedSpeed(_)
                | Request::SetInvert(_)
                | Request::StepDir { .. }
                | Request::Trajectory(_)
                | Request::SetMode(_)
                | Request::SetModeUsb(_)
        )
    }

    /// Refused for a member of a coordinated move under way: what would
    /// move it on its own, or change its unit, position or limits (USB
    /// 0x80's DRV8711 image carries the step mode: refused whole). A Stop,
    /// a soft stop and sleep are taken: they stop the group.
    pub const fn leaves_a_group(&self) -> bool {
        self.commands_motion()
            || matches!(
                self,
                Request::SetStepMode(_)
                    | Request::SetDriverRegisters(_)
                    | Request::SetZero
                    | Request::SetMaxSpeed(_)
                    | Request::SetAcceleration(_)
                    | Request::SetDeceleration(_)
            )
    }
}

/// USB 0xB1 Write trajectory data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Trajectory {
    /// Byte 2: 0 trajectory (mode 4), 1 BINx (mode 5), 2 auto run (mode 6).
    pub profile: u8,
    pub final_position: i32,
    pub max_speed: u32,
    pub acc: u32,
    pub dec: u32,
    pub end_switch: bool,
    pub end_switch_nc: bool,
    pub invert: bool,
    pub bin1_steps: i32,
    pub bin2_steps: i32,
    pub requested_speed: u32,
}

/// A PoStep60 read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Query {
    Loopback,
    HwFwInfo,
    Voltage,
    Temperature,
    Pins,
    DriverStatus,
    DriverMode,
    FullScaleCurrent,
    IdleCurrent,
    OverheatCurrent,
    StepMode,
    TemperatureLimit,
    Faults,
    Position,
    MaxSpeed,
    Acceleration,
    Deceleration,
    CurrentSpeed,
    RequestedSpeed,
    Invert,
}

/// The value of a query; transports choose the byte order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Value {
    U8(u8),
    U16(u16),
    I32(i32),
    Current(Current),
    /// Fixed byte sequences (HW/FW info, loopback).
    Bytes([u8; 5], u8),
}

/// Why a request was not performed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommandError {
    /// Not in this driver mode (manual's gating).
    WrongMode,
    /// The axis is asleep (0x03 0x0F).
    Asleep,
    /// A fault that stops the axis is latched (reset faults first).
    Faulted,
    /// A value the manual says is ignored.
    Ignored,
    /// The bridge cannot do this (DC motor, STEP not routed on this board).
    Unsupported,
    /// Address change: BYTE0 is not this axis's address, or the new one is invalid.
    BadAddress,
    /// The bridge is writing settings to flash (programming stalls the
    /// CPU): try again when the write is over; or homing runs.
    Busy,
    /// The bridge runs in its boot mode (after USB 0x02): no motion, no
    /// settings changes until the application is restarted.
    BootMode,
    /// The axis is a member of a coordinated move under way (extension
    /// 0x08nn): it takes stops, not motion of its own, until the move is
    /// over.
    Grouped,
}

impl CommandError {
    /// The reason's number on every bus that reports one (USB `InDATA[14]`,
    /// diagnostics 0x0349).
    pub const fn code(self) -> u8 {
        match self {
            CommandError::WrongMode => 1,
            CommandError::Asleep => 2,
            CommandError::Faulted => 3,
            CommandError::Ignored => 4,
            CommandError::Unsupported => 5,
            CommandError::BadAddress => 6,
            CommandError::Busy => 7,
            CommandError::BootMode => 8,
            // (9 to 13 are the USB outcomes of the transport's own refusals.)
            CommandError::Grouped => 14,
        }
    }
}

/// What the bridge must do after a request succeeded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Effect {
    None,
    /// Store every axis's settings (deferred until all axes are at rest).
    SaveSettings,
    /// Restart the bridge after the reply.
    SystemReset,
    /// The address base changes (handled by the bridge).
    SetAddress {
        current: u8,
        new: u8,
    },
}
