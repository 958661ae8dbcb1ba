//! `cargo xtask tick-cpu`: the control tick of 8 axes against simulated
//! chips (`firmware/armcount-bench`'s `tick-armcount`), two workloads:
//! *cruise* (every axis streaming a long move far from its target, every
//! tick the same: counters 1–3) and *moves* (every axis moving 40 000
//! logical steps back and forth: ramps, braking, the stop and the landing,
//! the next move's start; counters 6–8), with each part's largest count in
//! any one tick (the plugin's epochs) for the worst tick.

use super::*;

/// Ticks of each workload, and profile ticks (the counts are divided by it).
const N: f64 = 20_000.0;

/// The image's markers: counters 1–3 the cruise tick's parts, 4 the profile
/// generator, 5 the calibration, 6–8 the moves tick's parts, 9–11 the
/// coordinated tick's.
const RUN: Run = Run {
    image: Image::Bench("tick-armcount", &["sim"]),
    marks: &[
        "armcost_mark_off",
        "armcost_mark_prepare",
        "armcost_mark_run",
        "armcost_mark_finish",
        "armcost_mark_profile",
        "armcost_mark_cal",
        "armcost_mark_prepare2",
        "armcost_mark_run2",
        "armcost_mark_finish2",
        "armcost_mark_prepare3",
        "armcost_mark_run3",
        "armcost_mark_finish3",
    ],
    dump: "armcost_mark_dump",
    epoch: Some("armcost_epoch"),
    out: "tick.out",
};

/// Counters 1–5.
const NAMES: [&str; 5] = [
    "prepare (plan + profile generator + schedule/encode)",
    "begin + clock minus bus windows (window loop)",
    "tick_end (decode + absorb replies)",
    "profile mode: one Profile::tick",
    "calibration: empty marker pair",
];

/// `cargo xtask tick-cpu`.
pub fn tick_cpu(args: &[String]) -> Result {
    let (d, c) = Armcount::new()?.run(&RUN, true)?;
    println!("N = {N} ticks; Thumb-2 instructions per tick (per call for counters 4 and 5)\n");
    let s: Vec<Stats> = (1..=5).map(|k| stats(&d, &c, k, N)).collect();
    for (k, (name, st)) in NAMES.iter().zip(&s).enumerate() {
        print_counter(k + 1, name, st);
    }
    let [prepare, run, finish, profile, _cal] = &s[..] else {
        bail!("five counters expected");
    };
    let tick = [prepare, run, finish];
    summary(&tick, profile);
    let total = cruise_results(&c, &tick, profile);
    let moves: Vec<Stats> = (6..=8).map(|k| stats(&d, &c, k, N)).collect();
    let (m_cyc, w_cyc) = moves_results(&c, &s, &moves);
    let coord: Vec<Stats> = (9..=11).map(|k| stats(&d, &c, k, N)).collect();
    let c_cyc = coord_results(&c, &coord, total);
    // Where issue 22 started (a5b142a, this bench's cruise workload, code
    // in flash), to compare with the lines above (docs/performance.md).
    println!(
        "RESULT before (a5b142a, 1 kHz build, cruise): 9285 instructions per tick, 1161 per axis-tick, 0 64-bit divisions, ART misses 1030 + 239, cycles 13472 + 3768 flash wait = 17240, CPU 10.3 / 20.5 / 51.3 / 102.6 % at 1 / 2 / 5 / 10 kHz"
    );
    let name = if tick_hz() >= 5000 {
        "TICK_CYCLES_8_AXES_5KHZ"
    } else {
        "TICK_CYCLES_8_AXES_1KHZ"
    };
    // The fit takes the worst tick (every axis starting at once, alone or
    // in a coordinated move: the epoch maximum covers all three
    // workloads), so that a chain it fits holds every tick, not only the
    // mean one.
    cost::check(
        name,
        total.max(m_cyc).max(w_cyc).max(c_cyc),
        write_flag(args),
    )
}

