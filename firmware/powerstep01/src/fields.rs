//! Typed views of the packed configuration registers: STEP_MODE (0x16),
//! ALARM_EN (0x17) and CONFIG (0x1A), the datasheet.

/// STEP_SEL: microsteps per full step = 2^STEP_SEL.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StepSel {
    Full = 0,
    Half = 1,
    Quarter = 2,
    Eighth = 3,
    Sixteenth = 4,
    ThirtySecond = 5,
    SixtyFourth = 6,
    OneTwentyEighth = 7,
}

impl StepSel {
    pub const fn from_bits(b: u8) -> StepSel {
        match b & 7 {
            0 => StepSel::Full,
            1 => StepSel::Half,
            2 => StepSel::Quarter,
            3 => StepSel::Eighth,
            4 => StepSel::Sixteenth,
            5 => StepSel::ThirtySecond,
            6 => StepSel::SixtyFourth,
            _ => StepSel::OneTwentyEighth,
        }
    }
    /// log2 of microsteps per full step.
    pub const fn shift(self) -> u32 {
        self as u32
    }
    pub const fn microsteps(self) -> u32 {
        1 << self.shift()
    }
    /// Finest step the given drive mode supports (current mode stops at 1/16).
    pub const fn finest(mode: DriveMode) -> StepSel {
        match mode {
            DriveMode::Voltage => StepSel::OneTwentyEighth,
            DriveMode::Current => StepSel::Sixteenth,
        }
    }
}

/// STEP_MODE.CM_VM.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DriveMode {
    Voltage,
    Current,
}

/// STEP_MODE register value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepMode {
    pub step: StepSel,
    pub mode: DriveMode,
    /// SYNC_SEL (bits 6:4), used only when `sync_enable`.
    pub sync_sel: u8,
    /// SYNC_EN: BUSY/SYNC pin outputs the sync clock instead of BUSY.
    pub sync_enable: bool,
}

impl StepMode {
    pub const fn from_reg(v: u8) -> StepMode {
        StepMode {
            step: StepSel::from_bits(v),
            mode: if v & 0x08 != 0 {
                DriveMode::Current
            } else {
                DriveMode::Voltage
            },
            sync_sel: (v >> 4) & 7,
            sync_enable: v & 0x80 != 0,
        }
    }
    pub const fn to_reg(self) -> u8 {
        (self.step as u8)
            | match self.mode {
                DriveMode::Voltage => 0,
                DriveMode::Current => 0x08,
            }
            | ((self.sync_sel & 7) << 4)
            | if self.sync_enable { 0x80 } else { 0 }
    }
    /// A current-mode STEP_SEL finer than 1/16 is not usable.
    pub const fn is_valid(self) -> bool {
        (self.step as u8) <= (StepSel::finest(self.mode) as u8)
    }
}

/// ALARM_EN bits: a set bit lets the event pull FLAG low.
pub mod alarm {
    pub const OVERCURRENT: u8 = 1 << 0;
    pub const THERMAL_SHUTDOWN: u8 = 1 << 1;
    pub const THERMAL_WARNING: u8 = 1 << 2;
    pub const UVLO: u8 = 1 << 3;
    pub const ADC_UVLO: u8 = 1 << 4;
    pub const STALL: u8 = 1 << 5;
    pub const SWITCH_ON: u8 = 1 << 6;
    pub const COMMAND_ERROR: u8 = 1 << 7;
    pub const ALL: u8 = 0xFF;
}

/// CONFIG register (fields common to both drive modes, plus the raw PWM bits).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// Bits 3:0: EXT_CLK + OSC_SEL (0x8 = internal 16 MHz, 2 MHz on OSCOUT).
    pub clock: u8,
    /// SW_MODE: false = a SW falling edge hard-stops the motor; true = event only.
    pub sw_user: bool,
    /// Bit 5: EN_VSCOMP (voltage mode) / EN_TQREG (current mode).
    pub adc_compensation: bool,
    /// OC_SD: bridges shut down on overcurrent.
    pub oc_shutdown: bool,
    /// UVLOVAL: high thresholds.
    pub uvlo_high: bool,
    /// VCCVAL: 15 V VCC regulator.
    pub vcc_15v: bool,
    /// Bits 15:10 as they are (F_PWM_INT/F_PWM_DEC, or TSW/PRED_EN in current mode).
    pub pwm_bits: u8,
}

