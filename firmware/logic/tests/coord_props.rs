//! Property tests of the coordinated line (`motion::coord`), with an oracle
//! of their own: every check below is made from the axes' reported
//! positions only, never from the line's path parameter or its limits.
//!
//! For random groups (1–8 axes, zero, tiny and > 2²¹-step components,
//! mixed limits, 1, 2 and 5 kHz ticks), at every tick:
//! * every axis is within one step of the straight line (taken through the
//!   farthest-travelling axis's own position);
//! * no axis's speed or acceleration, measured from its positions, exceeds
//!   its own limits;
//!
//! and every moving axis reaches its target in the same tick, exactly.

#![allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use bridge_logic::motion::coord::{junction_speed, plan_speeds, CoordError, Line, Segment};
use bridge_logic::motion::Limits;
use proptest::prelude::*;

/// 2⁻³³ steps per step (the positions' fine unit).
const FINE: i128 = 1 << 33;

/// A component: mostly zero, tiny or beyond 2²¹ steps.
fn component() -> impl Strategy<Value = i64> {
    prop_oneof![
        Just(0i64),
        -10i64..=10,
        -50_000i64..=50_000,
        (1i64 << 21)..(1i64 << 23),
        -(1i64 << 23)..-(1i64 << 21),
    ]
}

/// Limits that keep a move of 2²³ steps under a minute of ticks.
fn limits() -> impl Strategy<Value = Limits> {
    (200_000u32..4_000_000, 1u32..100, 1u32..100).prop_map(|(v, a, d)| Limits {
        max_speed: v,
        acc: v.saturating_mul(a) / 4,
        dec: v.saturating_mul(d) / 4,
    })
}

fn group() -> impl Strategy<Value = Vec<(i64, i64, Limits)>> {
    prop::collection::vec((-(1i64 << 30)..(1i64 << 30), component(), limits()), 1..=8)
}

/// The path limits asked for: none, or a real cap.
fn path() -> impl Strategy<Value = Limits> {
    prop_oneof![
        Just(Limits {
            max_speed: u32::MAX,
            acc: u32::MAX,
            dec: u32::MAX
        }),
        limits(),
    ]
}

fn tick_us() -> impl Strategy<Value = u32> {
    prop_oneof![Just(1000u32), Just(500), Just(200)]
}