/// The coordinated workload's RESULT line (beside the single-axis cruise
/// tick, `cruise_cycles`): its mean cycles per tick (its worst single tick
/// is in the worst-tick line, which covers every workload).
fn coord_results(c: &Counts, coord: &[Stats], cruise_cycles: f64) -> f64 {
    let (insn, cyc, parts) = workload(c, coord, 9);
    println!(
        "RESULT coordinated workload (8 axes in one straight-line move, led every tick): {insn:.0} instructions per tick, {:.0} per axis-tick ({:.2} x the single-axis cruise tick's cycles); {cyc:.0} cycles, CPU share at 5 kHz {:.1} %; each part's largest summed {parts:.0} instructions",
        insn / 8.0,
        cyc / cruise_cycles.max(1.0),
        share(cyc, 5000),
    );
    cyc
}

/// ART misses per tick of the three parts, warm and cold, each as
/// (sequential, jumps).
fn art_misses(tick: &[&Stats; 3]) -> ((f64, f64), (f64, f64)) {
    let warm = tick
        .iter()
        .fold((0.0, 0.0), |a, t| (a.0 + t.warm.0, a.1 + t.warm.1));
    let cold = tick
        .iter()
        .fold((0.0, 0.0), |a, t| (a.0 + t.cold.0, a.1 + t.cold.1));
    (warm, cold)
}

/// The SUMMARY lines: the whole cruise tick (callgrind's scope, then with
/// the window loop), its cycles at each model and ART misses, and the
/// profile generator.
fn summary(tick: &[&Stats; 3], profile: &Stats) {
    let [prepare, run, finish] = *tick;
    let pf = prepare.net + finish.net;
    let insn: f64 = tick.iter().map(|t| t.net).sum();
    println!(
        "SUMMARY whole 8-axis tick: prepare+tick_end (callgrind's scope) {pf:.0} insns ({:.0}/axis); + the window loop {insn:.0} ({:.0}/axis)",
        pf / 8.0,
        insn / 8.0
    );
    for (i, (name, _)) in cycles::MODELS.iter().enumerate() {
        let c1 = prepare.cycles[i] + finish.cycles[i];
        println!(
            "  cycles ({name}): prepare+tick_end {c1:.0}; with the window loop {:.0}",
            c1 + run.cycles[i]
        );
    }
    let (warm, cold) = art_misses(tick);
    println!(
        "  ART misses/tick (counters 1-3): warm {:.0} seq + {:.0} jump; cold {:.0} seq + {:.0} jump",
        warm.0, warm.1, cold.0, cold.1
    );
    println!(
        "SUMMARY profile generator: {:.0} insns/axis-tick, cycles {:.0} / {:.0} / {:.0}",
        profile.net, profile.cycles[0], profile.cycles[1], profile.cycles[2]
    );
    println!();
}

/// The cruise workload's RESULT lines (instructions, division calls, ART
/// misses, cycles, what ran from SRAM, CPU shares): its cycles per tick.
fn cruise_results(c: &Counts, tick: &[&Stats; 3], profile: &Stats) -> f64 {
    let insn: f64 = tick.iter().map(|t| t.net).sum();
    let div: f64 = tick
        .iter()
        .flat_map(|t| t.calls.iter())
        .filter(|(f, _)| f.starts_with("__aeabi_"))
        .map(|(_, c)| c)
        .sum::<f64>()
        .max(0.0);
    let core: f64 = tick.iter().map(|t| t.cycles[1]).sum();
    let flash: f64 = tick.iter().map(|t| t.flash_wait()).sum();
    let total = core + flash;
    let tick_us = 1_000_000 / tick_hz().max(1);
    let (warm, cold) = art_misses(tick);
    println!(
        "RESULT tick {tick_us} us, 8 axes: {insn:.0} Thumb-2 instructions per tick, {:.0} per axis-tick; 64-bit division calls per tick: {div:.2}",
        insn / 8.0
    );
    println!(
        "RESULT profile generator: {:.0} instructions per axis-tick",
        profile.net
    );
    println!(
        "RESULT ART misses per tick (64 x 16 B, LRU, the tick's code alone): {:.0} sequential + {:.0} jumps; with the simulated chips' code in between: {:.0} + {:.0}",
        warm.0, warm.1, cold.0, cold.1
    );
    println!(
        "RESULT cycles per tick: {core:.0} core + {flash:.0} flash wait = {total:.0} ({WAIT_STATES} wait states; 0 wait states: {core:.0})"
    );
    // memory.x's `.ramtext`: what of the tick ran from SRAM (no ART, no
    // wait states; fetches share the S-bus with data, not modelled).
    let ram = c
        .pcs
        .iter()
        .filter(|p| (1..=3).contains(&p.counter) && p.pc >= 0x2000_0000)
        .map(|p| p.count)
        .sum::<u64>() as f64
        / N;
    println!(
        "RESULT run from SRAM: {ram:.0} of the {:.0} instructions per tick",
        tick.iter().map(|t| t.raw).sum::<f64>()
    );
    for hz in RATES_HZ {
        println!(
            "RESULT CPU share of the tick's computation at {} kHz: {:.1} %",
            hz / 1000,
            share(total, hz)
        );
    }
    total
}

