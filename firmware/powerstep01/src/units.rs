//! Unit conversions between physical quantities and powerSTEP01 register
//! values (datasheet and §6). Exact integer arithmetic only.
//!
//! Conventions:
//! * Speeds are **full steps per second** in Q16.16 (`u32`, `value << 16`),
//!   accelerations full steps per second² in Q16.16 — the chip's speed and
//!   acceleration registers count full steps whatever STEP_SEL is.
//! * The chip's tick is 250 ns (16 MHz oscillator), so 1 s = 4 000 000 ticks.
//! * `*_from_*` converts physical → register and rounds to nearest; results
//!   are clamped to the register's range. `*_to_*` converts register →
//!   physical exactly (or rounded to nearest where the result is not integral).
//! * Voltages are in microvolts or nanovolts, fractions of V_S in basis points.

// Every conversion widens its argument (a register value of at most 22
// bits, or a u32 in Q16.16) to u64/u128 before it multiplies, and divides by
// non-zero constants: no product or sum can overflow (each function's doc
// gives the range; `tests` run them at their extremes).
#![allow(clippy::arithmetic_side_effects)]

/// One Q16.16 unit: `steps_q16(5)` = 5 steps/s.
pub const fn steps_q16(steps: u32) -> u32 {
    steps << 16
}

const TICKS_PER_S: u64 = 4_000_000;

/// Round `num / den` to nearest (halves up). `den` must be non-zero.
const fn div_round(num: u64, den: u64) -> u64 {
    (num + den / 2) / den
}

const fn clamp(v: u64, max: u32) -> u32 {
    if v > max as u64 {
        max
    } else {
        v as u32
    }
}

// ---------------------------------------------------------------- speeds ----

/// SPEED register / Run and GoUntil SPD (0.28 step/tick, 20 bit):
/// reg = v · 2²⁸ / 4·10⁶ = v_q16 · 2¹² / 4·10⁶. 1 LSB ≈ 0.0149 step/s.
pub const fn speed_from_steps_per_s(v_q16: u32) -> u32 {
    clamp(div_round((v_q16 as u64) << 12, TICKS_PER_S), 0xF_FFFF)
}

/// Inverse of [`speed_from_steps_per_s`]: v_q16 = reg · 4·10⁶ / 2¹² = reg · 15625 / 16 (exact).
pub const fn speed_to_steps_per_s(reg: u32) -> u32 {
    ((reg as u64 & 0xF_FFFF) * 15_625 / 16) as u32
}

/// MAX_SPEED (0.18 step/tick, 10 bit): reg = v · 2¹⁸ / 4·10⁶. 1 LSB = 15.2587890625 step/s.
pub const fn max_speed_from_steps_per_s(v_q16: u32) -> u32 {
    clamp(div_round((v_q16 as u64) << 2, TICKS_PER_S), 0x3FF)
}

/// Inverse of [`max_speed_from_steps_per_s`]: v_q16 = reg · 10⁶ (exact).
pub const fn max_speed_to_steps_per_s(reg: u32) -> u32 {
    (reg & 0x3FF) * 1_000_000
}

/// MIN_SPEED bits 11:0 (0.24 step/tick, 12 bit): reg = v · 2²⁴ / 4·10⁶. LSPD_OPT not included.
pub const fn min_speed_from_steps_per_s(v_q16: u32) -> u32 {
    clamp(div_round((v_q16 as u64) << 8, TICKS_PER_S), 0xFFF)
}

/// Inverse of [`min_speed_from_steps_per_s`]: v_q16 = reg · 15625 (exact).
pub const fn min_speed_to_steps_per_s(reg: u32) -> u32 {
    (reg & 0xFFF) * 15_625
}

/// INT_SPEED (0.26 step/tick, 14 bit): reg = v · 2²⁶ / 4·10⁶.
pub const fn int_speed_from_steps_per_s(v_q16: u32) -> u32 {
    clamp(div_round((v_q16 as u64) << 10, TICKS_PER_S), 0x3FFF)
}

/// Inverse of [`int_speed_from_steps_per_s`]: v_q16 = reg · 15625 / 4 (exact).
pub const fn int_speed_to_steps_per_s(reg: u32) -> u32 {
    ((reg as u64 & 0x3FFF) * 15_625 / 4) as u32
}

