use armcount_bench::marker;
use bridge_logic::motion::{Axis, AxisConfig, AxisGroup, Limits, Profile};
use bridge_logic::powerstep::chain::{
    Chain, ChainBus, ChainError, Frames, MAX_DEVICES, MAX_WINDOWS,
};
use bridge_logic::powerstep::{DriveMode, StepSel};
use core::hint::black_box;
use cortex_m_rt::entry;
use stepbridge_sim::SimChain;

/// Control period, µs: the firmware's build setting `STEPBRIDGE_TICK_HZ`.
const TICK_US: u32 = bridge_logic::rate::TICK_US;

/// Measured ticks of the 8-axis group (xtask divides by it).
const N: u32 = 20_000;
/// Measured profile ticks.
const NP: u32 = N;

marker!(armcost_mark_off, 0x1111_0000u32);
marker!(armcost_mark_prepare, 0x2222_0001u32);
marker!(armcost_mark_run, 0x3333_0002u32);
marker!(armcost_mark_finish, 0x4444_0003u32);
marker!(armcost_mark_profile, 0x5555_0004u32);
marker!(armcost_mark_cal, 0x6666_0005u32);
marker!(armcost_mark_dump, 0x7777_0006u32);
marker!(armcost_mark_prepare2, 0x2222_0007u32);
marker!(armcost_mark_run2, 0x3333_0008u32);
marker!(armcost_mark_finish2, 0x4444_0009u32);
marker!(armcost_mark_prepare3, 0x2222_000Bu32);
marker!(armcost_mark_run3, 0x3333_000Cu32);
marker!(armcost_mark_finish3, 0x4444_000Du32);
// Not a counter: ends a tick (the plugin's `epoch`), run while counting is off.
marker!(armcost_epoch, 0x8888_000Au32);

/// The simulated chain with the counting paused while a window is on the
/// (simulated) wire: what is left of `run_into` is the CPU's part.
struct Bus {
    sim: SimChain,
    counting: bool,
    /// The marker that resumes the run counter after a window.
    resume: extern "C" fn(),
}

impl ChainBus for Bus {
    type Error = core::convert::Infallible;
    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), Self::Error> {
        if self.counting {
            armcost_mark_off();
        }
        let r = self.sim.window(tx, rx);
        if self.counting {
            (self.resume)();
        }
        r
    }
}

fn limits() -> Limits {
    Limits {
        max_speed: 400_000,
        acc: 200_000,
        dec: 200_000,
    }
}

/// One tick's three counted regions.
struct Marks {
    prepare: extern "C" fn(),
    run: extern "C" fn(),
    finish: extern "C" fn(),
}

/// One control tick through the blocking chain, as the firmware's tick in
/// a row runs it, each region between its marker and `armcost_mark_off`:
/// the plan, the windows (begin and clock), the decoding and absorbing of
/// what came back; then the simulated chips' time.
fn tick(group: &mut AxisGroup, chain: &mut Chain<Bus>, m: &Marks, tick_ns: u64) {
    (m.prepare)();
    let planned = group.prepare().is_ok();
    armcost_mark_off();
    if planned {
        (m.run)();
        let mut rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];
        let plan = group.plan();
        let r = chain
            .begin(black_box(plan))
            .map(|()| chain.clock(plan, &mut rx));
        armcost_mark_off();
        (m.finish)();
        let rx = match r {
            Ok(Ok(())) => Ok(black_box(&rx)),
            Ok(Err(e)) | Err(ChainError::Bus(e)) => Err(e),
            // Not on this chain (it is detected and fits): nothing to absorb.
            Err(_) => return,
        };
        let _ = group.tick_end(chain, rx);
        armcost_mark_off();
    }
    chain.bus_mut().sim.advance(tick_ns);
}

/// The chain of 8 simulated chips, detected (exit status 2 otherwise); its
/// bus counts nothing until a workload starts.
fn detected_chain() -> Chain<Bus> {
    let mut chain = Chain::new(Bus {
        sim: SimChain::new(8),
        counting: false,
        resume: armcost_mark_run,
    });
    if chain.detect() != Ok(8) {
        semihosting::process::exit(2)
    }
    chain
}

/// 8 axes, logical step modes 1/1 … 1/256 on 1/128 chips (exit status 3
/// if the group refuses one).
fn axis_group() -> AxisGroup {
    let mut group = AxisGroup::new();
    for k in 0..8u8 {
        let cfg = AxisConfig {
            tick_us: TICK_US,
            logical_shift: k % 9,
            step: StepSel::OneTwentyEighth,
            drive: DriveMode::Voltage,
        };
        if group.push(Axis::new(cfg, limits())).is_err() {
            semihosting::process::exit(3)
        }
    }
    // The batches' window budget the firmware gives 8 chips at this build's
    // rate (`rate::fit`: 5 windows at 5 kHz, where the overlapped tick
    // runs; no limit at 1 kHz).
    let rate = bridge_logic::rate::fit(bridge_logic::rate::TICK_HZ, 8);
    group.set_window_budget(usize::from(rate.windows));
    group
}

