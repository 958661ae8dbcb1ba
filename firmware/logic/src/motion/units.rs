//! Unit conversions of the motion layer: PoStep60 logical steps ↔ the chip's
//! physical microsteps, profile velocities → chip SPEED values, profile
//! limits ↔ the chip's MAX_SPEED/ACC/DEC registers, and what a chip can
//! follow in each step mode. Exact integer arithmetic; every function is
//! `const` and tested with worked numbers.
//!
//! Logical steps are 1/2^L full step (PoStep60 step mode L = 0 … 8), physical
//! microsteps 1/2^S full step (the chip's STEP_SEL S). Chip speeds and
//! accelerations count full steps (datasheet).

// Conversions widen to i64/u64/i128 before they multiply and shift by at
// most 8 + 33 bits; every input is a u32 or a clamped speed (function docs).
#![allow(clippy::arithmetic_side_effects)]

use super::divisor::Divisor;
use super::profile::Limits;
use crate::powerstep::fields::StepSel;
use crate::powerstep::units::ACC_MAX_FINITE;

/// Finest PoStep60 step mode (8 = 1/256).
pub const MAX_LOGICAL_SHIFT: u8 = 8;

/// The chip's ACC/DEC are the profile's times this ratio (3/2): with equal
/// ramps the chip could never catch up a following error while the profile
/// accelerates or brakes at its limit.
pub const RAMP_HEADROOM_NUM: u64 = 3;
pub const RAMP_HEADROOM_DEN: u64 = 2;

/// MAX_SPEED is a backstop this fraction (1/4) above the profile's max speed …
pub const BACKSTOP_QUARTERS: u64 = 1;
/// … plus this many full steps/s, so corrections have room at low speeds.
pub const BACKSTOP_EXTRA: u64 = 16;

/// Largest MAX_SPEED register value (10 bit).
const MAX_SPEED_REG_MAX: u64 = 0x3FF;

/// `(x >> shift) as i64` (the low 64 bits of the arithmetic shift), in
/// 64-bit halves for `1 ≤ shift ≤ 63`: an `i128` shift by a variable
/// amount is a long sequence on a 32-bit core, and the control tick does
/// one per axis (the profile's position in physical microsteps).
#[inline]
pub const fn shr_i128_to_i64(x: i128, shift: u32) -> i64 {
    if shift == 0 || shift >= 64 {
        return (x >> (shift & 127)) as i64;
    }
    let lo = x as u64;
    let hi = (x >> 64) as u64;
    ((lo >> shift) | (hi << (64 - shift))) as i64
}

/// Logical position → physical microsteps (floor when the logical step is finer).
pub const fn logical_to_physical(pos: i64, logical_shift: u8, step: StepSel) -> i64 {
    let s = step.shift() as i64;
    let l = logical_shift as i64;
    if s >= l {
        pos << (s - l)
    } else {
        pos >> (l - s)
    }
}

/// Physical microsteps → logical position (exact when the logical step is coarser
/// or equal; otherwise the physical microstep's first logical step).
pub const fn physical_to_logical(pos: i64, logical_shift: u8, step: StepSel) -> i64 {
    let s = step.shift() as i64;
    let l = logical_shift as i64;
    if s >= l {
        // Floor: a physical position between two logical steps reads as the lower one.
        pos >> (s - l)
    } else {
        pos << (l - s)
    }
}

/// Logical steps/s (or /s²) → full steps/s in Q16.16, rounded up, not capped.
const fn full_q16(v: u32, logical_shift: u8) -> u64 {
    ((v as u64) << 16).div_ceil(1u64 << logical_shift)
}

/// Logical steps/s (or /s²) → full steps/s in Q16.16, rounded up (capped at `u32::MAX`).
pub const fn full_steps_q16_from_logical(v: u32, logical_shift: u8) -> u32 {
    let r = full_q16(v, logical_shift);
    if r > u32::MAX as u64 {
        u32::MAX
    } else {
        r as u32
    }
}

/// Profile velocity (2⁻³² logical steps per tick) → chip SPEED units (signed):
/// `v · 10⁶ · 2²⁸ / (tick_us · 2³² · 2^L · 4·10⁶) = v / (tick_us · 2^(6+L))`.
pub const fn speed_reg_from_internal(v: i64, tick_us: u32, logical_shift: u8) -> i64 {
    let div = (tick_us as i64) << (6 + logical_shift as i64);
    if div == 0 {
        0
    } else {
        v / div
    }
}

/// The divisor of [`speed_reg_from_internal`] (`tick_us · 2^(6+L)`), for the
/// control tick's division-free [`speed_reg_with`].
pub const fn speed_divisor(tick_us: u32, logical_shift: u8) -> Divisor {
    Divisor::new((tick_us as u64) << (6 + logical_shift as u64))
}

