//! Instruction-count benchmark of the control tick (run under callgrind by
//! `cargo xtask bench`; not a timed test).
//!
//! `bench-tick profile N`: N ticks of one profile generator in a long move.
//! `bench-tick group N`: N ticks of 8 axes streaming against 8 simulated
//! powerSTEP01s. Only the bridge's own work is in the functions callgrind
//! collects (`bench_profile_tick`, `bench_prepare`, `bench_finish`); the
//! simulated SPI transfer and chip physics are outside them.

use bridge_logic::motion::{Axis, AxisConfig, AxisGroup, Limits, Profile};
use bridge_logic::powerstep::chain::{Chain, Frames, Plan, MAX_DEVICES, MAX_WINDOWS};
use bridge_logic::powerstep::{DriveMode, StepSel};
use host_tests::clock::{SimClock, SimControl};
use stepbridge_sim::SimChain;

const TICK_US: u32 = 1000;

#[inline(never)]
fn bench_profile_tick(p: &mut Profile) -> i64 {
    p.tick()
}

#[inline(never)]
fn bench_prepare(g: &mut AxisGroup) -> Option<&Plan> {
    g.prepare().ok()
}

/// Decode what came back and absorb it (the firmware's `tick_end`).
#[inline(never)]
fn bench_finish(g: &mut AxisGroup, chain: &mut Chain<SimChain>, rx: &Frames) {
    let _ = g.tick_end(chain, Ok(rx));
}

/// The 8-axis group on its chain; each control tick's own work is in the
/// `bench_*` functions callgrind collects.
struct Bench {
    group: AxisGroup,
    chain: Chain<SimChain>,
    /// Measured ticks go through the `bench_*` functions; set-up ticks not.
    measure: bool,
    /// Windows per tick → ticks.
    histogram: std::collections::BTreeMap<usize, u32>,
}

impl SimControl for Bench {
    fn control_tick(&mut self, _now_ms: u64) {
        if !self.measure {
            let _ = self.group.tick(&mut self.chain);
            return;
        }
        let Some(plan) = bench_prepare(&mut self.group) else {
            return;
        };
        *self.histogram.entry(plan.windows()).or_default() += 1;
        let mut rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];
        let plan = self.group.plan();
        if self.chain.begin(plan).is_err() || self.chain.clock(plan, &mut rx).is_err() {
            return;
        }
        bench_finish(&mut self.group, &mut self.chain, &rx);
    }
    fn chips(&mut self) -> &mut SimChain {
        self.chain.bus_mut()
    }
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
            let mut bench = Bench {
                group,
                chain,
                measure: false,
                histogram: Default::default(),
            };
            let mut clock = SimClock::new(TICK_US);
            // Configure the chips and start a long move on every axis (not measured).
            clock.run(&mut bench, 10);
            for k in 0..8 {
                if let Some(a) = bench.group.axis_mut(k) {
                    a.move_to(if k % 2 == 0 { 1 << 30 } else { -(1 << 30) });
                }
            }
            bench.measure = true;
            clock.run(&mut bench, u64::from(n));
            let h: Vec<String> = bench
                .histogram
                .iter()
                .map(|(w, c)| format!("{w} windows ({} bytes): {c} ticks", w * 8))
                .collect();
            println!("group: {n} ticks of 8 axes streaming; {}", h.join(", "));
        }
    }
}