/// `N` measured ticks, each region counted by `marks` (the run counter
/// resumed after each window), `before` run ahead of each (not counted),
/// the calibration pair after each if `calibrate`.
fn measured(
    group: &mut AxisGroup,
    chain: &mut Chain<Bus>,
    marks: &Marks,
    tick_ns: u64,
    calibrate: bool,
    mut before: impl FnMut(&mut AxisGroup),
) {
    let bus = chain.bus_mut();
    bus.resume = marks.run;
    bus.counting = true;
    for _ in 0..N {
        before(group);
        tick(group, chain, marks, tick_ns);
        if calibrate {
            armcost_mark_cal();
        }
        armcost_mark_off();
        armcost_epoch();
    }
    chain.bus_mut().counting = false;
}

/// The cruise workload (counters 1–3, and 5 after each tick): every axis
/// streaming its long move, every tick the same.
fn cruise(group: &mut AxisGroup, chain: &mut Chain<Bus>, tick_ns: u64) {
    let marks = Marks {
        prepare: armcost_mark_prepare,
        run: armcost_mark_run,
        finish: armcost_mark_finish,
    };
    measured(group, chain, &marks, tick_ns, true, |_| {});
}

/// Stop every axis and wait until the group has settled (not measured).
fn stop_all(group: &mut AxisGroup, chain: &mut Chain<Bus>, tick_ns: u64) {
    for k in 0..8 {
        if let Some(a) = group.axis_mut(k) {
            a.soft_stop();
        }
    }
    for _ in 0..200_000 {
        if group.is_settled() {
            break;
        }
        let _ = group.tick(chain);
        chain.bus_mut().sim.advance(tick_ns);
    }
}

/// The moves workload (counters 6–8): every axis moves back and forth
/// (40 000 logical steps, a triangle profile: ramps, braking, stop and
/// landing, the next move's start), each starting when the last one has
/// landed.
fn moves(group: &mut AxisGroup, chain: &mut Chain<Bus>, tick_ns: u64) {
    let marks = Marks {
        prepare: armcost_mark_prepare2,
        run: armcost_mark_run2,
        finish: armcost_mark_finish2,
    };
    let mut out = [true; 8];
    measured(group, chain, &marks, tick_ns, false, |group| {
        for (k, o) in out.iter_mut().enumerate() {
            if let Some(a) = group.axis_mut(k) {
                if a.is_settled() {
                    let here = a.required_position();
                    a.move_to(if *o { here + 40_000 } else { here - 40_000 });
                    *o = !*o;
                }
            }
        }
    });
}

/// The coordinated workload (counters 9–11): the 8 axes in one
/// coordinated move (extension 0x08nn) far beyond `N` ticks, from its
/// start: every tick leads every axis along the line.
fn coordinated(group: &mut AxisGroup, chain: &mut Chain<Bus>, tick_ns: u64) {
    let members = [0, 1, 2, 3, 4, 5, 6, 7];
    let mut targets = [0i64; 8];
    for (k, t) in targets.iter_mut().enumerate() {
        let here = group.axis(k).map_or(0, |a| a.required_position());
        let d = (1i64 << 28) >> (k % 3);
        *t = if k % 2 == 0 { here + d } else { here - d };
    }
    let fast = Limits {
        max_speed: u32::MAX,
        acc: u32::MAX,
        dec: u32::MAX,
    };
    if group.coord_start(&members, &targets, fast).is_err() {
        semihosting::process::exit(4)
    }
    let marks = Marks {
        prepare: armcost_mark_prepare3,
        run: armcost_mark_run3,
        finish: armcost_mark_finish3,
    };
    measured(group, chain, &marks, tick_ns, false, |_| {});
}

/// Counter 4: `Profile::tick` of a long move, on its own.
fn profile_ticks() {
    let mut p = Profile::new(TICK_US, limits());
    p.move_to(1 << 40);
    let mut acc = 0i64;
    for _ in 0..NP {
        armcost_mark_profile();
        acc = acc.wrapping_add(p.tick());
        armcost_mark_off();
    }
    black_box(acc);
}

#[entry]
fn main() -> ! {
    let mut chain = detected_chain();
    let mut group = axis_group();
    let tick_ns = u64::from(TICK_US) * 1000;
    // Configure the chips and start a long move on every axis (not measured).
    for _ in 0..10 {
        let _ = group.tick(&mut chain);
        chain.bus_mut().sim.advance(tick_ns);
    }
    for k in 0..8 {
        if let Some(a) = group.axis_mut(k) {
            a.move_to(if k % 2 == 0 { 1 << 30 } else { -(1 << 30) });
        }
    }
    cruise(&mut group, &mut chain, tick_ns);
    stop_all(&mut group, &mut chain, tick_ns);
    moves(&mut group, &mut chain, tick_ns);
    stop_all(&mut group, &mut chain, tick_ns);
    coordinated(&mut group, &mut chain, tick_ns);
    profile_ticks();
    armcost_mark_dump();
    semihosting::process::exit(0)
}