/// [`speed_reg_from_internal`] with its divisor precomputed: the same value.
pub const fn speed_reg_with(v: i64, div: Divisor) -> i64 {
    div.div_signed(v)
}

/// The divisor of [`correction_speed_reg`] (`tick_us · ticks · 2^S`, at
/// least 1), for the control tick's division-free [`correction_reg_with`].
pub const fn correction_divisor(tick_us: u32, step: StepSel, ticks: i64) -> Divisor {
    let div = (tick_us as i64) * ticks;
    if div <= 0 {
        return Divisor::new(0);
    }
    Divisor::new((div as u64) << step.shift())
}

/// [`correction_speed_reg`] with its divisor precomputed: the same value
/// (for `tick_us · ticks > 0`).
pub const fn correction_reg_with(e: i64, div: Divisor) -> i64 {
    div.div_signed(correction_numerator(e))
}

/// The numerator [`correction_reg_with`] divides (the error clamped to
/// ±2³⁰ microsteps, times 2²⁶), for a divisor that remembers it.
pub const fn correction_numerator(e: i64) -> i64 {
    let e = if e > 1 << 30 {
        1 << 30
    } else if e < -(1 << 30) {
        -(1 << 30)
    } else {
        e
    };
    e << 26
}

/// The largest read-back correction (chip SPEED units) for a chip whose
/// DEC register holds `dec_reg`, at a feed-forward speed `ff` (SPEED): the
/// speed its DEC takes off in half the correction period (4 ms), plus an
/// eighth of `ff`.
///
/// A correction is a speed the chip must later undo at its own DEC. Near
/// zero speed, where the correction alone sets the Run's direction, a chip
/// with a slow DEC that was nudged one way while its profile rested or
/// crept is so back at the profile's speed within 4 ms when the profile
/// sets off the other way (unbounded, it ran on the wrong way for tens of
/// ms and was then driven at twice its acceleration to catch up). At speed
/// the eighth leaves room to follow a chip whose oscillator is up to 10 %
/// off before its rate is learned (a cap of the first term alone held
/// such a chip's error above the rate estimate's gate). A DEC register of
/// `d` changes SPEED by `d · 2⁻⁴⁰ · (4·10⁶)² / 2⁻²⁸ / 4·10⁶ = d · 4·10⁶ /
/// 2¹²` per second, so `d · 4000 µs / 1024` in 4 ms (`d` = 0, no DEC
/// written yet: the eighth alone).
pub const fn correction_cap(dec_reg: u32, ff: i64) -> i64 {
    correction_cap_at_rest(dec_reg) as i64 + (ff.unsigned_abs() >> 3) as i64
}

/// [`correction_cap`] at a standstill (`ff` = 0), in the core's 32-bit
/// arithmetic: DEC is a 12-bit register (`d · 4000 < 2²⁴`).
pub const fn correction_cap_at_rest(dec_reg: u32) -> u32 {
    ((dec_reg & 0xFFF) * CORRECTION_CAP_US) >> 10
}

/// The span [`correction_cap`] allows the chip's DEC to undo a correction in.
pub const CORRECTION_CAP_US: u32 = 4_000;

/// A following error of `e` physical microsteps corrected over `ticks` ticks,
/// in chip SPEED units: `e / 2^S` full steps per `ticks · tick_us` µs.
pub const fn correction_speed_reg(e: i64, tick_us: u32, step: StepSel, ticks: i64) -> i64 {
    let div = (tick_us as i64) * ticks;
    if div <= 0 {
        return 0;
    }
    // full steps/s = e · 10⁶ / (2^S · div); reg = that · 2²⁸ / 4·10⁶.
    // |e| beyond 2³⁰ microsteps is no following error but a lost position:
    // clamp so the shift cannot overflow (the speed saturates anyway).
    let e = if e > 1 << 30 {
        1 << 30
    } else if e < -(1 << 30) {
        -(1 << 30)
    } else {
        e
    };
    (e << 26) / (div << step.shift())
}

/// The deceleration a move's last stretch may ask of the chip, as a share of
/// the profile's (5/4): the chip's DEC is [`RAMP_HEADROOM_NUM`] /
/// [`RAMP_HEADROOM_DEN`] of the profile's, and the rest is the margin for
/// the loop's delay (the position the cap is worked out from is 1 to 3
/// ticks old) and a chip oscillator up to 10 % slow (its ramps then take
/// 1/0.9² as long).
pub const STOP_RAMP_NUM: u64 = 5;
pub const STOP_RAMP_DEN: u64 = 4;

