//! The control tick split for a DMA chain driver (`Bridge::tick_begin`, the
//! windows clocked by the driver, `Bridge::tick_end`) does exactly what the
//! blocking `Bridge::tick` does, byte for byte on the wire.

use bridge_logic::bridge::Bridge;
use bridge_logic::postep60::{PowerStage, Request, Settings};
use bridge_logic::powerstep::chain::{ChainBus, Frames, MAX_DEVICES, MAX_WINDOWS};
use host_tests::sim_bridge::Breakable;
use host_tests::sim_bridge::{chip, new_bridge, TICK_US};
use stepbridge_sim::SimChain;

/// What a DMA driver does between `tick_begin` and `tick_end`: clock every
/// window of the plan (here through the simulated chain).
fn async_tick(b: &mut Bridge<SimChain>, now_ms: u64) {
    if !b.tick_begin(now_ms) {
        return;
    }
    let n = b.chain().len();
    let mut rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];
    let plan = b.plan().clone();
    for (w, row) in rx.iter_mut().enumerate().take(plan.windows()) {
        let tx = plan.window(w).expect("window");
        let _ = b.chain_mut().bus_mut().window(tx, &mut row[..n]);
    }
    b.tick_end(Ok(&rx));
}

fn run_both(ms: u64, a: &mut Bridge<SimChain>, b: &mut Bridge<SimChain>, now: &mut u64) {
    for _ in 0..ms {
        *now += 1;
        a.tick(*now);
        async_tick(b, *now);
        let dt = u64::from(TICK_US) * 1000;
        a.chain_mut().bus_mut().advance(dt);
        b.chain_mut().bus_mut().advance(dt);
        for k in 0..a.axes() {
            assert_eq!(
                chip(a, k).received().collect::<Vec<_>>(),
                chip(b, k).received().collect::<Vec<_>>(),
                "chip {k}: the same commands at {now} ms"
            );
        }
    }
}

#[test]
fn a_tick_begun_and_ended_around_the_driver_equals_the_blocking_tick() {
    let mut a = new_bridge(4, Settings::FACTORY, PowerStage::REFERENCE);
    let mut b = new_bridge(4, Settings::FACTORY, PowerStage::REFERENCE);
    let mut now = 0;
    run_both(30, &mut a, &mut b, &mut now);
    for k in 0..4 {
        let t = 1000 * (k as i32 + 1) * if k % 2 == 0 { 1 } else { -1 };
        a.request(k, Request::SetPosition(t)).expect("move");
        b.request(k, Request::SetPosition(t)).expect("move");
    }
    run_both(200, &mut a, &mut b, &mut now);
    a.request(1, Request::Stop).expect("stop");
    b.request(1, Request::Stop).expect("stop");
    run_both(10_000, &mut a, &mut b, &mut now);
    for k in 0..4 {
        assert_eq!(chip(&a, k).abs_pos(), chip(&b, k).abs_pos());
        assert_eq!(a.axis(k).map(|x| x.is_settled()), Some(true));
    }
    assert_eq!(
        chip(&b, 0).abs_pos(),
        8000,
        "1000 steps at 1/16 on a 1/128 chip"
    );
}

#[test]
fn a_transfer_the_driver_reports_failed_sets_every_chip_up_again() {
    let mut b = Bridge::new(
        Breakable::new(2),
        PowerStage::REFERENCE,
        Settings::FACTORY,
        bridge_logic::bridge::SettingsSource::Stored,
        TICK_US,
    );
    let tick = |b: &mut Bridge<Breakable>, now: u64, fail: bool| {
        if b.tick_begin(now) {
            if fail {
                b.tick_end(Err(()));
            } else {
                let n = b.chain().len();
                let mut rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];
                let plan = b.plan().clone();
                for (w, row) in rx.iter_mut().enumerate().take(plan.windows()) {
                    let tx = plan.window(w).expect("window").to_vec();
                    let _ = b.chain_mut().bus_mut().window(&tx, &mut row[..n]);
                }
                b.tick_end(Ok(&rx));
            }
        }
        b.chain_mut().bus_mut().sim.advance(1_000_000);
    };
    for now in 1..=30 {
        tick(&mut b, now, false);
    }
    assert!(b.axis(0).is_some_and(|a| a.is_configured()));
    tick(&mut b, 31, true);
    assert_eq!(b.diag.chain_errors, 1);
    assert!(
        !b.axis(0).is_some_and(|a| a.is_configured()),
        "set up again"
    );
    for now in 32..=80 {
        tick(&mut b, now, false);
    }
    assert!(
        b.axis(0).is_some_and(|a| a.is_configured()),
        "and configured again"
    );
    assert!(!b.chain_dead());
}
