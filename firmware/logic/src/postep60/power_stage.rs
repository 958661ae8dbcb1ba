//! The power stage: the electrical facts of the hardware around the chips
//! (drive mode, sense and phase resistance, supply, current limit, CONFIG,
//! the analogue dividers) that turn PoStep60 settings into chip registers.
//! One value, passed in by the firmware (or a test); nothing else hard-codes
//! them. (The MCU's pins are `firmware::pins`; the real-hardware platform is
//! `firmware::platform::stm32f405`.)

use super::analog::AnalogBoard;
use crate::powerstep::fields::{Config, DriveMode, StepSel};
use crate::powerstep::units;

/// Electrical facts of one box's power stage (the same for every axis).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PowerStage {
    /// Voltage mode (KVAL) or current mode (TVAL) drive.
    pub drive: DriveMode,
    /// The chips' STEP_SEL (1/128 in voltage mode, at most 1/16 in current mode).
    pub step: StepSel,
    /// Current-mode sense resistor per bridge, mΩ (TVAL = I · R_sense).
    pub sense_milliohm: u32,
    /// Voltage mode: motor phase resistance (mΩ) and nominal supply (mV):
    /// KVAL = I · R_phase / V_supply.
    pub phase_milliohm: u32,
    pub supply_millivolts: u32,
    /// Largest current a setting may ask for, mA (PoStep60: 6.0 A).
    pub current_limit_ma: u32,
    /// The board routes an external STEP input to the chips' STCK pins
    /// (needed for PoStep60 mode 1). The reference board does not.
    pub step_dir_routed: bool,
    /// CONFIG register for every chip (clock, OC shutdown, PWM…). SW_MODE is
    /// forced to 1: the bridge, not the chip, decides what an end switch does.
    pub chip_config: u16,
    pub analog: AnalogBoard,
    /// HW version reported by 0x0A (major, minor).
    pub hw_version: (u8, u8),
}

impl PowerStage {
    /// The reference board: voltage mode at 1/128, 1 Ω motors on 24 V,
    /// 6.0 A limit, supply divider ÷20, no STEP routing.
    pub const REFERENCE: PowerStage = PowerStage {
        drive: DriveMode::Voltage,
        step: StepSel::OneTwentyEighth,
        sense_milliohm: 100,
        phase_milliohm: 1000,
        supply_millivolts: 24_000,
        current_limit_ma: 6000,
        step_dir_routed: false,
        chip_config: 0x2C88,
        analog: AnalogBoard {
            divider_num: 20,
            divider_den: 1,
            temperature_offset_eighths: 0,
        },
        hw_version: (1, 0),
    };

    /// CONFIG as written to the chips (SW_MODE = 1).
    pub const fn config_register(&self) -> u16 {
        self.chip_config | Config::SW_MODE
    }

    /// The KVAL_x / TVAL_x register value for a phase current in mA.
    pub const fn current_register(&self, ma: u32) -> u32 {
        let ma = if ma > self.current_limit_ma {
            self.current_limit_ma
        } else {
            ma
        };
        match self.drive {
            DriveMode::Current => units::tval_from_milliamps(ma, self.sense_milliohm) as u32,
            DriveMode::Voltage => {
                // V = I·R in mV, as a fraction of the supply.
                let mv = (ma as u64).saturating_mul(self.phase_milliohm as u64) / 1000;
                let mv = if mv > u32::MAX as u64 {
                    u32::MAX
                } else {
                    mv as u32
                };
                units::kval_from_ratio(mv, self.supply_millivolts) as u32
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voltage_mode_kval_is_current_times_resistance_over_supply() {
        // 1 A · 1 Ω = 1 V of 24 V = 4.17 % → KVAL 10.7 → 11
        assert_eq!(PowerStage::REFERENCE.current_register(1000), 11);
        // 6 A → 6 V / 24 V = 25 % → 64
        assert_eq!(PowerStage::REFERENCE.current_register(6000), 64);
        // above the limit: clamped to 6 A
        assert_eq!(PowerStage::REFERENCE.current_register(9000), 64);
    }

    #[test]
    fn current_mode_tval_is_current_times_sense_resistor() {
        let b = PowerStage {
            drive: DriveMode::Current,
            step: StepSel::Sixteenth,
            ..PowerStage::REFERENCE
        };
        // 3.281 A · 100 mΩ = 328.1 mV → TVAL 0x29
        assert_eq!(b.current_register(3281), 0x29);
        // 6 A → 600 mV → 76
        assert_eq!(b.current_register(6000), 76);
    }

    #[test]
    fn sw_mode_is_forced_to_user() {
        assert_eq!(PowerStage::REFERENCE.config_register(), 0x2C98);
    }
}
