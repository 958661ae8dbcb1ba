//! Property tests of the profile generator alone (issue: motion).
//!
//! Every case simulates a whole move tick by tick and checks the promises of
//! `motion::profile`'s module doc at every tick.

// A test: not bus input.
#![allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used
)]
#![allow(clippy::expect_used, clippy::panic)]

use bridge_logic::motion::{Limits, Profile};
use proptest::prelude::*;

const TICK_US: u32 = 1000;

/// Limits whose move times stay short enough to simulate 10 000 cases:
/// ramps of 20 ms … 2 s.
fn limits() -> impl Strategy<Value = Limits> {
    max_speed().prop_flat_map(limits_near)
}

/// Max speeds from 10 steps/s up to the fastest a chip can go in the finest
/// PoStep60 step mode (15 625 full steps/s · 256 = 4 000 000 steps/s).
fn max_speed() -> impl Strategy<Value = u32> {
    prop_oneof![10u32..200_000, 200_000u32..4_000_000]
}

/// Limits with a max speed within a factor of two of `v` (so that retargets
/// between them stay short) and ramps of 10 ms … 4 s at `v`.
fn limits_near(v: u32) -> impl Strategy<Value = Limits> {
    let lo = (v / 4).max(1);
    let hi = v.saturating_mul(100).max(lo + 1);
    ((v / 2).max(1)..v.saturating_mul(2).max(2), lo..hi, lo..hi).prop_map(
        |(max_speed, acc, dec)| Limits {
            max_speed,
            acc,
            dec,
        },
    )
}

/// One tick, checked against the limits in force during it (taken before
/// the tick: the deceleration may return to the limit's once at rest).
fn tick_checked(p: &mut Profile, before: i64) -> Result<i64, TestCaseError> {
    let limits = p.internal_limits();
    let after = p.tick();
    check_step(limits, before, after)?;
    Ok(after)
}

/// Checks one tick's velocity change against the limits in force.
fn check_step(limits: (i64, i64, i64), before: i64, after: i64) -> Result<(), TestCaseError> {
    let (vmax, acc, dec) = limits;
    // Speed never above max, unless it is coming down from an older, higher max.
    prop_assert!(
        after.abs() <= vmax || after.abs() < before.abs(),
        "speed {after} above max {vmax} (was {before})"
    );
    // No sign change inside one tick.
    prop_assert!(before == 0 || after == 0 || (before > 0) == (after > 0));
    if after.abs() > before.abs() {
        prop_assert!(
            after.abs() - before.abs() <= acc,
            "acc {} > {acc}",
            after.abs() - before.abs()
        );
    } else {
        prop_assert!(
            before.abs() - after.abs() <= dec,
            "dec {} > {dec}",
            before.abs() - after.abs()
        );
    }
    Ok(())
}

/// Analytic trapezoid/triangle time in ticks for the quantised limits.
fn analytic_ticks(d: f64, vmax: f64, acc: f64, dec: f64) -> f64 {
    if d == 0.0 {
        return 0.0;
    }
    let ramp = vmax * vmax / (2.0 * acc) + vmax * vmax / (2.0 * dec);
    if d >= ramp {
        d / vmax + vmax / (2.0 * acc) + vmax / (2.0 * dec)
    } else {
        let vp = (2.0 * d * acc * dec / (acc + dec)).sqrt();
        vp / acc + vp / dec
    }
}