/// The moves workload's RESULT line and the worst tick's, from the cruise
/// counters 1–5 and the moves ones 6–8: the moves' cycles per tick and the
/// worst tick's.
fn moves_results(c: &Counts, cruise: &[Stats], moves: &[Stats]) -> (f64, f64) {
    let (m_insn, m_cyc, worst) = workload(c, moves, 6);
    let (_, _, c_worst) = workload(c, &cruise[..3], 1);
    println!(
        "RESULT moves workload (8 axes back and forth: ramps, braking, landing, starts): {m_insn:.0} instructions per tick, {:.0} per axis-tick; {m_cyc:.0} cycles",
        m_insn / 8.0
    );
    // The worst single tick (all of its parts in one tick, the plugin's
    // epoch total), less the markers' share (the smaller of the two
    // workloads'); the sum of each part's largest, from different ticks,
    // bounds it from above.
    let overhead = |ks: &[usize]| -> f64 {
        ks.iter()
            .filter_map(|k| cruise.get(k - 1).or_else(|| moves.get(k - 6)))
            .map(|t| t.raw - t.net)
            .sum::<f64>()
    };
    let markers = overhead(&[1, 2, 3, 5]).min(overhead(&[6, 7, 8]));
    let bound = worst.max(c_worst);
    let (w, at) = match c.epoch_max {
        Some((max, at)) => ((max as f64 - markers).max(0.0), at),
        None => (bound, 0),
    };
    let w_cyc = w * m_cyc / m_insn.max(1.0);
    println!(
        "RESULT worst tick: {w:.0} instructions ({:.0} per axis-tick; tick {at} of the bench, {}), ~{w_cyc:.0} cycles, CPU share at 5 kHz {:.1} %; each part's largest summed: cruise {c_worst:.0}, moves {worst:.0}",
        w / 8.0,
        // (Epochs count from 0: the ticks of each workload in turn.)
        match at {
            a if a < N as u64 => "cruise",
            a if a < 2 * N as u64 => "moves",
            _ => "coordinated",
        },
        share(w_cyc, 5000)
    );
    (m_cyc, w_cyc)
}

/// Per tick of a workload whose three parts are counters `first`..: the
/// mean net instructions and cycles (0 wait states: the tick runs from
/// SRAM) and the worst tick's instructions (each part's largest count in
/// one tick less its markers' share, summed: an upper bound).
fn workload(c: &Counts, parts: &[Stats], first: usize) -> (f64, f64, f64) {
    let insn: f64 = parts.iter().map(|t| t.net).sum();
    let cyc: f64 = parts.iter().map(|t| t.cycles[1] + t.flash_wait()).sum();
    let worst: f64 = parts
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let max = c.totals.get(&(first + i)).map_or(0, |x| x.epoch_max) as f64;
            (max - (t.raw - t.net)).max(0.0)
        })
        .sum();
    (insn, cyc, worst)
}