/// The factor of [`cap_to_stop`] for a profile decelerating at `dec`
/// (logical steps/s² of mode `logical_shift`) on a chip at `step`: the
/// fastest `Run` (SPEED units) from which the chip still stops within `d`
/// microsteps is `√(factor · d / 2¹⁶)` (`v² = 2·a·d`, `a = dec ·
/// STOP_RAMP_NUM / STOP_RAMP_DEN`).
///
/// In full steps: `v = √(2·a·d / 2^S)` steps/s, SPEED = `v · 2²⁶ / 10⁶`, so
/// `SPEED² = 2·a·d · 2^(52 − L − S) / 10¹²` for `a` in logical steps/s²; in
/// Q16 `2^(69 − L − S)`. At most `2³² · 5/4 · 2⁶⁹ / 10¹²` < 2⁶³ (worked out
/// once per change of limits: a 128-bit division).
pub const fn stop_cap_q16(dec: u32, logical_shift: u8, step: StepSel) -> u64 {
    let dec = if dec == 0 { 1 } else { dec };
    let l = if logical_shift > MAX_LOGICAL_SHIFT {
        MAX_LOGICAL_SHIFT
    } else {
        logical_shift
    };
    let shift = 69 - l as u32 - step.shift();
    let f = ((dec as u128 * STOP_RAMP_NUM as u128) << shift)
        / (STOP_RAMP_DEN as u128 * 1_000_000_000_000);
    if f > u64::MAX as u128 {
        u64::MAX
    } else if f == 0 {
        1
    } else {
        f as u64
    }
}

/// Beyond this a SPEED's size no longer matters (twice SPEED_MAX, the
/// largest `Run` the chip takes: the caller saturates the sum it caps).
const SPEED_CAP: u64 = 1 << 21;

/// `speed` (SPEED units, signed), no faster than the chip can stop from
/// within `d` microsteps ([`stop_cap_q16`]'s `factor`; `d ≤ 0`: not at
/// all). No division: a square root only when the cap applies.
pub const fn cap_to_stop(speed: i64, d: i64, factor_q16: u64) -> i64 {
    cap_speed(speed, stop_speed2(d, factor_q16))
}

/// The square of the fastest SPEED the chip stops from within `d`
/// microsteps ([`stop_cap_q16`]'s `factor`; 0 for `d ≤ 0`, saturating at
/// `u64::MAX`, far above any SPEED²).
#[inline]
pub const fn stop_speed2(d: i64, factor_q16: u64) -> u64 {
    let d = if d < 0 { 0 } else { d as u64 };
    match factor_q16.checked_mul(d) {
        Some(p) => p >> 16,
        None => u64::MAX,
    }
}

/// `speed` is no faster than `√cap2` (SPEED units; a speed beyond
/// `SPEED_CAP` counts as that).
#[inline]
pub const fn within(speed: i64, cap2: u64) -> bool {
    let c = speed.unsigned_abs();
    let c = if c > SPEED_CAP { SPEED_CAP } else { c };
    c * c <= cap2
}

/// `speed` (SPEED units, signed), no faster than `√cap2`.
#[inline]
pub const fn cap_speed(speed: i64, cap2: u64) -> i64 {
    if within(speed, cap2) {
        return speed;
    }
    let c = isqrt(cap2) as i64;
    if speed < 0 {
        -c
    } else {
        c
    }
}

/// [`cap_to_stop`] for one axis's deceleration, worked out when its limits
/// change: the factor, and the room beyond which no `Run` needs a cap (the
/// chip stops from its fastest, SPEED_MAX, within it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StopCap {
    factor: u64,
    room: i64,
}

impl StopCap {
    /// For a profile decelerating at `dec` (logical steps/s² of mode
    /// `logical_shift`) on a chip at `step`.
    pub const fn new(dec: u32, logical_shift: u8, step: StepSel) -> StopCap {
        let factor = stop_cap_q16(dec, logical_shift, step);
        // SPEED_MAX² ≤ factor · room / 2¹⁶, rounded up.
        let room = ((SPEED_CAP / 2) * (SPEED_CAP / 2)) << 16;
        let room = room.div_ceil(factor);
        StopCap {
            factor,
            room: if room > i64::MAX as u64 {
                i64::MAX
            } else {
                room as i64
            },
        }
    }

    /// Microsteps from which the chip stops from any `Run`.
    pub const fn room(&self) -> i64 {
        self.room
    }

    /// [`stop_speed2`] with this factor.
    #[inline]
    pub const fn speed2(&self, d: i64) -> u64 {
        stop_speed2(d, self.factor)
    }
}