/// Peak speed of the analytic profile.
fn peak_speed(d: f64, vmax: f64, acc: f64, dec: f64) -> f64 {
    let vp = (2.0 * d * acc * dec / (acc + dec)).sqrt();
    vp.min(vmax)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 10_000, ..ProptestConfig::default() })]

    #[test]
    fn speed_and_acceleration_stay_within_limits_on_a_fixed_move(
        lim in limits(), frac in 0u32..=3000, neg in any::<bool>(), start in -1_000_000i64..1_000_000,
    ) {
        let d = i64::from(lim.max_speed) * i64::from(frac) / 1000;
        let mut p = Profile::new(TICK_US, lim);
        p.set_position(start);
        p.move_to(if neg { start - d } else { start + d });
        let mut v = 0;
        for _ in 0..100_000 {
            if p.is_settled() { break; }
            v = tick_checked(&mut p, v)?;
        }
        prop_assert!(p.is_settled());
    }

    #[test]
    fn fixed_target_move_ends_exactly_on_target_without_overshoot(
        lim in limits(), frac in 0u32..=3000, neg in any::<bool>(), start in -3_000_000_000i64..3_000_000_000,
    ) {
        let d = i64::from(lim.max_speed) * i64::from(frac) / 1000;
        let target = if neg { start - d } else { start + d };
        let mut p = Profile::new(TICK_US, lim);
        p.set_position(start);
        p.move_to(target);
        let goal = i128::from(target) << 33;
        for _ in 0..100_000 {
            if p.is_settled() { break; }
            p.tick();
            // Never beyond the target, never behind the start.
            if neg {
                prop_assert!(p.position_fine() >= goal);
                prop_assert!(p.velocity_internal() <= 0);
            } else {
                prop_assert!(p.position_fine() <= goal);
                prop_assert!(p.velocity_internal() >= 0);
            }
        }
        prop_assert_eq!(p.position_fine(), goal);
        prop_assert_eq!(p.velocity_internal(), 0);
    }

    #[test]
    fn move_time_is_within_one_tick_of_the_analytic_trapezoid(
        lim in limits(), frac in 0u32..=3000,
    ) {
        let d = i64::from(lim.max_speed) * i64::from(frac) / 1000;
        let mut p = Profile::new(TICK_US, lim);
        p.move_to(d);
        let mut n = 0u32;
        while !p.is_settled() && n < 100_000 {
            p.tick();
            n += 1;
        }
        let (vmax, acc, dec) = p.internal_limits();
        let q = (1u64 << 32) as f64;
        let (vmax, acc, dec) = (vmax as f64 / q, acc as f64 / q, dec as f64 / q);
        let t = analytic_ticks(d as f64, vmax, acc, dec);
        // A ramp corner that falls inside a tick costs up to a/8 of distance
        // (velocity is linear within a tick), i.e. a/(8·v_peak) ticks.
        let v_peak = peak_speed(d as f64, vmax, acc, dec);
        let corners = if v_peak > 0.0 { (acc + dec) / (8.0 * v_peak) } else { 0.0 };
        prop_assert!(f64::from(n) >= t - 1e-9, "{n} ticks faster than analytic {t}");
        prop_assert!(f64::from(n) <= t + 1.0 + corners + 1e-9, "{n} ticks vs analytic {t} (+{corners})");
    }

    #[test]
    fn lowering_the_deceleration_mid_move_never_passes_the_target(
        lim in limits(), frac in 1u32..=3000, neg in any::<bool>(), at in 0u32..4000, div in 2u32..1000,
    ) {
        let d = i64::from(lim.max_speed) * i64::from(frac) / 1000;
        let target = if neg { -d } else { d };
        let mut p = Profile::new(TICK_US, lim);
        p.move_to(target);
        let mut v = 0;
        for _ in 0..at {
            if p.is_settled() { break; }
            v = tick_checked(&mut p, v)?;
        }
        p.set_limits(Limits { dec: (lim.dec / div).max(1), ..lim });
        let goal = i128::from(target) << 33;
        for _ in 0..2_000_000 {
            if p.is_settled() { break; }
            v = tick_checked(&mut p, v)?;
            if neg {
                prop_assert!(p.position_fine() >= goal, "passed the target");
            } else {
                prop_assert!(p.position_fine() <= goal, "passed the target");
            }
        }
        prop_assert_eq!(p.position_fine(), goal);
    }

    #[test]
    fn retargeting_sequences_keep_all_limits_and_finally_land(
        (first, events, last) in max_speed().prop_flat_map(|v| {
            let span = i64::from(v) * 3;
            (
                limits_near(v),
                proptest::collection::vec((1u32..400, 0u8..5, -span..span, limits_near(v)), 1..8),
                -span..span,
            )
        }),
    ) {
        let mut p = Profile::new(TICK_US, first);
        p.move_to(last / 2);
        let mut v = 0;
        for (after, kind, arg, lim) in events {
            for _ in 0..after {
                v = tick_checked(&mut p, v)?;
            }
            match kind {
                0 => p.move_to(arg),
                1 => p.run_at((arg / 4) as i32),
                2 => p.set_limits(lim),
                3 => p.soft_stop(),
                _ => { p.move_to(arg); p.set_limits(lim); }
            }
        }
        p.move_to(last);
        let mut n = 0;
        while !p.is_settled() {
            v = tick_checked(&mut p, v)?;
            n += 1;
            prop_assert!(n < 2_000_000, "did not settle");
        }
        prop_assert_eq!(p.position_fine(), i128::from(last) << 33);
    }
}
