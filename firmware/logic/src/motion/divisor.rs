//! Exact division by a divisor known in advance, without a division
//! instruction: the control tick divides by the same few numbers (the tick
//! period, the deceleration) every tick, and a Cortex-M4 has no 64-bit
//! divide — each `u64 / u64` is a ~160-instruction library call.
//!
//! [`Divisor::new`] pays one division to make the reciprocal
//! `m = ⌊(2⁶⁴ − 1) / d⌋`; [`Divisor::div`] then estimates `q = ⌊n·m / 2⁶⁴⌋`
//! with four 32 × 32 → 64-bit multiplies (UMULL) and corrects it.
//!
//! Why at most two corrections: `m ≤ (2⁶⁴ − 1)/d` gives `q ≤ n/d`, so `q`
//! never exceeds `⌊n/d⌋`; `m > (2⁶⁴ − 1)/d − 1` gives
//! `n·m/2⁶⁴ > n/d − n(1 + d)/(d·2⁶⁴) ≥ n/d − 2` for every `n < 2⁶⁴`, so `q`
//! is at least `⌊n/d⌋ − 2`. The result is exactly `n / d` (property test).

// A 64-bit reciprocal divider: the products are of 32-bit halves in u64 and
// the quotient correction runs at most twice (module doc, exhaustive tests).
#![allow(clippy::arithmetic_side_effects)]

/// A divisor with its precomputed reciprocal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Divisor {
    d: u64,
    m: u64,
}

/// High 64 bits of the 128-bit product `a·b` ([`mul_wide`]; the low half's
/// assembly is left out by the compiler).
const fn mul_hi(a: u64, b: u64) -> u64 {
    (mul_wide(a, b) >> 64) as u64
}

/// The 128-bit product `a·b`, from four 32 × 32 → 64 products (a `u128`
/// product is a library call on 32-bit ARM).
pub const fn mul_wide(a: u64, b: u64) -> u128 {
    let (a0, a1) = (a & 0xFFFF_FFFF, a >> 32);
    let (b0, b1) = (b & 0xFFFF_FFFF, b >> 32);
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let p11 = a1 * b1;
    let mid = (p00 >> 32) + (p01 & 0xFFFF_FFFF) + (p10 & 0xFFFF_FFFF);
    let hi = p11 + (p01 >> 32) + (p10 >> 32) + (mid >> 32);
    ((hi as u128) << 64) | ((mid << 32) | (p00 & 0xFFFF_FFFF)) as u128
}

impl Divisor {
    /// Division by `d` (0 is taken as 1: callers guard their divisors, and a
    /// division must never trap).
    pub const fn new(d: u64) -> Divisor {
        let d = if d == 0 { 1 } else { d };
        Divisor { d, m: u64::MAX / d }
    }

    /// The divisor.
    pub const fn get(self) -> u64 {
        self.d
    }

    /// `n / d`, exactly.
    pub const fn div(self, n: u64) -> u64 {
        let mut q = mul_hi(n, self.m);
        // q ≤ n/d (module doc), so this never wraps.
        let mut r = n - q * self.d;
        while r >= self.d {
            q += 1;
            r -= self.d;
        }
        q
    }

    /// `n / d` rounded toward zero, as Rust's `/` on `i64`.
    pub const fn div_signed(self, n: i64) -> i64 {
        let q = self.div(n.unsigned_abs());
        // q ≤ |n| ≤ 2⁶³: the negation is exact; a positive q of 2⁶³ (n =
        // i64::MIN, d = 1) cannot be returned positive, but n < 0 there.
        if n < 0 {
            (q as i64).wrapping_neg()
        } else {
            q as i64
        }
    }
}

/// A [`Divisor`] that keeps its last signed quotient: while an axis
/// cruises, the control tick converts the same speed and the same
/// following error tick after tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Recalled {
    div: Divisor,
    /// (n, n / d) of the last division (0 / d = 0 to begin with).
    last: (i64, i64),
}