/// `|x| · scale ≤ bound · FINE + slack · scale`, in exact integers.
fn within(x: i128, scale: i128, bound: i128, slack: i128) -> bool {
    x.abs() * scale <= bound * FINE + slack * scale
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn a_coordinated_line_stays_on_the_line_within_every_axis_s_limits_and_arrives_in_one_tick(
        axes in group(),
        path in path(),
        tick in tick_us(),
    ) {
        let start: Vec<i64> = axes.iter().map(|a| a.0).collect();
        let target: Vec<i64> = axes.iter().map(|a| a.0 + a.1).collect();
        let limits: Vec<Limits> = axes.iter().map(|a| a.2).collect();
        let n = axes.len();
        let mut line = Line::new(tick, &start, &target, &limits, path).unwrap();
        let d: Vec<i128> = axes.iter().map(|a| i128::from(a.1)).collect();
        let length = d.iter().map(|x| x.abs()).max().unwrap();
        let far = d.iter().position(|x| x.abs() == length).unwrap();
        let t = i128::from(tick);
        let fine = |line: &Line| (0..n).map(|k| line.position_fine(k).unwrap()).collect::<Vec<_>>();
        let mut prev = fine(&line);
        let mut prev_step: Vec<i128> = vec![0; n];
        let mut arrived: Vec<Option<u32>> = vec![None; n];
        // Ticks enough to finish (a bound, not a check): the path's
        // distance at its speed plus a ramp each way, twice over.
        let pl = line.path_limits();
        let us = length.unsigned_abs() as u64 * 1_000_000 / u64::from(pl.max_speed)
            + 2 * u64::from(pl.max_speed) * 1_000_000 / u64::from(pl.acc.min(pl.dec).max(1));
        let cap = 2 * us / u64::from(tick) + 100;
        for tick_no in 1..=u32::try_from(cap).unwrap() {
            if line.is_done() {
                break;
            }
            line.tick();
            let now = fine(&line);
            let p: Vec<i128> = (0..n).map(|k| i128::from(line.position(k).unwrap())).collect();
            for k in 0..n {
                let a = i128::from(start[k]);
                // On the line through the farthest axis's own position.
                let off = (p[k] - a) * d[far] - d[k] * (p[far] - i128::from(start[far]));
                prop_assert!(off.abs() <= length.max(1), "axis {k} off the line at tick {tick_no}");
                // Speed and acceleration from positions (2⁻³³ steps per tick):
                // v ≤ vmax · tick · 2³³ / 10⁶, Δv ≤ max(acc, dec) · tick² · 2³³ / 10¹²,
                // with a few 2⁻³³ of truncation and the one-quantum minimum.
                let step = now[k] - prev[k];
                let lim = limits[k];
                prop_assert!(
                    within(step, 1_000_000, i128::from(lim.max_speed) * t, 2),
                    "axis {k} too fast at tick {tick_no}: {step}"
                );
                let acc = i128::from(lim.acc.max(lim.dec));
                prop_assert!(
                    within(step - prev_step[k], 1_000_000_000_000, acc * t * t, 8),
                    "axis {k} accelerates too hard at tick {tick_no}"
                );
                prev_step[k] = step;
                // Direction: never backwards along the line.
                prop_assert!(step * d[k] >= 0, "axis {k} moved backwards");
                if arrived[k].is_none() && d[k] != 0 && now[k] == i128::from(target[k]) * FINE {
                    arrived[k] = Some(tick_no);
                }
            }
            prev = now;
        }
        prop_assert!(line.is_done(), "not done");
        for (k, want) in target.iter().enumerate() {
            prop_assert_eq!(line.position(k), Some(*want));
        }
        let ticks: Vec<u32> = arrived.iter().flatten().copied().collect();
        prop_assert!(ticks.windows(2).all(|w| w[0] == w[1]), "arrivals {ticks:?}");
        prop_assert_eq!(ticks.len(), d.iter().filter(|x| **x != 0).count());
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn the_junction_speed_is_the_highest_at_which_no_axis_jumps_more_than_one_tick_of_acceleration(
        segs in prop::collection::vec((component(), component(), limits()), 1..=8),
        tick in tick_us(),
    ) {
        let a: Vec<i64> = segs.iter().map(|s| s.0).collect();
        let b: Vec<i64> = segs.iter().map(|s| s.1).collect();
        let lim: Vec<Limits> = segs.iter().map(|s| s.2).collect();
        let v = junction_speed(&a, &b, &lim, tick).unwrap();
        let la = a.iter().map(|x| i128::from(x.unsigned_abs())).max().unwrap();
        let lb = b.iter().map(|x| i128::from(x.unsigned_abs())).max().unwrap();
        if la == 0 || lb == 0 {
            prop_assert_eq!(v, 0);
            return Ok(());
        }
        // Axis i's jump at speed s, in steps/s, is s·|aᵢ/la − bᵢ/lb|; one
        // tick of acceleration is min(acc, dec)·tick/10⁶. Exact, scaled by
        // la·lb·10⁶.
        let fits = |s: i128| {
            (0..a.len()).all(|i| {
                let jump = (i128::from(a[i]) * lb - i128::from(b[i]) * la).abs();
                let allowed = i128::from(lim[i].acc.max(1).min(lim[i].dec.max(1)));
                s * jump * 1_000_000 <= allowed * i128::from(tick) * la * lb
            })
        };
        prop_assert!(fits(i128::from(v)), "v = {v} makes an axis jump too far");
        if v < u32::MAX {
            prop_assert!(!fits(i128::from(v) + 1), "v = {v} is not the highest");
        }
    }
}

fn segment() -> impl Strategy<Value = Segment> {
    (
        prop_oneof![1u64..100, 100u64..100_000, (1u64 << 21)..(1u64 << 32)],
        limits(),
        prop_oneof![Just(u32::MAX), 0u32..5_000_000],
    )
        .prop_map(|(length, limits, junction)| Segment {
            length,
            limits,
            junction,
        })
}

/// v² ≤ u² + 2·rate·length (continuous kinematics, exact).
fn reachable(u: u32, v: u32, rate: u32, length: u64) -> bool {
    let (u, v) = (u128::from(u), u128::from(v));
    v * v <= u * u + 2 * u128::from(rate.max(1)) * u128::from(length)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn the_look_ahead_stops_on_the_last_waypoint_within_every_limit_and_as_fast_as_they_allow(
        segs in prop::collection::vec(segment(), 1..=16),
        start in prop_oneof![Just(0u32), 0u32..4_000, 0u32..4_000_000],
    ) {
        let n = segs.len();
        let mut out = [0u32; 17];
        let got = plan_speeds(start, &segs, &mut out);
        // Independent of the planner's backward pass: braking as hard as
        // every segment allows from `start` gives the lowest speed the path
        // can have at each waypoint; the start is possible iff that never
        // exceeds a waypoint's cap (its junction and both segments' max
        // speeds, 0 at the end) nor the first segment's max speed.
        let possible = |start: u32| {
            let mut u2 = u128::from(start).pow(2);
            if start > segs[0].limits.max_speed.max(1) {
                return false;
            }
            for k in 0..n {
                let s = segs[k];
                u2 = u2.saturating_sub(2 * u128::from(s.limits.dec.max(1)) * u128::from(s.length));
                let cap = match segs.get(k + 1) {
                    Some(next) => next.junction.min(next.limits.max_speed.max(1)).min(s.limits.max_speed.max(1)),
                    None => 0,
                };
                if u2 > u128::from(cap).pow(2) {
                    return false;
                }
            }
            true
        };
        if got.is_err() {
            // Refused: impossible, or within the planner's rounding (under
            // 1 step/s per segment) of impossible.
            prop_assert_eq!(got, Err(CoordError::CannotStop));
            prop_assert!(!possible(start.saturating_add(n as u32 + 1)), "a possible start refused");
            return Ok(());
        }
        prop_assert!(possible(start));
        let v = &out[..=n];
        prop_assert_eq!(v[0], start);
        prop_assert_eq!(v[n], 0);
        for k in 0..n {
            let s = segs[k];
            prop_assert!(reachable(v[k], v[k + 1], s.limits.acc, s.length), "segment {k} cannot reach its exit");
            prop_assert!(reachable(v[k + 1], v[k], s.limits.dec, s.length), "segment {k} cannot brake to its exit");
            prop_assert!(v[k] <= s.limits.max_speed.max(1) && v[k + 1] <= s.limits.max_speed.max(1));
            if k > 0 {
                prop_assert!(v[k] <= s.junction, "junction {k} taken too fast");
            }
        }
        // As fast as allowed: every interior waypoint is at a cap, or one
        // more step/s would break braking to the next or reaching from the
        // one before.
        for k in 1..n {
            let up = v[k] + 1;
            let capped = v[k] == segs[k].junction.min(segs[k].limits.max_speed.max(1)).min(segs[k - 1].limits.max_speed.max(1));
            let forward = !reachable(v[k - 1], up, segs[k - 1].limits.acc, segs[k - 1].length);
            let backward = !reachable(v[k + 1], up, segs[k].limits.dec, segs[k].length);
            prop_assert!(capped || forward || backward, "waypoint {k} could go faster");
        }
    }
}
