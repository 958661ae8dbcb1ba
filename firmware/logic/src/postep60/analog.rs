//! Supply voltage and temperature: raw ADC counts → PoStep60 wire units.
//!
//! The firmware samples three ADC1 channels (the motor supply through the
//! board's divider, the STM32 internal temperature sensor, VREFINT) and
//! hands the raw 12-bit counts over; all arithmetic is here. VDDA is derived
//! from VREFINT (1.21 V typical), so the result does not depend on the
//! 3.3 V rail's tolerance. The temperature uses the STM32F405 datasheet's
//! typical sensor line (V25 = 0.76 V, 2.5 mV/°C); it reads the MCU die, which
//! sits next to the powerSTEP01s on the board — a board sensor can replace it
//! through [`AnalogBoard::temperature_offset_eighths`].

// ADC conversions: 12-bit samples and board constants widened to u64/i64.
#![allow(clippy::arithmetic_side_effects)]

/// One set of raw ADC samples (12-bit counts).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AnalogSample {
    /// Motor supply through the board divider.
    pub supply: u16,
    /// STM32 internal temperature sensor (ADC1_IN16).
    pub temperature: u16,
    /// Internal reference VREFINT (ADC1_IN17).
    pub vrefint: u16,
}

impl AnalogSample {
    /// What the reference power stage reads at a 24 V supply and a 25 °C
    /// die with VDDA = 3.2988 V: 24 V / 20 = 1.2 V at the pin = 1490 counts;
    /// 0.76 V = 943 counts; VREFINT 1.21 V = 1502 counts. The simulations'
    /// and the QEMU image's stand-in for the ADC.
    pub const NOMINAL_24V_25C: AnalogSample = AnalogSample {
        supply: 1490,
        temperature: 943,
        vrefint: 1502,
    };
}

/// Analogue part of the board description.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AnalogBoard {
    /// Supply divider: V_supply = V_pin · num / den.
    pub divider_num: u32,
    pub divider_den: u32,
    /// Added to the computed temperature, in 1/8 °C.
    pub temperature_offset_eighths: i32,
}

/// VREFINT typical voltage, µV (STM32F405 datasheet).
pub const VREFINT_UV: u32 = 1_210_000;
const FULL_SCALE: u32 = 4095;

/// VDDA in µV from a VREFINT sample (0 if the sample is 0).
pub const fn vdda_microvolts(vrefint_raw: u16) -> u32 {
    if vrefint_raw == 0 {
        return 0;
    }
    let uv = (VREFINT_UV as u64 * FULL_SCALE as u64) / vrefint_raw as u64;
    if uv > u32::MAX as u64 {
        u32::MAX
    } else {
        uv as u32
    }
}

/// Pin voltage in µV of a raw sample at the given VDDA.
pub const fn pin_microvolts(raw: u16, vdda_uv: u32) -> u32 {
    ((raw as u64 * vdda_uv as u64) / FULL_SCALE as u64) as u32
}

/// Supply voltage in PoStep60 units of 0.072 V (manual 8.3.7), rounded.
pub const fn supply_units(sample: AnalogSample, board: AnalogBoard) -> u16 {
    if board.divider_den == 0 {
        return 0;
    }
    let pin = pin_microvolts(sample.supply, vdda_microvolts(sample.vrefint)) as u64;
    let uv = pin * board.divider_num as u64 / board.divider_den as u64;
    let units = (uv + 36_000) / 72_000;
    if units > u16::MAX as u64 {
        u16::MAX
    } else {
        units as u16
    }
}

/// Temperature in PoStep60 units of 0.125 °C (manual 8.3.8), clamped to 0.
/// T = (V_sense − 0.76 V) / 2.5 mV/°C + 25 °C.
pub const fn temperature_units(sample: AnalogSample, board: AnalogBoard) -> u16 {
    let v = pin_microvolts(sample.temperature, vdda_microvolts(sample.vrefint)) as i64;
    // eighths of a degree: (v − 760 000 µV) · 8 / 2 500 µV + 25 · 8
    let t = (v - 760_000) * 8 / 2_500 + 200 + board.temperature_offset_eighths as i64;
    if t < 0 {
        0
    } else if t > u16::MAX as i64 {
        u16::MAX
    } else {
        t as u16
    }
}

/// Whole degrees Celsius from PoStep60 temperature units (floor).
pub const fn celsius(units: u16) -> u16 {
    units / 8
}

#[cfg(test)]
mod tests {
    use super::*;

    const BOARD: AnalogBoard = AnalogBoard {
        divider_num: 20,
        divider_den: 1,
        temperature_offset_eighths: 0,
    };

    /// VREFINT reads 1502 counts at VDDA = 3.3 V.
    const VREF_3V3: u16 = 1502;

    #[test]
    fn vdda_from_vrefint() {
        assert_eq!(vdda_microvolts(VREF_3V3) / 1000, 3298);
        assert_eq!(vdda_microvolts(0), 0);
    }

    #[test]
    fn supply_of_24_v_is_333_units_of_72_mv() {
        // 24 V / 20 = 1.2 V at the pin = 1.2/3.2988 · 4095 = 1489.6 counts
        let s = AnalogSample {
            supply: 1490,
            temperature: 0,
            vrefint: VREF_3V3,
        };
        let u = supply_units(s, BOARD);
        assert_eq!(u, 333); // 333 · 0.072 = 23.976 V
    }

    #[test]
    fn temperature_at_25_c_is_200_eighths() {
        // 0.76 V at VDDA 3.2988 V = 943.4 counts
        let s = AnalogSample {
            supply: 0,
            temperature: 943,
            vrefint: VREF_3V3,
        };
        let t = temperature_units(s, BOARD);
        assert!((199..=201).contains(&t), "{t}");
        assert_eq!(celsius(200), 25);
    }

    #[test]
    fn temperature_slope_is_2_5_mv_per_degree() {
        // +100 °C = +250 mV = +310.3 counts
        let cold = temperature_units(
            AnalogSample {
                supply: 0,
                temperature: 943,
                vrefint: VREF_3V3,
            },
            BOARD,
        );
        let hot = temperature_units(
            AnalogSample {
                supply: 0,
                temperature: 1253,
                vrefint: VREF_3V3,
            },
            BOARD,
        );
        assert!((795..=805).contains(&(hot - cold)), "{}", hot - cold);
    }

    #[test]
    fn nonsense_samples_do_not_panic() {
        for raw in [0u16, 1, 4095, u16::MAX] {
            let s = AnalogSample {
                supply: raw,
                temperature: raw,
                vrefint: raw,
            };
            let _ = supply_units(s, BOARD);
            let _ = temperature_units(s, BOARD);
        }
    }
}