impl Recalled {
    pub const fn new(div: Divisor) -> Recalled {
        Recalled { div, last: (0, 0) }
    }

    /// [`Divisor::div_signed`], from memory when `n` is the last one's.
    #[inline]
    pub fn div_signed(&mut self, n: i64) -> i64 {
        if n != self.last.0 {
            self.last = (n, self.div.div_signed(n));
        }
        self.last.1
    }
}

/// `n / d` for a divisor below 2³², exactly, with the core's 32-bit
/// divide (UDIV) only: the high word by UDIV, then the low word's 64-by-32
/// step as two 16-bit digits (Hacker's Delight, `divlu`). A 64-bit `/` is
/// a library call and an `i128` one a 128-step loop on a Cortex-M4.
pub const fn div_u64_by_u32(n: u64, d: u32) -> u64 {
    if d == 0 {
        return n; // as Divisor: 0 divides as 1 (callers guard their divisors)
    }
    let hi = (n >> 32) as u32;
    let q_hi = hi / d;
    let r_hi = hi - q_hi * d;
    ((q_hi as u64) << 32) | divlu(r_hi, n as u32, d) as u64
}

/// `n / d` for a divisor below 2³², exactly: long division in 32-bit
/// limbs, each step by [`div_u64_by_u32`] (an `i128`/`u128` division is a
/// long loop on a Cortex-M4). 0 divides as 1.
pub const fn div_u128_by_u32(n: u128, d: u32) -> u128 {
    if d == 0 {
        return n;
    }
    let dd = d as u64;
    let mut r = 0u64;
    let mut q = 0u128;
    let mut i = 4;
    while i > 0 {
        i -= 1;
        // r < d < 2³²: the step's dividend fits 64 bits, its quotient 32.
        let t = (r << 32) | ((n >> (32 * i)) as u64 & 0xFFFF_FFFF);
        let qi = div_u64_by_u32(t, d);
        r = t - qi * dd;
        q |= (qi as u128) << (32 * i);
    }
    q
}