/// FS_SPD bits 9:0 with the datasheet's +0.5 offset:
/// v = (reg + 0.5) · 15.2587890625, so reg = round(v · 0.065536 − 0.5) = floor(v · 0.065536)
/// (ties at exact multiples go down, so the threshold never rises above the request).
pub const fn fs_spd_from_steps_per_s(v_q16: u32) -> u32 {
    clamp(((v_q16 as u64) << 2) / TICKS_PER_S, 0x3FF)
}

/// Inverse of [`fs_spd_from_steps_per_s`]: v_q16 = (reg + 0.5) · 10⁶ (exact).
pub const fn fs_spd_to_steps_per_s(reg: u32) -> u32 {
    (reg & 0x3FF) * 1_000_000 + 500_000
}

// --------------------------------------------------------- accelerations ----

/// Largest finite ACC/DEC: 0xFFF means "infinite acceleration" on the
/// powerSTEP01 and is reserved on siblings, so we never send it.
pub const ACC_MAX_FINITE: u32 = 0xFFE;

/// ACC/DEC (0.40 step/tick², 12 bit): reg = a · 2⁴⁰ / (4·10⁶)² = a_q16 · 2²⁴ / 1.6·10¹³.
/// Clamped to 1..=0xFFE (0 would never move, 0xFFF is "infinite").
pub const fn acc_from_steps_per_s2(a_q16: u32) -> u32 {
    let reg = div_round((a_q16 as u64) << 24, TICKS_PER_S * TICKS_PER_S);
    if reg == 0 {
        1
    } else {
        clamp(reg, ACC_MAX_FINITE)
    }
}

/// Inverse of [`acc_from_steps_per_s2`], rounded to nearest Q16.16.
pub const fn acc_to_steps_per_s2(reg: u32) -> u32 {
    div_round((reg as u64 & 0xFFF) * TICKS_PER_S * TICKS_PER_S, 1 << 24) as u32
}

// ------------------------------------------------------------ analogue ----

/// TVAL (current mode): V_ref = (TVAL + 1) · 7.8125 mV, so TVAL = round(V / 7.8125 mV) − 1,
/// clamped to 0..=127 (7.8125 mV … 1 V).
pub const fn tval_from_microvolts(uv: u32) -> u8 {
    // 7.8125 mV = 7812.5 µV → multiply by 2 to stay integral.
    let steps = div_round(uv as u64 * 2, 15_625);
    if steps == 0 {
        0
    } else {
        clamp(steps - 1, 127) as u8
    }
}

/// Inverse of [`tval_from_microvolts`], in nanovolts (exact).
pub const fn tval_to_nanovolts(tval: u8) -> u32 {
    ((tval as u32 & 0x7F) + 1) * 7_812_500
}

/// Peak phase current from TVAL and the sense resistor: I = V_ref / R_sense, in mA.
pub const fn tval_to_milliamps(tval: u8, sense_milliohm: u32) -> u32 {
    if sense_milliohm == 0 {
        return 0;
    }
    // nV / mΩ = µA; /1000 → mA
    (tval_to_nanovolts(tval) / sense_milliohm) / 1000
}

/// TVAL giving a peak current of `ma` through `sense_milliohm` (rounded, clamped).
pub const fn tval_from_milliamps(ma: u32, sense_milliohm: u32) -> u8 {
    // mA · mΩ = µV
    let uv = ma as u64 * sense_milliohm as u64;
    tval_from_microvolts(clamp(uv, u32::MAX))
}

/// KVAL (voltage mode): amplitude = V_S · KVAL / 256. `bp` is basis points of
/// V_S (10 000 = 100 %); KVAL = round(bp · 256 / 10 000), clamped to 255.
pub const fn kval_from_basis_points(bp: u32) -> u8 {
    kval_from_ratio(bp, 10_000)
}

/// KVAL for an amplitude of `num / den` of V_S (e.g. mV of phase voltage over
/// mV of supply): round(num · 256 / den), clamped to 255; 0 when `den` is 0.
pub const fn kval_from_ratio(num: u32, den: u32) -> u8 {
    if den == 0 {
        return 0;
    }
    clamp(div_round(num as u64 * 256, den as u64), 255) as u8
}

/// Inverse of [`kval_from_basis_points`] (rounded to nearest basis point).
pub const fn kval_to_basis_points(kval: u8) -> u32 {
    div_round(kval as u64 * 10_000, 256) as u32
}

/// OCD_TH: threshold = (OCD_TH + 1) · 31.25 mV; reg = round(V / 31.25 mV) − 1, clamped 0..=31.
pub const fn ocd_th_from_microvolts(uv: u32) -> u8 {
    threshold_31mv25(uv)
}