/// ⌊√x⌋, bit by bit (x < 2⁴² where it is used: 21 rounds).
const fn isqrt(x: u64) -> u64 {
    let mut r = 0u64;
    let mut bit = 1u64 << 62;
    while bit > x {
        bit >>= 2;
    }
    let mut x = x;
    while bit != 0 {
        if x >= r + bit {
            x -= r + bit;
            r = (r >> 1) + bit;
        } else {
            r >>= 1;
        }
        bit >>= 2;
    }
    r
}

/// The MAX_SPEED register a profile max speed (logical steps/s) needs, not
/// capped at the register's 10 bits: the backstop 25 % + 16 full steps/s
/// above it, rounded to nearest (at least 1).
const fn backstop_reg_exact(v: u32, logical_shift: u8) -> u64 {
    let full = full_q16(v, logical_shift);
    let backstop = full + full * BACKSTOP_QUARTERS / 4 + (BACKSTOP_EXTRA << 16);
    // MAX_SPEED = v · 2¹⁸ / 4·10⁶ = v_q16 · 4 / 4·10⁶ (units::max_speed_from_steps_per_s),
    // by the core's 32-bit divide (a move's first tick asks; a 64-bit
    // division is a library call on the M4): backstop < 2⁴⁹.
    let reg = super::divisor::div_u64_by_u32(backstop * 4 + 2_000_000, 4_000_000);
    if reg == 0 {
        1
    } else {
        reg
    }
}

/// The MAX_SPEED register for a profile max speed: the backstop, capped at 0x3FF.
pub const fn backstop_reg(v: u32, logical_shift: u8) -> u32 {
    let r = backstop_reg_exact(v, logical_shift);
    if r > MAX_SPEED_REG_MAX {
        MAX_SPEED_REG_MAX as u32
    } else {
        r as u32
    }
}

/// The ACC/DEC register for a profile acceleration (logical steps/s²), not
/// capped: RAMP_HEADROOM times faster, plus one LSB for rounding.
const fn ramp_reg_exact(a: u32, logical_shift: u8) -> u64 {
    let full = full_q16(a, logical_shift);
    let fast = full * RAMP_HEADROOM_NUM / RAMP_HEADROOM_DEN;
    // ACC = a · 2⁴⁰ / (4·10⁶)² = a_q16 · 2²⁴ / 1.6·10¹³ (units::acc_from_steps_per_s2),
    // rounded: ⌊(fast · 2²⁴ + 8·10¹²) / (2¹⁶ · 244 140 625)⌋. The 2¹⁶ first
    // (exact: fast · 2²⁴ is a multiple of it, 8·10¹² / 2¹⁶ = 122 070 312.5),
    // then the 32-bit divisor by the core's divide: fast < 2⁵⁰, so
    // fast · 2⁸ fits 64 bits (a 128-bit division is a long loop on the M4).
    let reg = super::divisor::div_u64_by_u32((fast << 8) + 122_070_312, 244_140_625);
    let reg = if reg == 0 { 1 } else { reg };
    reg.saturating_add(1)
}

/// The chip's ACC/DEC register for a profile acceleration: capped at the
/// largest finite value (0xFFE).
pub const fn ramp_reg(a: u32, logical_shift: u8) -> u32 {
    let r = ramp_reg_exact(a, logical_shift);
    if r > ACC_MAX_FINITE as u64 {
        ACC_MAX_FINITE
    } else {
        r as u32
    }
}

/// The chip's ACC/DEC register for ramps the chip runs itself (homing's
/// GoUntil and ReleaseSW, and the SoftStop after a found switch): the
/// axis's acceleration exactly (rounded to the nearest register step, 1 at
/// least, 0xFFE at most), without the streaming headroom of [`ramp_reg`].
pub const fn chip_ramp_reg(a: u32, logical_shift: u8) -> u32 {
    crate::powerstep::units::acc_from_steps_per_s2(full_steps_q16_from_logical(a, logical_shift))
}