/// ⌊(u1·2³² + u0) / v⌋ for `u1 < v` (the quotient fits 32 bits), from
/// 32-by-32 divisions of 16-bit digits (Hacker's Delight 9-3, `divlu2`).
const fn divlu(u1: u32, u0: u32, v: u32) -> u32 {
    const B: u32 = 1 << 16;
    // Normalise: v's top bit set (u1 < v keeps the numerator's top part in range).
    let s = v.leading_zeros();
    let v = v << s;
    let (vn1, vn0) = (v >> 16, v & 0xFFFF);
    let un32 = if s == 0 {
        u1
    } else {
        (u1 << s) | (u0 >> (32 - s))
    };
    let un10 = u0 << s;
    let (un1, un0) = (un10 >> 16, un10 & 0xFFFF);
    let mut q1 = un32 / vn1;
    let mut rhat = un32 - q1 * vn1;
    while q1 >= B || (q1 as u64) * (vn0 as u64) > (B as u64) * (rhat as u64) + un1 as u64 {
        q1 -= 1;
        rhat += vn1;
        if rhat >= B {
            break;
        }
    }
    let un21 = un32
        .wrapping_mul(B)
        .wrapping_add(un1)
        .wrapping_sub(q1.wrapping_mul(v));
    let mut q0 = un21 / vn1;
    let mut rhat = un21 - q0 * vn1;
    while q0 >= B || (q0 as u64) * (vn0 as u64) > (B as u64) * (rhat as u64) + un0 as u64 {
        q0 -= 1;
        rhat += vn1;
        if rhat >= B {
            break;
        }
    }
    q1 * B + q0
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn the_wide_product_is_the_u128_product() {
        for (a, b) in [
            (0u64, 0u64),
            (u64::MAX, u64::MAX),
            (u64::MAX, 1),
            (0x1_0000_0000, 0xFFFF_FFFF),
            (0x1234_5678_9ABC_DEF0, 0x0FED_CBA9_8765_4321),
        ] {
            assert_eq!(
                mul_wide(a, b),
                u128::from(a) * u128::from(b),
                "{a:#x} · {b:#x}"
            );
        }
    }

    #[test]
    fn small_divisors_and_edges_are_exact() {
        for d in [
            1u64,
            2,
            3,
            7,
            10,
            1000,
            64_000,
            1 << 32,
            (1 << 32) + 1,
            u64::MAX,
        ] {
            let v = Divisor::new(d);
            for n in [
                0u64,
                1,
                d - 1,
                d,
                d.saturating_add(1),
                d.saturating_mul(2),
                u64::MAX - 1,
                u64::MAX,
            ] {
                assert_eq!(v.div(n), n / d, "{n} / {d}");
            }
        }
    }

    #[test]
    fn zero_divides_as_one() {
        assert_eq!(Divisor::new(0).div(12345), 12345);
        assert_eq!(Divisor::new(0).get(), 1);
    }

    #[test]
    fn signed_division_truncates_toward_zero_like_rust() {
        let v = Divisor::new(1000);
        for n in [
            -1999i64,
            -1000,
            -999,
            -1,
            0,
            1,
            999,
            1000,
            1999,
            i64::MIN,
            i64::MAX,
        ] {
            assert_eq!(v.div_signed(n), n / 1000, "{n}");
        }
        assert_eq!(Divisor::new(1).div_signed(i64::MIN), i64::MIN);
    }

    #[test]
    fn by_u32_is_exact_at_the_edges() {
        for d in [
            1u32,
            2,
            3,
            7,
            0xFFFF,
            0x1_0000,
            0x1_0001,
            0x8000_0000,
            u32::MAX - 1,
            u32::MAX,
        ] {
            for n in [
                0u64,
                1,
                u64::from(d) - 1,
                u64::from(d),
                u64::MAX,
                u64::MAX - 1,
                1 << 32,
                (1 << 32) - 1,
                0x8000_0000_0000_0000,
            ] {
                assert_eq!(div_u64_by_u32(n, d), n / u64::from(d), "{n} / {d}");
            }
        }
        assert_eq!(div_u64_by_u32(12345, 0), 12345);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20_000))]

        #[test]
        fn by_u32_equals_the_division_operator(n in any::<u64>(), d in 1u32..) {
            prop_assert_eq!(div_u64_by_u32(n, d), n / u64::from(d));
        }

        #[test]
        fn u128_by_u32_equals_the_division_operator(n in any::<u128>(), d in 1u32..) {
            prop_assert_eq!(div_u128_by_u32(n, d), n / u128::from(d));
        }

        #[test]
        fn by_small_u32_too(n in any::<u64>(), d in 1u32..100_000) {
            prop_assert_eq!(div_u64_by_u32(n, d), n / u64::from(d));
        }

        #[test]
        fn div_equals_the_division_operator(n in any::<u64>(), d in 1u64..) {
            prop_assert_eq!(Divisor::new(d).div(n), n / d);
        }

        #[test]
        fn small_divisors_too(n in any::<u64>(), d in 1u64..100_000) {
            prop_assert_eq!(Divisor::new(d).div(n), n / d);
        }

        #[test]
        fn signed_div_equals_the_division_operator(n in any::<i64>(), d in 1u64..(1 << 62)) {
            prop_assert_eq!(Divisor::new(d).div_signed(n), n / d as i64);
        }
    }

    #[test]
    fn a_recalled_quotient_is_the_division_of_the_same_number() {
        for d in [1u64, 3, 1000, 64_000, (1 << 40) + 7] {
            let mut r = Recalled::new(Divisor::new(d));
            let div = Divisor::new(d);
            for n in [
                0i64,
                5,
                5,
                -5,
                -5,
                i64::MIN,
                i64::MAX,
                i64::MAX,
                12_345_678_901,
                0,
            ] {
                assert_eq!(r.div_signed(n), div.div_signed(n), "{n} / {d}");
            }
        }
    }
}