/// Inverse of [`ocd_th_from_microvolts`], in microvolts (exact).
pub const fn ocd_th_to_microvolts(reg: u8) -> u32 {
    ((reg as u32 & 0x1F) + 1) * 31_250
}

/// STALL_TH: threshold = (STALL_TH + 1) · 31.25 mV; same rounding as OCD_TH.
pub const fn stall_th_from_microvolts(uv: u32) -> u8 {
    threshold_31mv25(uv)
}

/// Inverse of [`stall_th_from_microvolts`], in microvolts (exact).
pub const fn stall_th_to_microvolts(reg: u8) -> u32 {
    ((reg as u32 & 0x1F) + 1) * 31_250
}

const fn threshold_31mv25(uv: u32) -> u8 {
    let steps = div_round(uv as u64, 31_250);
    if steps == 0 {
        0
    } else {
        clamp(steps - 1, 31) as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Q16.16 of a decimal number given as (integer part, millionths).
    fn q16(int: u32, micro: u32) -> u32 {
        (int << 16) + ((u64::from(micro) << 16) / 1_000_000) as u32
    }

    #[test]
    fn speed_register_lsb_is_0_0149_steps_per_s() {
        // 1 LSB = 0.0149011612 step/s; 67.108864 LSB per step/s.
        assert_eq!(speed_from_steps_per_s(steps_q16(1)), 67);
        assert_eq!(speed_from_steps_per_s(steps_q16(1000)), 67_109);
        assert_eq!(speed_to_steps_per_s(1), 976); // 0.0149 · 65536
    }

    #[test]
    fn speed_register_full_scale_is_15625_steps_per_s() {
        assert_eq!(speed_to_steps_per_s(0xF_FFFF) >> 16, 15_624);
        assert_eq!(speed_from_steps_per_s(steps_q16(15_625)), 0xF_FFFF);
        assert_eq!(speed_from_steps_per_s(steps_q16(20_000)), 0xF_FFFF);
    }

    #[test]
    fn speed_round_trip_is_within_half_an_lsb() {
        for reg in [0u32, 1, 2, 1000, 67_109, 0x8_0000, 0xF_FFFE] {
            assert_eq!(speed_from_steps_per_s(speed_to_steps_per_s(reg)), reg);
        }
    }

    #[test]
    fn max_speed_default_0x041_is_991_8_steps_per_s() {
        assert_eq!(max_speed_to_steps_per_s(0x041), 65_000_000); // 991.82 · 65536
        assert_eq!(max_speed_to_steps_per_s(0x041) >> 16, 991);
        assert_eq!(max_speed_from_steps_per_s(q16(991, 820_000)), 0x041);
        // 0x3FF → 15609.7 step/s
        assert_eq!(max_speed_to_steps_per_s(0x3FF) >> 16, 15_609);
        assert_eq!(max_speed_from_steps_per_s(steps_q16(15_625)), 0x3FF);
    }

    #[test]
    fn max_speed_lsb_is_15_2587890625_steps_per_s() {
        // 0.065536 LSB per step/s
        assert_eq!(max_speed_from_steps_per_s(q16(15, 258_789)), 1);
        assert_eq!(max_speed_to_steps_per_s(1), 1_000_000); // 15.2587890625 · 65536
    }

    #[test]
    fn min_speed_lsb_is_0_2384_steps_per_s_and_range_976_3() {
        assert_eq!(min_speed_to_steps_per_s(1), 15_625); // 0.2384185791 · 65536
        assert_eq!(min_speed_from_steps_per_s(steps_q16(1)), 4); // 4.194304
        assert_eq!(min_speed_to_steps_per_s(0xFFF) >> 16, 976);
        assert_eq!(min_speed_from_steps_per_s(steps_q16(2000)), 0xFFF);
    }

    #[test]
    fn int_speed_default_0x408_is_61_5_steps_per_s() {
        let v = int_speed_to_steps_per_s(0x408);
        assert_eq!(v >> 16, 61);
        assert_eq!((u64::from(v & 0xFFFF) * 10) >> 16, 5); // 61.5…
        assert_eq!(int_speed_from_steps_per_s(v), 0x408);
        assert_eq!(int_speed_from_steps_per_s(steps_q16(1)), 17); // 16.777216
        assert_eq!(int_speed_to_steps_per_s(0x3FFF) >> 16, 976);
    }

    #[test]
    fn fs_spd_default_0x027_is_602_7_steps_per_s_with_half_lsb_offset() {
        // (0x27 + 0.5) · 15.2587890625 = 602.72
        assert_eq!(fs_spd_to_steps_per_s(0x027), 39_500_000);
        assert_eq!(fs_spd_to_steps_per_s(0x027) >> 16, 602);
        assert_eq!(fs_spd_from_steps_per_s(q16(602, 720_000)), 0x027);
        // reg = v · 0.065536 − 0.5: 7.63 step/s is the lowest threshold (reg 0)
        assert_eq!(fs_spd_to_steps_per_s(0) >> 16, 7);
        assert_eq!(fs_spd_from_steps_per_s(steps_q16(8)), 0);
        assert_eq!(fs_spd_from_steps_per_s(steps_q16(16_000)), 0x3FF);
    }

    #[test]
    fn acc_default_0x08a_is_2008_steps_per_s2() {
        assert_eq!(acc_to_steps_per_s2(0x08A) >> 16, 2008);
        assert_eq!(acc_from_steps_per_s2(steps_q16(2008)), 0x08A);
        // 1 LSB = 14.5519 step/s², 0.068719476736 LSB per step/s²
        assert_eq!(acc_to_steps_per_s2(1) >> 16, 14);
        assert_eq!(acc_from_steps_per_s2(q16(14, 551_915)), 1);
    }

    #[test]
    fn acc_is_clamped_to_0xffe_and_never_zero() {
        assert_eq!(acc_to_steps_per_s2(0xFFE) >> 16, 59_575);
        assert_eq!(acc_from_steps_per_s2(q16(59_575, 500_000)), 0xFFE);
        assert_eq!(acc_from_steps_per_s2(steps_q16(60_000)), ACC_MAX_FINITE);
        assert_eq!(acc_from_steps_per_s2(0), 1);
        assert_eq!(acc_from_steps_per_s2(steps_q16(1)), 1);
    }

    #[test]
    fn tval_default_0x29_is_328_1_mv() {
        assert_eq!(tval_to_nanovolts(0x29), 328_125_000);
        assert_eq!(tval_from_microvolts(328_125), 0x29);
        assert_eq!(tval_to_nanovolts(0), 7_812_500);
        assert_eq!(tval_to_nanovolts(127), 1_000_000_000);
        assert_eq!(tval_from_microvolts(1_000_000), 127);
        assert_eq!(tval_from_microvolts(2_000_000), 127);
        assert_eq!(tval_from_microvolts(0), 0);
    }

    #[test]
    fn tval_current_uses_sense_resistor() {
        // 328.125 mV across 100 mΩ = 3.281 A
        assert_eq!(tval_to_milliamps(0x29, 100), 3281);
        assert_eq!(tval_from_milliamps(3281, 100), 0x29);
        assert_eq!(tval_to_milliamps(0x29, 0), 0);
    }

    #[test]
    fn kval_default_0x29_is_16_percent_of_supply() {
        // percent = KVAL · 0.390625
        assert_eq!(kval_to_basis_points(0x29), 1602); // 16.015625 %
        assert_eq!(kval_from_basis_points(1602), 0x29);
        assert_eq!(kval_from_basis_points(10_000), 255);
        assert_eq!(kval_to_basis_points(1), 39);
    }

    #[test]
    fn kval_from_phase_voltage_over_supply() {
        // 2.486 V of 24 V = 10.36 % → 26.52 → 27
        assert_eq!(kval_from_ratio(2486, 24_000), 27);
        assert_eq!(kval_from_ratio(30_000, 24_000), 255);
        assert_eq!(kval_from_ratio(1, 0), 0);
    }

    #[test]
    fn ocd_th_default_0x08_is_281_25_mv() {
        assert_eq!(ocd_th_to_microvolts(0x08), 281_250);
        assert_eq!(ocd_th_from_microvolts(281_250), 0x08);
        assert_eq!(ocd_th_to_microvolts(0x1F), 1_000_000);
        assert_eq!(ocd_th_from_microvolts(5_000_000), 0x1F);
        assert_eq!(ocd_th_from_microvolts(0), 0);
    }

    #[test]
    fn stall_th_default_0x10_is_531_25_mv() {
        assert_eq!(stall_th_to_microvolts(0x10), 531_250);
        assert_eq!(stall_th_from_microvolts(531_250), 0x10);
        assert_eq!(stall_th_to_microvolts(0), 31_250);
    }
}
