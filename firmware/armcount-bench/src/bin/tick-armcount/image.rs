use bridge_logic::motion::{Axis, AxisConfig, AxisGroup, Limits, Profile};
use bridge_logic::powerstep::chain::{Chain, ChainBus, Replies};
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

macro_rules! marker {
    ($name:ident, $v:expr) => {
        #[inline(never)]
        #[no_mangle]
        pub extern "C" fn $name() {
            black_box($v as u32);
        }
    };
}
marker!(armcost_mark_off, 0x1111_0000u32);
marker!(armcost_mark_prepare, 0x2222_0001u32);
marker!(armcost_mark_run, 0x3333_0002u32);
marker!(armcost_mark_finish, 0x4444_0003u32);
marker!(armcost_mark_profile, 0x5555_0004u32);
marker!(armcost_mark_cal, 0x6666_0005u32);
marker!(armcost_mark_dump, 0x7777_0006u32);

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    semihosting::process::exit(1)
}

/// The simulated chain with the counting paused while a window is on the
/// (simulated) wire: what is left of `run_into` is the CPU's part.
struct Bus {
    sim: SimChain,
    counting: bool,
}

impl ChainBus for Bus {
    type Error = core::convert::Infallible;
    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), Self::Error> {
        if self.counting {
            armcost_mark_off();
        }
        let r = self.sim.window(tx, rx);
        if self.counting {
            armcost_mark_run();
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

#[entry]
fn main() -> ! {
    let mut chain = Chain::new(Bus {
        sim: SimChain::new(8),
        counting: false,
    });
    if chain.detect() != Ok(8) {
        semihosting::process::exit(2)
    }
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
    let tick_ns = u64::from(TICK_US) * 1000;
    let mut replies = Replies::default();
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
    chain.bus_mut().counting = true;
    for _ in 0..N {
        armcost_mark_prepare();
        let plan = group.prepare().ok();
        armcost_mark_off();
        let ran = if let Some(plan) = plan {
            armcost_mark_run();
            let r = chain.run_into(black_box(plan), &mut replies);
            armcost_mark_off();
            if r.is_err() {
                replies = Replies::default();
            }
            true
        } else {
            false
        };
        if ran {
            armcost_mark_finish();
            group.finish(black_box(&replies));
            armcost_mark_off();
        }
        chain.bus_mut().sim.advance(tick_ns);
        armcost_mark_cal();
        armcost_mark_off();
    }
    chain.bus_mut().counting = false;
    let mut p = Profile::new(TICK_US, limits());
    p.move_to(1 << 40);
    let mut acc = 0i64;
    for _ in 0..NP {
        armcost_mark_profile();
        acc = acc.wrapping_add(p.tick());
        armcost_mark_off();
    }
    black_box(acc);
    armcost_mark_dump();
    semihosting::process::exit(0)
}
