//! The STATUS register (0x1B), the datasheet.
//!
//! [`Status`] wraps the raw 16 bits and answers questions with the polarity
//! already handled: `busy()` is true while a command executes although the
//! BUSY bit is active-low; `uvlo()`, `ocd()`, `stall_*()` likewise. The two
//! stall bits are disputed between sources (datasheet), so the bridge
//! only relies on [`Status::stalled`] (either bit).

/// Bit masks of STATUS, raw (no polarity applied).
pub mod bits {
    pub const HIZ: u16 = 1 << 0;
    /// Active low: 0 = a command is executing.
    pub const BUSY: u16 = 1 << 1;
    /// 1 = switch closed (SW input low).
    pub const SW_F: u16 = 1 << 2;
    /// Latched switch turn-on event.
    pub const SW_EVN: u16 = 1 << 3;
    /// 1 = forward.
    pub const DIR: u16 = 1 << 4;
    pub const MOT_STATUS: u16 = 0b11 << 5;
    /// Latched, active high.
    pub const CMD_ERROR: u16 = 1 << 7;
    pub const STCK_MOD: u16 = 1 << 8;
    /// Active low, latched: undervoltage or reset/power-up.
    pub const UVLO: u16 = 1 << 9;
    /// Active low, latched: ADCIN undervoltage.
    pub const UVLO_ADC: u16 = 1 << 10;
    pub const TH_STATUS: u16 = 0b11 << 11;
    /// Active low, latched.
    pub const OCD: u16 = 1 << 13;
    /// Active low, latched (ST driver's naming; see the datasheet).
    pub const STALL_A: u16 = 1 << 14;
    /// Active low, latched.
    pub const STALL_B: u16 = 1 << 15;
    /// Bits that read 1 when nothing is wrong (the active-low flags).
    pub const ACTIVE_LOW: u16 = BUSY | UVLO | UVLO_ADC | OCD | STALL_A | STALL_B;
}

/// MOT_STATUS (bits 6:5).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MotorStatus {
    Stopped = 0,
    Accelerating = 1,
    Decelerating = 2,
    ConstantSpeed = 3,
}

/// TH_STATUS (bits 12:11).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ThermalStatus {
    Normal = 0,
    Warning = 1,
    BridgeShutdown = 2,
    DeviceShutdown = 3,
}

impl ThermalStatus {
    pub const fn from_bits(b: u16) -> ThermalStatus {
        match b & 3 {
            0 => ThermalStatus::Normal,
            1 => ThermalStatus::Warning,
            2 => ThermalStatus::BridgeShutdown,
            _ => ThermalStatus::DeviceShutdown,
        }
    }
}

impl MotorStatus {
    pub const fn from_bits(b: u16) -> MotorStatus {
        match b & 3 {
            0 => MotorStatus::Stopped,
            1 => MotorStatus::Accelerating,
            2 => MotorStatus::Decelerating,
            _ => MotorStatus::ConstantSpeed,
        }
    }
}

/// A STATUS value as read from the chip.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status(pub u16);

impl Status {
    /// Status of an idle, healthy device with bridges enabled: all active-low
    /// flags inactive, BUSY released, motor stopped.
    pub const IDLE: Status = Status(bits::ACTIVE_LOW);

    pub const fn from_bytes(msb: u8, lsb: u8) -> Status {
        Status(u16::from_be_bytes([msb, lsb]))
    }
    pub const fn raw(self) -> u16 {
        self.0
    }
    const fn set(self, m: u16) -> bool {
        self.0 & m != 0
    }