/// Largest `x` in `1..=u32::MAX` with `f(x) ≤ limit` (`f` non-decreasing), or 1.
const fn largest_within(limit: u64, logical_shift: u8, ramp: bool) -> u32 {
    const fn f(x: u32, logical_shift: u8, ramp: bool) -> u64 {
        if ramp {
            ramp_reg_exact(x, logical_shift)
        } else {
            backstop_reg_exact(x, logical_shift)
        }
    }
    let (mut lo, mut hi) = (1u64, u32::MAX as u64);
    if f(hi as u32, logical_shift, ramp) <= limit {
        return u32::MAX;
    }
    // Invariant: f(hi) > limit; f(lo) ≤ limit unless lo = 1 fails too.
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if f(mid as u32, logical_shift, ramp) <= limit {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo as u32
}

/// The largest profile acceleration (logical steps/s²) that a chip whose
/// ACC (or DEC) register holds `reg` can follow with its headroom.
///
/// Closed form of "the largest `a` with `ramp_reg_exact(a) ≤ reg`" (a move
/// start needs it; a bisection cost ~70 000 instructions per axis on the
/// target). Every step inverts one monotone step of `ramp_reg_exact`:
/// `reg₀ = ⌊(fast·2²⁴ + den/2) / den⌋ ≤ reg − 1 ⟺ fast ≤ F = ⌊(reg·den −
/// den/2 − 1) / 2²⁴⌋`; `fast = ⌊3·full/2⌋ ≤ F ⟺ full ≤ G = ⌊(2F + 1)/3⌋`;
/// `full = ⌈a·2¹⁶/2^L⌉ ≤ G ⟺ a ≤ ⌊G·2^L / 2¹⁶⌋`. Equal to the bisection
/// for every register value (test).
pub const fn ramp_capability(reg: u32, logical_shift: u8) -> u32 {
    // ramp_reg_exact is at least 2: nothing fits below (the bisection's 1).
    if reg < 2 {
        return 1;
    }
    let den: u128 = 16_000_000_000_000;
    let f = ((reg as u128) * den - den / 2 - 1) >> 24;
    let g = (2 * f + 1) / 3;
    let a = (g << logical_shift) >> 16;
    if a > u32::MAX as u128 {
        u32::MAX
    } else if a == 0 {
        1
    } else {
        a as u32
    }
}

/// The fastest profile limits a powerSTEP01 can follow in logical step mode
/// `logical_shift`: max speed whose backstop still fits MAX_SPEED (0x3FF ≈
/// 15 610 full steps/s), accelerations whose ramps (× 3/2) still fit the
/// largest finite ACC/DEC (0xFFE ≈ 59 575 full steps/s²).
pub const fn limit_cap(logical_shift: u8) -> Limits {
    let shift = if logical_shift > MAX_LOGICAL_SHIFT {
        MAX_LOGICAL_SHIFT
    } else {
        logical_shift
    };
    let a = largest_within(ACC_MAX_FINITE as u64, shift, true);
    Limits {
        max_speed: largest_within(MAX_SPEED_REG_MAX, shift, false),
        acc: a,
        dec: a,
    }
}

/// [`limit_cap`] for every logical step mode, computed at compile time.
// Const evaluation: an out-of-range index would fail the build.
#[allow(clippy::indexing_slicing)]
pub const LIMIT_CAPS: [Limits; 9] = {
    let mut caps = [Limits {
        max_speed: 0,
        acc: 0,
        dec: 0,
    }; 9];
    let mut l = 0;
    while l < 9 {
        caps[l] = limit_cap(l as u8);
        l += 1;
    }
    caps
};

/// `limits` clamped to what the chip can follow in logical step mode `shift`.
// The index is clamped to 8 on the line it is computed: LIMIT_CAPS has 9.
#[allow(clippy::indexing_slicing)]
pub const fn clamp_to_chip(limits: Limits, shift: u8) -> Limits {
    let cap = LIMIT_CAPS[if shift as usize > 8 {
        8
    } else {
        shift as usize
    }];
    Limits {
        max_speed: min(limits.max_speed, cap.max_speed),
        acc: min(limits.acc, cap.acc),
        dec: min(limits.dec, cap.dec),
    }
}

const fn min(a: u32, b: u32) -> u32 {
    if a < b {
        a
    } else {
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::powerstep::units::{acc_to_steps_per_s2, max_speed_to_steps_per_s};

    #[test]
    fn chip_ramp_reg_is_the_acceleration_itself() {
        // 4000 steps/s² at 1/16 = 250 full steps/s²; ACC = a · 2⁴⁰ / (4·10⁶)²
        // (datasheet, ACC): 250 · 0.0687 = 17.18 → 17; 500 → 34.36 → 34.
        assert_eq!(chip_ramp_reg(4000, 4), 17);
        assert_eq!(chip_ramp_reg(8000, 4), 34);
        assert_eq!(chip_ramp_reg(1, 8), 1, "never 0");
        assert_eq!(chip_ramp_reg(u32::MAX, 0), ACC_MAX_FINITE, "never infinite");
    }

    #[test]
    fn logical_to_physical_scales_by_powers_of_two() {
        // logical 1/16 (4) on a chip at 1/128 (7): ×8
        assert_eq!(logical_to_physical(100, 4, StepSel::OneTwentyEighth), 800);
        assert_eq!(physical_to_logical(800, 4, StepSel::OneTwentyEighth), 100);
        // logical 1/256 (8) on a chip at 1/16: ÷16, floor
        assert_eq!(logical_to_physical(4096, 8, StepSel::Sixteenth), 256);
        assert_eq!(logical_to_physical(-1, 8, StepSel::Sixteenth), -1);
        assert_eq!(physical_to_logical(256, 8, StepSel::Sixteenth), 4096);
        // full steps on full steps
        assert_eq!(logical_to_physical(-7, 0, StepSel::Full), -7);
    }

    #[test]
    fn full_step_rates_round_up() {
        // 1000 logical 1/16 steps/s = 62.5 full steps/s
        assert_eq!(full_steps_q16_from_logical(1000, 4), 62 * 65536 + 32768);
        assert_eq!(full_steps_q16_from_logical(1, 8), 256);
        assert_eq!(full_steps_q16_from_logical(3, 1), 98_304);
    }

    #[test]
    fn precomputed_divisors_give_the_same_speeds() {
        for shift in 0..=MAX_LOGICAL_SHIFT {
            for tick_us in [1000u32, 500, 200, 1, 2_000_000] {
                let d = speed_divisor(tick_us, shift);
                let c = correction_divisor(tick_us, StepSel::OneTwentyEighth, 8);
                for v in [
                    0i64,
                    1,
                    -1,
                    4_294_967_296_000,
                    -123_456_789_012,
                    i64::MAX,
                    i64::MIN + 1,
                ] {
                    assert_eq!(
                        speed_reg_with(v, d),
                        speed_reg_from_internal(v, tick_us, shift)
                    );
                }
                for e in [
                    0i64,
                    1,
                    -1,
                    7,
                    -7,
                    1000,
                    -1000,
                    1 << 31,
                    -(1 << 31),
                    i64::MIN + 1,
                ] {
                    assert_eq!(
                        correction_reg_with(e, c),
                        correction_speed_reg(e, tick_us, StepSel::OneTwentyEighth, 8)
                    );
                }
            }
        }
    }

    #[test]
    fn speed_register_from_profile_velocity() {
        // 1 logical full step per 1 ms tick = 1000 full steps/s = 67108.864 SPEED
        assert_eq!(speed_reg_from_internal(1 << 32, 1000, 0), 67_108);
        // same speed in 1/128 logical steps = 1000/128 full steps/s
        assert_eq!(speed_reg_from_internal(1 << 32, 1000, 7), 524);
        assert_eq!(speed_reg_from_internal(-(1 << 32), 1000, 0), -67_108);
    }

    #[test]
    fn correction_cap_is_the_speed_the_chips_dec_takes_off_in_four_ms_and_an_eighth_of_the_speed() {
        // DEC 42 (the slow-deceleration case): 42 · 2⁻⁴⁰ steps per 250 ns²
        // = 611.2 full steps/s², 2.445 full steps/s in 4 ms = 164.1 SPEED.
        assert_eq!(correction_cap(42, 0), 164);
        // The same through the chip's units: DEC in steps/s² (Q16) times
        // 4 ms, as a Run speed.
        for reg in [1u32, 42, 0x8A, 1884, 0xFFE] {
            let per_s2 = crate::powerstep::units::acc_to_steps_per_s2(reg);
            let v_q16 = (u64::from(per_s2) * 4 / 1000) as u32;
            let spd = i64::from(crate::powerstep::units::speed_from_steps_per_s(v_q16));
            assert!((correction_cap(reg, 0) - spd).abs() <= 1, "DEC {reg}");
        }
        assert_eq!(correction_cap(0, 0), 0);
        // At speed, an eighth of it more (either direction).
        assert_eq!(correction_cap(42, 8_000), 1_164);
        assert_eq!(correction_cap(42, -8_000), 1_164);
    }

    #[test]
    fn correction_of_one_full_step_over_eight_ticks() {
        // 128 microsteps (one full step at 1/128) in 8 ms = 125 full steps/s = 8388.6 SPEED
        assert_eq!(
            correction_speed_reg(128, 1000, StepSel::OneTwentyEighth, 8),
            8388
        );
        assert_eq!(
            correction_speed_reg(-128, 1000, StepSel::OneTwentyEighth, 8),
            -8388
        );
    }

    #[test]
    fn the_stop_cap_is_the_speed_the_chip_stops_from_within_the_distance() {
        // dec 65 535 logical 1/16 steps/s² = 4095.9 full steps/s², × 5/4 =
        // 5119.9; 10 full steps (1280 microsteps at 1/128) stop from
        // √(2 · 5119.9 · 10) = 320.0 full steps/s = 21 474.6 SPEED.
        let f = stop_cap_q16(65_535, 4, StepSel::OneTwentyEighth);
        assert!((cap_to_stop(1_000_000, 1280, f) - 21_474).abs() <= 1);
        assert!((cap_to_stop(-1_000_000, 1280, f) + 21_474).abs() <= 1);
        // Slower Runs are left alone; nothing left: no Run toward it.
        assert_eq!(cap_to_stop(21_000, 1280, f), 21_000);
        assert_eq!(cap_to_stop(-5, 1280, f), -5);
        assert_eq!(cap_to_stop(500, 0, f), 0);
        assert_eq!(cap_to_stop(500, -40, f), 0);
        // The same in full steps on a full-step chip: one full step = one microstep.
        let g = stop_cap_q16(65_535 / 16, 0, StepSel::Full);
        assert!((cap_to_stop(1_000_000, 10, g) - 21_474).abs() <= 3);
        // Never faster for less room; saturating for any input.
        let mut last = 0;
        for d in (0..200_000).step_by(997) {
            let c = cap_to_stop(i64::MAX, d, f);
            assert!(c >= last && c <= 1 << 21);
            last = c;
        }
        // Beyond twice SPEED_MAX a speed counts as that (the chip takes no
        // more): room for it leaves any speed as it is.
        let top = stop_cap_q16(u32::MAX, 0, StepSel::Full);
        assert_eq!(cap_to_stop(i64::MIN, i64::MAX, top), i64::MIN);
        assert_eq!(cap_to_stop(i64::MAX, 1, 1 << 16), 1);
        assert_eq!(cap_to_stop(0, 1000, top), 0);
    }

    #[test]
    fn beyond_the_room_no_run_is_capped() {
        for (dec, shift) in [(65_535, 4), (1, 8), (u32::MAX, 0), (1000, 0)] {
            let s = StopCap::new(dec, shift, StepSel::OneTwentyEighth);
            let f = stop_cap_q16(dec, shift, StepSel::OneTwentyEighth);
            let max = (1i64 << 20) - 1;
            assert_eq!(cap_to_stop(max, s.room(), f), max, "{dec} {shift}");
            assert!(s.room() <= 2 || cap_to_stop(max, s.room() / 2, f) < max);
            assert_eq!(s.speed2(s.room()), stop_speed2(s.room(), f));
        }
        // 65 535 at 1/16 on 1/128: SPEED_MAX (15 625 full steps/s) stops in
        // 15 625² / (2 · 5 120) = 23 842 full steps.
        let r = StopCap::new(65_535, 4, StepSel::OneTwentyEighth).room();
        assert!((r - 23_842 * 128).abs() < 128, "{r}");
    }

    /// The 128-bit form `ramp_reg_exact` had.
    fn ramp_reg_by_u128(a: u32, logical_shift: u8) -> u64 {
        let fast = full_q16(a, logical_shift) * RAMP_HEADROOM_NUM / RAMP_HEADROOM_DEN;
        let den: u128 = 16_000_000_000_000;
        let reg = ((u128::from(fast) << 24) + den / 2) / den;
        u64::try_from(reg.max(1)).unwrap_or(u64::MAX - 1) + 1
    }

    #[test]
    fn the_ramp_register_equals_the_128_bit_division() {
        for shift in 0..=MAX_LOGICAL_SHIFT {
            for a in (0..5_000u32)
                .chain((0..2_000).map(|k| k * 2_147_483))
                .chain([u32::MAX, u32::MAX - 1, 1 << 31, 65_535, 200_000])
            {
                assert_eq!(
                    ramp_reg_exact(a, shift),
                    ramp_reg_by_u128(a, shift),
                    "{a} {shift}"
                );
            }
        }
    }

    #[test]
    fn the_halves_shift_equals_the_i128_shift() {
        let xs = [
            0i128,
            1,
            -1,
            (1 << 33) - 1,
            -(1 << 33),
            i128::from(i64::MAX) << 33,
            i128::from(i64::MIN) << 33,
            0x1234_5678_9ABC_DEF0_1357_9BDF_0246_8ACE,
            -0x1234_5678_9ABC_DEF0_1357_9BDF_0246_8ACE,
            i128::MAX,
            i128::MIN,
        ];
        for x in xs {
            for shift in 0..=127 {
                assert_eq!(
                    shr_i128_to_i64(x, shift),
                    (x >> shift) as i64,
                    "{x} >> {shift}"
                );
            }
        }
    }

    #[test]
    fn integer_square_roots_are_floors() {
        for x in (0..5_000u64).chain([1 << 40, (1 << 42) - 1, 1 << 42, u64::MAX]) {
            let r = isqrt(x);
            assert!(
                r * r <= x && (r + 1).checked_mul(r + 1).is_none_or(|s| s > x),
                "{x}"
            );
        }
    }

    #[test]
    fn backstop_is_a_quarter_and_16_steps_above_the_max_speed() {
        // 1000 full steps/s → 1266 full steps/s → 1266 · 0.065536 = 82.97 → 83
        assert_eq!(backstop_reg(1000, 0), 83);
        // the same speed as 1/16 steps
        assert_eq!(backstop_reg(16_000, 4), 83);
        // 0 steps/s still gives the 16 steps/s backstop: 1.05 → 1
        assert_eq!(backstop_reg(0, 0), 1);
        // beyond the register: capped at 0x3FF
        assert_eq!(backstop_reg(65_535, 0), 0x3FF);
    }

    #[test]
    fn ramps_are_one_and_a_half_times_the_profile_plus_one_lsb() {
        // 20 000 full steps/s² · 1.5 = 30 000 → 30 000 · 0.068719 = 2061.6 → 2062, + 1
        assert_eq!(ramp_reg(20_000, 0), 2063);
        // the default-like 2008 steps/s²: 3012 · 0.0687 = 206.99 → 207, + 1
        assert_eq!(ramp_reg(2008 * 128, 7), 208);
        assert_eq!(ramp_reg(65_535, 0), ACC_MAX_FINITE);
    }

    #[test]
    fn ramp_capability_equals_the_bisection_for_every_register() {
        for shift in 0..=MAX_LOGICAL_SHIFT {
            for reg in (0..=0x1000u32).chain([u32::MAX, u32::MAX / 3, 1 << 20]) {
                assert_eq!(
                    ramp_capability(reg, shift),
                    largest_within(u64::from(reg), shift, true),
                    "shift {shift} reg {reg}"
                );
            }
        }
    }

    #[test]
    fn ramp_capability_inverts_the_ramp_register() {
        for shift in 0..=8 {
            for reg in [2, 3, 208, 2063, 0xFFE] {
                let a = ramp_capability(reg, shift);
                assert!(ramp_reg(a, shift) <= reg, "shift {shift} reg {reg}");
                if a < u32::MAX {
                    assert!(ramp_reg_exact(a + 1, shift) > u64::from(reg));
                }
            }
        }
    }

    #[test]
    fn the_chip_caps_full_step_limits_at_12_481_steps_per_s_and_39_712_per_s2() {
        // MAX_SPEED 0x3FF = 15 609.7 full steps/s; the backstop is v·1.25 + 16.
        let cap = limit_cap(0);
        assert_eq!(cap.max_speed, 12_481);
        assert!(backstop_reg(cap.max_speed, 0) <= 0x3FF);
        // (rounded to nearest: 12 481 · 1.25 + 16 = 15 617 → 1023.49 → 0x3FF)
        let backstop = (cap.max_speed + 1) as f64 * 1.25 + 16.0;
        assert!(backstop * 0.065536 > 1023.5);
        // 0xFFE = 59 575.5 full steps/s²; the ramp is a·1.5 (+1 LSB).
        assert_eq!(cap.acc, 39_712);
        assert_eq!(cap.dec, cap.acc);
        assert!(acc_to_steps_per_s2(0xFFE) >> 16 >= 59_575);
        assert_eq!(max_speed_to_steps_per_s(0x3FF) / 1_000_000, 0x3FF);
    }

    #[test]
    fn finer_step_modes_scale_the_cap_by_their_steps_per_full_step() {
        // 1/16 (4): the full-step cap times 16 (± the rounding of a step)
        let cap = limit_cap(4);
        assert!((cap.max_speed as i64 - 12_481 * 16).abs() < 16);
        assert!((cap.acc as i64 - 39_712 * 16).abs() < 16);
        // A 16-bit PoStep60 value can never exceed it at 1/8 or finer.
        assert!(limit_cap(3).max_speed > 65_535 && limit_cap(3).acc > 65_535);
        assert_eq!(LIMIT_CAPS[4], cap);
    }

    #[test]
    fn clamping_keeps_what_the_chip_can_do() {
        let l = Limits {
            max_speed: 65_535,
            acc: 100,
            dec: 65_535,
        };
        let c = clamp_to_chip(l, 0);
        assert_eq!(c.max_speed, 12_481);
        assert_eq!(c.acc, 100);
        assert_eq!(c.dec, 39_712);
        assert_eq!(clamp_to_chip(l, 8), l);
    }
}
