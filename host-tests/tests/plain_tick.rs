//! The plain tick (`AxisGroup::prepare`: when every axis streams or rests,
//! each writes its read and its Run or SoftStop straight into the plan, no
//! batch) puts on the chain, tick for tick, what the general plan puts
//! there: two rigs run the same random commands, one with the shortcut
//! off, and every window, every chip and every axis's state stay the same.

use bridge_logic::motion::Limits;
use bridge_logic::powerstep::registers::Register;
use bridge_logic::powerstep::{DriveMode, StepSel};
use host_tests::rig::{config as cfg, Rig};
use host_tests::rng::Rng;

const TICK_US: u32 = bridge_logic::rate::TICK_US;

fn limits(v: u32, a: u32, d: u32) -> Limits {
    Limits {
        max_speed: v,
        acc: a,
        dec: d,
    }
}

/// Both rigs' windows, chips and axes agree after every tick.
fn assert_same(fast: &Rig, slow: &Rig, tick: u32) {
    let (a, b) = (fast.group.plan(), slow.group.plan());
    assert_eq!(a.windows(), b.windows(), "tick {tick}");
    for w in 0..a.windows() {
        assert_eq!(a.window(w), b.window(w), "tick {tick}, window {w}");
    }
    for k in 0..fast.group.len() {
        assert_eq!(
            fast.chain.bus().device(k).unwrap().abs_pos(),
            slow.chain.bus().device(k).unwrap().abs_pos(),
            "tick {tick}, chip {k}"
        );
        assert_eq!(
            format!("{:?}", fast.group.axis(k).unwrap()),
            format!("{:?}", slow.group.axis(k).unwrap()),
            "tick {tick}, axis {k}"
        );
    }
}

#[test]
fn a_plain_tick_puts_on_the_chain_what_the_batch_would() {
    let configs = [
        cfg(7, StepSel::OneTwentyEighth, DriveMode::Voltage),
        cfg(4, StepSel::OneTwentyEighth, DriveMode::Voltage),
        cfg(8, StepSel::Sixteenth, DriveMode::Current),
        cfg(0, StepSel::OneTwentyEighth, DriveMode::Voltage),
    ];
    let start = limits(4_000, 40_000, 40_000);
    let mut fast = Rig::new(&configs, start);
    let mut slow = Rig::new(&configs, start);
    slow.group.set_plain_shortcut(false);
    let mut rng = Rng(0x5eed_c401_5e00_0001);
    let ticks_per_s = 1_000_000 / TICK_US;
    let mut total = 0u32;
    for round in 0..60u32 {
        // The same command for both, on a random axis.
        let k = rng.below(configs.len() as u64) as usize;
        let what = rng.below(10);
        for rig in [&mut fast, &mut slow] {
            let mut r = Rng(rng.0 ^ u64::from(round));
            let axis = rig.axis(k);
            match what {
                0..=2 => axis.move_to(r.range(-400_000, 400_000)),
                // Short moves: they end (the SoftStop) within the round.
                3 | 4 => {
                    let here = axis.required_position();
                    axis.move_to(here + r.range(-3_000, 3_000));
                }
                5 => axis.run_at(r.range(-3_000, 3_000) as i32),
                6 => axis.set_limits(limits(
                    r.range(500, 6_000) as u32,
                    r.range(5_000, 80_000) as u32,
                    r.range(5_000, 80_000) as u32,
                )),
                7 => axis.soft_stop(),
                8 => {
                    // A changed register waits for a spare slot.
                    let _ = axis.set_register(Register::OcdTh, r.range(1, 31) as u32);
                }
                _ => {
                    let _ = axis.read_register(Register::Speed);
                }
            }
        }
        let _ = rng.next_u64();
        let ticks = rng.range(1, i64::from(ticks_per_s) * 2) as u32;
        for t in 0..ticks {
            fast.tick();
            slow.tick();
            total += 1;
            assert_same(&fast, &slow, total);
            if what == 9 && t == 4 {
                // The bus comes back for its value (until then the axis
                // takes the batch: the read waits for a slot).
                let a = fast.axis(k).read_register(Register::Speed);
                let b = slow.axis(k).read_register(Register::Speed);
                assert_eq!(a, b);
            }
        }
    }
    // The shortcut ran (and the comparison means something).
    let cruised = fast.group.plain_ticks();
    eprintln!("{cruised} of {total} ticks plain");
    assert!(cruised > total / 4, "{cruised} of {total} ticks plain");
    assert_eq!(slow.group.plain_ticks(), 0);
}

/// The same with the overlapped tick (batch k on the bus while k + 1 is
/// planned, two plans in flight) on whole bridges: the chips receive the
/// same commands and every axis keeps the same state.
#[test]
fn an_overlapped_plain_tick_puts_on_the_chain_what_the_batch_would() {
    use bridge_logic::postep60::{PowerStage, Request, Settings};
    use host_tests::sim_bridge::{chip, new_bridge, tick_overlapped};
    let n = 4;
    let make = |shortcut: bool| {
        let mut b = new_bridge(n, Settings::FACTORY, PowerStage::REFERENCE);
        tick_overlapped(&mut b, n, host_tests::sim_bridge::TICK_US);
        b.set_plain_shortcut(shortcut);
        b
    };
    let (mut fast, mut slow) = (make(true), make(false));
    let mut rng = Rng(0x0e71_a9d5_eed1);
    let mut now = 0u64;
    for round in 0..40 {
        let k = rng.below(n as u64) as usize;
        let req = match rng.below(6) {
            0..=3 => Request::SetPosition(rng.range(-60_000, 60_000) as i32),
            4 => Request::SetMaxSpeed(rng.range(200, 3_000) as u32),
            _ => Request::Stop,
        };
        assert_eq!(fast.request(k, req), slow.request(k, req), "round {round}");
        for _ in 0..rng.range(1, 3_000) {
            now += 1;
            fast.tick(now);
            slow.tick(now);
            for d in 0..n {
                assert_eq!(
                    chip(&fast, d).abs_pos(),
                    chip(&slow, d).abs_pos(),
                    "{now} ms, chip {d}"
                );
                assert_eq!(
                    format!("{:?}", fast.axis(d).unwrap()),
                    format!("{:?}", slow.axis(d).unwrap()),
                    "{now} ms, axis {d}"
                );
            }
        }
    }
    assert!(fast.is_overlapped());
    let cruised = u64::from(fast.plain_ticks());
    eprintln!("{cruised} of {now} ticks plain");
    assert!(cruised > now / 4, "{cruised} of {now} ticks plain");
    assert_eq!(slow.plain_ticks(), 0);
}