    /// Bridges in high impedance.
    pub const fn hiz(self) -> bool {
        self.set(bits::HIZ)
    }
    /// A command is executing (BUSY pin low).
    pub const fn busy(self) -> bool {
        !self.set(bits::BUSY)
    }
    /// The SW input is closed (low).
    pub const fn switch_closed(self) -> bool {
        self.set(bits::SW_F)
    }
    /// A switch turn-on event was latched.
    pub const fn switch_event(self) -> bool {
        self.set(bits::SW_EVN)
    }
    pub const fn direction(self) -> super::commands::Direction {
        super::commands::Direction::from_bit((self.0 >> 4) as u8)
    }
    pub const fn motor_status(self) -> MotorStatus {
        MotorStatus::from_bits(self.0 >> 5)
    }
    /// Last command was unknown or not performable (latched).
    pub const fn command_error(self) -> bool {
        self.set(bits::CMD_ERROR)
    }
    pub const fn step_clock_mode(self) -> bool {
        self.set(bits::STCK_MOD)
    }
    /// Undervoltage lockout or a reset happened (latched, active low on the wire).
    pub const fn uvlo(self) -> bool {
        !self.set(bits::UVLO)
    }
    pub const fn uvlo_adc(self) -> bool {
        !self.set(bits::UVLO_ADC)
    }
    pub const fn thermal(self) -> ThermalStatus {
        ThermalStatus::from_bits(self.0 >> 11)
    }
    /// Overcurrent detected (latched).
    pub const fn overcurrent(self) -> bool {
        !self.set(bits::OCD)
    }
    pub const fn stall_a(self) -> bool {
        !self.set(bits::STALL_A)
    }
    pub const fn stall_b(self) -> bool {
        !self.set(bits::STALL_B)
    }
    /// Stall on either bridge (which bit is which is disputed).
    pub const fn stalled(self) -> bool {
        self.stall_a() || self.stall_b()
    }
    /// Any condition that stops the axis: overcurrent, thermal shutdown, UVLO.
    pub const fn fault(self) -> bool {
        self.overcurrent()
            || self.uvlo()
            || matches!(
                self.thermal(),
                ThermalStatus::BridgeShutdown | ThermalStatus::DeviceShutdown
            )
    }
    /// What a dead or absent device reads as: all ones or all zeros.
    pub const fn looks_dead(self) -> bool {
        self.0 == 0xFFFF || self.0 == 0x0000
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::commands::Direction;

    #[test]
    fn forum_value_after_soft_stop_decodes_as_idle_forward_with_uvlo_latched() {
        // the datasheet: 0xE012 read after SoftStop.
        let s = Status(0xE012);
        assert!(!s.hiz());
        assert!(!s.busy());
        assert!(!s.switch_closed());
        assert_eq!(s.direction(), Direction::Forward);
        assert_eq!(s.motor_status(), MotorStatus::Stopped);
        assert!(!s.command_error());
        assert!(s.uvlo());
        assert!(s.uvlo_adc());
        assert!(!s.overcurrent());
        assert!(!s.stalled());
        assert_eq!(s.thermal(), ThermalStatus::Normal);
    }

    #[test]
    fn forum_value_after_reset_outside_hiz_has_command_error() {
        assert!(Status(0xE092).command_error());
    }

    #[test]
    fn active_low_bits_read_inactive_when_set() {
        let s = Status::IDLE;
        assert!(!s.busy() && !s.uvlo() && !s.uvlo_adc() && !s.overcurrent() && !s.stalled());
        assert!(!s.fault());
    }

    #[test]
    fn each_active_low_flag_asserts_when_its_bit_clears() {
        assert!(Status(bits::ACTIVE_LOW & !bits::BUSY).busy());
        assert!(Status(bits::ACTIVE_LOW & !bits::UVLO).uvlo());
        assert!(Status(bits::ACTIVE_LOW & !bits::UVLO_ADC).uvlo_adc());
        assert!(Status(bits::ACTIVE_LOW & !bits::OCD).overcurrent());
        assert!(Status(bits::ACTIVE_LOW & !bits::STALL_A).stall_a());
        assert!(Status(bits::ACTIVE_LOW & !bits::STALL_B).stall_b());
        assert!(Status(bits::ACTIVE_LOW & !bits::STALL_B).stalled());
    }

    #[test]
    fn motor_and_thermal_fields_decode() {
        assert_eq!(Status(3 << 5).motor_status(), MotorStatus::ConstantSpeed);
        assert_eq!(Status(1 << 5).motor_status(), MotorStatus::Accelerating);
        assert_eq!(Status(2 << 5).motor_status(), MotorStatus::Decelerating);
        assert_eq!(Status(1 << 11).thermal(), ThermalStatus::Warning);
        assert_eq!(Status(3 << 11).thermal(), ThermalStatus::DeviceShutdown);
        assert!(Status(bits::ACTIVE_LOW | (2 << 11)).fault());
    }

    #[test]
    fn bytes_are_msb_first() {
        assert_eq!(Status::from_bytes(0xE0, 0x12), Status(0xE012));
    }

    #[test]
    fn dead_device_patterns_are_recognised() {
        assert!(Status(0xFFFF).looks_dead());
        assert!(Status(0x0000).looks_dead());
        assert!(!Status(0xE012).looks_dead());
    }
}