impl Config {
    pub const SW_MODE: u16 = 1 << 4;

    pub const fn from_reg(v: u16) -> Config {
        Config {
            clock: (v & 0xF) as u8,
            sw_user: v & (1 << 4) != 0,
            adc_compensation: v & (1 << 5) != 0,
            oc_shutdown: v & (1 << 7) != 0,
            uvlo_high: v & (1 << 8) != 0,
            vcc_15v: v & (1 << 9) != 0,
            pwm_bits: (v >> 10) as u8 & 0x3F,
        }
    }
    pub const fn to_reg(self) -> u16 {
        (self.clock as u16 & 0xF)
            | if self.sw_user { 1 << 4 } else { 0 }
            | if self.adc_compensation { 1 << 5 } else { 0 }
            | if self.oc_shutdown { 1 << 7 } else { 0 }
            | if self.uvlo_high { 1 << 8 } else { 0 }
            | if self.vcc_15v { 1 << 9 } else { 0 }
            | ((self.pwm_bits as u16 & 0x3F) << 10)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_mode_reset_value_0x07_is_1_128_voltage_mode_busy_output() {
        let m = StepMode::from_reg(0x07);
        assert_eq!(m.step, StepSel::OneTwentyEighth);
        assert_eq!(m.mode, DriveMode::Voltage);
        assert!(!m.sync_enable);
        assert_eq!(m.to_reg(), 0x07);
        assert!(m.is_valid());
    }

    #[test]
    fn step_mode_current_mode_stops_at_1_16() {
        let m = StepMode::from_reg(0x0C);
        assert_eq!(m.mode, DriveMode::Current);
        assert_eq!(m.step, StepSel::Sixteenth);
        assert!(m.is_valid());
        assert!(!StepMode::from_reg(0x0D).is_valid());
    }

    #[test]
    fn step_mode_round_trips_every_byte() {
        for v in 0u8..=0xFF {
            assert_eq!(StepMode::from_reg(v).to_reg(), v);
        }
    }

    #[test]
    fn step_sel_microsteps_are_powers_of_two() {
        assert_eq!(StepSel::Full.microsteps(), 1);
        assert_eq!(StepSel::Sixteenth.microsteps(), 16);
        assert_eq!(StepSel::OneTwentyEighth.microsteps(), 128);
    }

    #[test]
    fn config_expected_reset_0x2c88_decodes() {
        let c = Config::from_reg(0x2C88);
        assert_eq!(c.clock, 0x8);
        assert!(!c.sw_user);
        assert!(c.oc_shutdown);
        assert!(!c.vcc_15v);
        assert_eq!(c.pwm_bits, 0x0B); // F_PWM_DEC = 3, F_PWM_INT = 1
        assert_eq!(c.to_reg(), 0x2C88);
    }

    #[test]
    fn config_round_trips_all_defined_bits() {
        for v in [0u16, 0x2C88, 0x2E88, 0xFFBF, 0x0010] {
            assert_eq!(Config::from_reg(v).to_reg(), v & !(1 << 6));
        }
    }

    #[test]
    fn alarm_bits_match_facts_table() {
        assert_eq!(alarm::OVERCURRENT, 0x01);
        assert_eq!(alarm::THERMAL_SHUTDOWN, 0x02);
        assert_eq!(alarm::THERMAL_WARNING, 0x04);
        assert_eq!(alarm::UVLO, 0x08);
        assert_eq!(alarm::ADC_UVLO, 0x10);
        assert_eq!(alarm::STALL, 0x20);
        assert_eq!(alarm::SWITCH_ON, 0x40);
        assert_eq!(alarm::COMMAND_ERROR, 0x80);
    }
}
