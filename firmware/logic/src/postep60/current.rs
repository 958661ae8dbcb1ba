//! PoStep60 current encoding (manual 8.3.12 and 8.3.18): on the wire a current
//! is two bytes, Tq and Ai, with I = 0.065 A · Tq / 2^Ai.

// Tq/Ai codec: u8 fields and mA values widened to u32/u64 before they multiply.
#![allow(clippy::arithmetic_side_effects)]

/// A current as the PoStep60 encodes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Current {
    pub tq: u8,
    pub ai: u8,
}

/// Largest Ai we accept (2^15 keeps the arithmetic exact; the manual's
/// encoder only produces 0..=3).
pub const AI_MAX: u8 = 15;

impl Current {
    /// I in mA = 65 · Tq / 2^Ai (rounded down). `None` for Ai > [`AI_MAX`].
    pub const fn milliamps(self) -> Option<u32> {
        if self.ai > AI_MAX {
            return None;
        }
        Some((65 * self.tq as u32) >> self.ai)
    }

    /// The manual's encoder (8.3.18) on milliamps, in exact integers:
    /// `Tq = 123 · I; Ai = 3; while Tq > 255 { Ai -= 1; Tq >>= 1 }`.
    /// `123 · I[A]` is computed as `123 · mA / 1000`, truncated like the
    /// manual's `int` conversion. Currents that would need Ai < 0 saturate at
    /// Tq = 255, Ai = 0 (15.9 A, far above any board limit).
    pub const fn from_milliamps(ma: u32) -> Current {
        let mut tq = (123u64 * ma as u64) / 1000;
        let mut ai: u8 = 3;
        while tq > 255 {
            if ai == 0 {
                return Current { tq: 255, ai: 0 };
            }
            ai -= 1;
            tq >>= 1;
        }
        Current { tq: tq as u8, ai }
    }

    /// Clamp to `limit_ma`: a current above the limit is replaced by the
    /// manual's encoding of the limit (so the clamp shows on read-back).
    pub const fn clamped(self, limit_ma: u32) -> Current {
        match self.milliamps() {
            Some(ma) if ma <= limit_ma => self,
            _ => Current::from_milliamps(limit_ma),
        }
    }

    /// The same current with Ai at most `max_ai` (Tq shifted down, rounded
    /// down): for encodings that only hold Ai 0..=3 (the DRV8711's ISGAIN).
    pub const fn with_ai_at_most(self, max_ai: u8) -> Current {
        if self.ai <= max_ai {
            return self;
        }
        let shift = self.ai - max_ai;
        let tq = if shift >= 8 { 0 } else { self.tq >> shift };
        Current { tq, ai: max_ai }
    }

    pub const fn to_bytes(self) -> [u8; 2] {
        [self.tq, self.ai]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The manual's C loop, run literally on amps as f64 (test oracle only).
    fn manual_loop(amps: f64) -> (u8, u8) {
        let mut tq = (123.0 * amps) as i32;
        let mut ai = 3;
        while tq > 255 {
            ai -= 1;
            tq >>= 1;
        }
        (tq as u8, ai as u8)
    }

    #[test]
    fn one_amp_encodes_as_tq_123_ai_3() {
        assert_eq!(Current::from_milliamps(1000), Current { tq: 123, ai: 3 });
        assert_eq!(Current { tq: 123, ai: 3 }.milliamps(), Some(999)); // 0.065·123/8 = 0.999 A
    }

    #[test]
    fn six_amp_limit_encodes_as_tq_184_ai_1() {
        // 123·6 = 738 → 369 (Ai 2) → 184 (Ai 1)
        assert_eq!(Current::from_milliamps(6000), Current { tq: 184, ai: 1 });
        assert_eq!(Current { tq: 184, ai: 1 }.milliamps(), Some(5980));
    }

    #[test]
    fn encoder_matches_the_manual_loop_for_every_10_ma_step() {
        for ma in (0..=6000).step_by(10) {
            let (tq, ai) = manual_loop(f64::from(ma) / 1000.0);
            assert_eq!(Current::from_milliamps(ma), Current { tq, ai }, "{ma} mA");
        }
    }

    #[test]
    fn read_formula_is_0_065_tq_over_2_pow_ai() {
        assert_eq!(Current { tq: 200, ai: 2 }.milliamps(), Some(3250));
        assert_eq!(Current { tq: 255, ai: 0 }.milliamps(), Some(16575));
        assert_eq!(Current { tq: 1, ai: 16 }.milliamps(), None);
    }

    #[test]
    fn currents_above_the_limit_are_clamped_to_the_limit_encoding() {
        let too_much = Current { tq: 255, ai: 1 }; // 8.29 A
        assert_eq!(too_much.clamped(6000), Current { tq: 184, ai: 1 });
        let fine = Current { tq: 123, ai: 3 };
        assert_eq!(fine.clamped(6000), fine);
        assert_eq!(
            Current { tq: 9, ai: 99 }.clamped(6000),
            Current { tq: 184, ai: 1 }
        );
    }

    #[test]
    fn round_trip_stays_within_one_quantum() {
        for ma in [100u32, 500, 999, 1500, 2500, 4000, 5999] {
            let back = Current::from_milliamps(ma).milliamps().unwrap();
            assert!(back <= ma && ma - back <= 65, "{ma} → {back}");
        }
    }
}
