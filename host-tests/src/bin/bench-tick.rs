//! Instruction-count benchmark of the control tick (run under callgrind by
//! `scripts/bench`; not a timed test).
//!
//! `bench-tick profile N`: N ticks of one profile generator in a long move.
//! `bench-tick group N`: N ticks of 8 axes streaming against 8 simulated
//! powerSTEP01s. Only the bridge's own work is in the functions callgrind
//! collects (`bench_profile_tick`, `bench_prepare`, `bench_finish`); the
//! simulated SPI transfer and chip physics are outside them.

use bridge_logic::motion::{Axis, AxisConfig, AxisGroup, Limits, Profile};
use bridge_logic::powerstep::chain::{Chain, Plan, Replies};
use bridge_logic::powerstep::{DriveMode, StepSel};
use bridge_logic::sim::SimChain;

const TICK_US: u32 = 1000;

#[inline(never)]
fn bench_profile_tick(p: &mut Profile) -> i64 {
    p.tick()
}

#[inline(never)]
fn bench_prepare(g: &mut AxisGroup) -> Option<&Plan> {
    g.prepare().ok()
}

#[inline(never)]
fn bench_finish(g: &mut AxisGroup, r: &Replies) {
    g.finish(r)
}

fn limits() -> Limits {
    Limits {
        max_speed: 400_000,
        acc: 200_000,
        dec: 200_000,
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let mode = args.next().unwrap_or_else(|| "group".into());
    let n: u32 = args.next().and_then(|s| s.parse().ok()).unwrap_or(2000);
    match mode.as_str() {
        "profile" => {
            let mut p = Profile::new(TICK_US, limits());
            p.move_to(1 << 40);
            let mut acc = 0i64;
            for _ in 0..n {
                acc = acc.wrapping_add(bench_profile_tick(&mut p));
            }
            println!("profile: {n} ticks, v = {acc}");
        }
        _ => {
            let mut chain = Chain::new(SimChain::new(8));
            if chain.detect() != Ok(8) {
                eprintln!("bench-tick: chain detection failed");
                std::process::exit(1);
            }
            let mut group = AxisGroup::new();
            for k in 0..8u8 {
                let cfg = AxisConfig {
                    tick_us: TICK_US,
                    logical_shift: k % 9,
                    step: StepSel::OneTwentyEighth,
                    drive: DriveMode::Voltage,
                };
                let _ = group.push(Axis::new(cfg, limits()));
            }
            // Configure the chips and start a long move on every axis (not measured).
            for _ in 0..10 {
                let _ = group.tick(&mut chain);
                chain.bus_mut().advance(u64::from(TICK_US) * 1000);
            }
            for k in 0..8 {
                if let Some(a) = group.axis_mut(k) {
                    a.move_to(if k % 2 == 0 { 1 << 30 } else { -(1 << 30) });
                }
            }
            let mut histogram = std::collections::BTreeMap::<usize, u32>::new();
            let mut replies = Replies::default();
            for _ in 0..n {
                let Some(plan) = bench_prepare(&mut group) else {
                    break;
                };
                *histogram.entry(plan.windows()).or_default() += 1;
                if chain.run_into(plan, &mut replies).is_err() {
                    replies = Replies::default();
                }
                bench_finish(&mut group, &replies);
                chain.bus_mut().advance(u64::from(TICK_US) * 1000);
            }
            let h: Vec<String> = histogram
                .iter()
                .map(|(w, c)| format!("{w} windows ({} bytes): {c} ticks", w * 8))
                .collect();
            println!("group: {n} ticks of 8 axes streaming; {}", h.join(", "));
        }
    }
}
