//! The firmware's control tick with the DMA chain driver
//! (`Bridge::tick_pipelined`): each tick ends the previous batch, then plans
//! and starts its own, whose replies the next tick absorbs. Here the
//! "driver" clocks the windows through the simulated chips at start, as the
//! QEMU image's does; a board's DMA puts the same bytes out over the period.
//!
//! * Without requests in between, the wire carries the blocking tick's bytes.
//! * Bus requests now arrive between a batch's plan and its absorb: random
//!   move / retarget / stop / soft stop / Set zero / step-mode sequences
//!   still end exactly where the last accepted command says.
//! * A batch still running skips the tick (an overrun); a failed or refused
//!   batch is a chain error and every chip is set up again.

#![allow(clippy::needless_range_loop)] // axes are addressed by chain index

use bridge_logic::bridge::{BatchState, Bridge, PipelinedTick, SettingsSource};
use bridge_logic::motion::axis::{logical_to_physical, physical_to_logical};
use bridge_logic::postep60::{PowerStage, Query, Request, Settings, Value};
use bridge_logic::powerstep::chain::{ChainBus, Frames, Plan, MAX_DEVICES, MAX_WINDOWS};
use bridge_logic::powerstep::registers::{sign_extend_22, wrap_22};
use host_tests::rng::Rng;
use host_tests::sim_bridge::{all_settled, chip, new_bridge, TICK_US};
use stepbridge_sim::SimChain;

const BOARD: PowerStage = PowerStage::REFERENCE;
const EMPTY: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];

/// Clock every window of `plan` through `bus` into `rx` (what the QEMU
/// image's driver does at start).
fn clock<B: ChainBus>(plan: &Plan, bus: &mut B, rx: &mut Frames) -> Result<(), B::Error> {
    let n = plan.devices();
    for (w, row) in rx.iter_mut().enumerate().take(plan.windows()) {
        if let (Some(tx), Some(row)) = (plan.window(w), row.get_mut(..n)) {
            bus.window(tx, row)?;
        }
    }
    Ok(())
}

/// A bridge ticked the firmware's way, plus the driver's state.
struct Pipelined {
    bridge: Bridge<SimChain>,
    /// The driver's receive buffer (the batch in flight).
    rx: Frames,
    /// What the firmware copies out of it before handing it to the bridge.
    ended: Frames,
    running: bool,
    now: u64,
}

impl Pipelined {
    fn new(n: usize, settings: Settings) -> Pipelined {
        // new_bridge measures 24 V and 25 °C already.
        let bridge = new_bridge(n, settings, BOARD);
        Pipelined {
            bridge,
            rx: EMPTY,
            ended: EMPTY,
            running: false,
            now: 0,
        }
    }

    /// One control tick, then one period of chip time.
    fn tick(&mut self) -> PipelinedTick {
        self.now += 1;
        let previous = if self.running {
            self.ended = self.rx;
            BatchState::Done(Ok(&self.ended))
        } else {
            BatchState::Idle
        };
        let rx = &mut self.rx;
        let step = self
            .bridge
            .tick_pipelined(self.now, previous, |plan, bus| clock(plan, bus, rx));
        self.running = step == PipelinedTick::Started;
        self.bridge
            .chain_mut()
            .bus_mut()
            .advance(u64::from(TICK_US) * 1000);
        step
    }

    fn run(&mut self, ms: u64) {
        for _ in 0..ms {
            self.tick();
        }
    }

    fn position(&self, k: usize) -> i64 {
        match self.bridge.query(k, Query::Position) {
            Some(Value::I32(p)) => i64::from(p),
            other => panic!("position of axis {k}: {other:?}"),
        }
    }

    fn settle(&mut self, cap: u64) {
        for _ in 0..cap {
            if all_settled(&self.bridge) {
                return;
            }
            self.tick();
        }
        panic!("not settled after {cap} ms");
    }
}

#[test]
fn without_requests_in_between_the_wire_carries_the_blocking_ticks_bytes() {
    let mut a = new_bridge(4, Settings::FACTORY, BOARD);
    let mut p = Pipelined::new(4, Settings::FACTORY);
    let compare = |a: &Bridge<SimChain>, p: &Pipelined| {
        for k in 0..4 {
            assert!(
                chip(a, k).received().eq(chip(&p.bridge, k).received()),
                "chip {k}: the same commands at {} ms",
                p.now
            );
        }
    };
    // The setup after power-up, then rest.
    for now in 1..=300 {
        a.tick(now);
        a.chain_mut().bus_mut().advance(u64::from(TICK_US) * 1000);
        p.tick();
        compare(&a, &p);
    }
    assert!(all_settled(&a) && all_settled(&p.bridge));
    assert!(chip(&p.bridge, 0).received_count() > 300);
}

/// Where the last accepted command says an axis ends up.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Expect {
    At { target: i64, mode: u8 },
    Held,
}

/// xorshift64*: deterministic, seedable.
struct Oracle {
    expect: Vec<Expect>,
    mode: Vec<u8>,
    moves: u64,
}

impl Oracle {
    fn request(&mut self, p: &mut Pipelined, k: usize, req: Request) {
        if p.bridge.request(k, req).is_err() {
            return;
        }
        match req {
            Request::SetPosition(t) => {
                self.moves += 1;
                self.expect[k] = Expect::At {
                    target: i64::from(t),
                    mode: self.mode[k],
                };
            }
            Request::SetZero => {
                self.expect[k] = Expect::At {
                    target: 0,
                    mode: self.mode[k],
                };
                assert_eq!(p.position(k), 0, "axis {k}: 0 right after Set zero");
            }
            Request::Stop | Request::SoftStop => self.expect[k] = Expect::Held,
            Request::SetStepMode(m) => {
                if m != self.mode[k] {
                    self.expect[k] = Expect::Held;
                }
                self.mode[k] = m;
            }
            _ => {}
        }
    }

    fn check(&self, p: &Pipelined, seq: usize) {
        for (k, e) in self.expect.iter().enumerate() {
            let Expect::At { target, mode } = *e else {
                continue;
            };
            let phys = logical_to_physical(target, mode, BOARD.step);
            let want = sign_extend_22(wrap_22(phys as i32));
            assert_eq!(
                chip(&p.bridge, k).abs_pos(),
                want,
                "sequence {seq}, axis {k}: chip ABS_POS for target {target} (mode {mode})"
            );
            assert_eq!(
                p.position(k),
                physical_to_logical(phys, mode, BOARD.step),
                "sequence {seq}, axis {k}: reported position"
            );
        }
    }
}

#[test]
fn requests_between_a_batchs_plan_and_its_absorb_still_arrive() {
    let n = 4;
    let mut settings = Settings::FACTORY;
    for a in settings.axes.iter_mut() {
        a.max_speed = 16_000;
        a.acc = 60_000;
        a.dec = 60_000;
    }
    let mut p = Pipelined::new(n, settings);
    p.run(30);
    let mut o = Oracle {
        expect: vec![
            Expect::At {
                target: 0,
                mode: settings.axes[0].step_mode
            };
            n
        ],
        mode: settings.axes.iter().take(n).map(|a| a.step_mode).collect(),
        moves: 0,
    };
    let mut rng = Rng(0x5EED_D3A1);
    for seq in 0..120 {
        for k in 0..n {
            let here = p.position(k);
            let scale = 1i64 << o.mode[k];
            let target = here + rng.range(-2000, 2000) * scale;
            o.request(&mut p, k, Request::SetPosition(target as i32));
        }
        p.run(rng.below(300));
        for k in 0..n {
            let scale = 1i64 << o.mode[k];
            match rng.below(7) {
                0 => {
                    o.request(&mut p, k, Request::Stop);
                    p.run(rng.below(4));
                    let here = p.position(k);
                    let t = here + rng.range(-500, 500) * scale;
                    o.request(&mut p, k, Request::SetPosition(t as i32));
                }
                1 => {
                    o.request(&mut p, k, Request::SetZero);
                    p.run(rng.below(6));
                    let t = rng.range(-800, 800) * scale;
                    o.request(&mut p, k, Request::SetPosition(t as i32));
                }
                2 => {
                    let m = rng.below(9) as u8;
                    o.request(&mut p, k, Request::SetStepMode(m));
                    p.run(rng.below(3));
                    let here = p.position(k);
                    let t = here + (rng.range(-400, 400) << m);
                    o.request(&mut p, k, Request::SetPosition(t as i32));
                }
                3 => {
                    o.request(&mut p, k, Request::SoftStop);
                    p.run(rng.below(30));
                    let here = p.position(k);
                    let t = here + rng.range(-500, 500) * scale;
                    o.request(&mut p, k, Request::SetPosition(t as i32));
                }
                4 => {
                    let here = p.position(k);
                    let t = here + rng.range(-3000, 3000) * scale;
                    o.request(&mut p, k, Request::SetPosition(t as i32));
                }
                _ => {}
            }
        }
        p.settle(400_000);
        o.check(&p, seq);
    }
    assert!(o.moves > 500, "{} moves", o.moves);
    assert_eq!(p.bridge.diag.chain_errors, 0);
    assert_eq!(p.bridge.tick_overruns(), 0);
}

/// A chain whose batches the test ends by hand.
#[derive(Debug)]
struct Manual {
    sim: SimChain,
}

impl ChainBus for Manual {
    type Error = ();
    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ()> {
        self.sim.transfer(tx, rx);
        Ok(())
    }
}

fn manual(n: usize) -> Bridge<Manual> {
    Bridge::new(
        Manual {
            sim: SimChain::new(n),
        },
        BOARD,
        Settings::FACTORY,
        SettingsSource::Stored,
        TICK_US,
    )
}

/// Tick `b` with a batch that ends at once, `ms` times.
fn run_manual(b: &mut Bridge<Manual>, now: &mut u64, ms: u64) {
    let mut rx = EMPTY;
    let mut pending = false;
    for _ in 0..ms {
        *now += 1;
        let ended = rx;
        let previous = if pending {
            BatchState::Done(Ok(&ended))
        } else {
            BatchState::Idle
        };
        let step = b.tick_pipelined(*now, previous, |plan, bus| clock(plan, bus, &mut rx));
        pending = step == PipelinedTick::Started;
        b.chain_mut().bus_mut().sim.advance(1_000_000);
    }
    if pending {
        b.tick_end(Ok(&rx));
    }
}

#[test]
fn a_batch_still_running_skips_the_tick_and_counts_an_overrun() {
    let mut b = manual(2);
    let mut now = 0;
    run_manual(&mut b, &mut now, 30);
    assert!(b.axis(0).is_some_and(|a| a.is_configured()));
    // Tick 31 starts a batch; at tick 32 it is still on the bus.
    let mut rx = EMPTY;
    let step = b.tick_pipelined(31, BatchState::Idle, |plan, bus| clock(plan, bus, &mut rx));
    assert_eq!(step, PipelinedTick::Started);
    let sent = b.chain().bus().sim.device(0).map(|c| c.received_count());
    let mut refused = false;
    let step = b.tick_pipelined(32, BatchState::Running, |_, _| {
        refused = true;
        Ok(())
    });
    assert_eq!(step, PipelinedTick::Overrun);
    assert!(!refused, "no new batch while one runs");
    assert_eq!(b.tick_overruns(), 1);
    assert_eq!(
        b.chain().bus().sim.device(0).map(|c| c.received_count()),
        sent,
        "nothing went out"
    );
    // Tick 33 ends it and carries on.
    let ended = rx;
    let step = b.tick_pipelined(33, BatchState::Done(Ok(&ended)), |plan, bus| {
        clock(plan, bus, &mut rx)
    });
    assert_eq!(step, PipelinedTick::Started);
    b.tick_end(Ok(&rx));
    assert_eq!(b.diag.chain_errors, 0);
    assert_eq!(b.tick_overruns(), 1);
    // The tick's own duration still counts too.
    b.tick_timing(TICK_US + 1, TICK_US);
    assert_eq!(b.tick_overruns(), 2);
}

#[test]
fn a_batch_that_failed_or_was_refused_is_a_chain_error_and_every_chip_is_set_up_again() {
    let mut b = manual(2);
    let mut now = 0;
    run_manual(&mut b, &mut now, 30);
    assert!(b.axis(0).is_some_and(|a| a.is_configured()));

    // The driver ended the batch with an error (DMA error, timeout).
    let mut rx = EMPTY;
    now += 1;
    let _ = b.tick_pipelined(now, BatchState::Idle, |plan, bus| clock(plan, bus, &mut rx));
    now += 1;
    let step = b.tick_pipelined(now, BatchState::Done(Err(())), |plan, bus| {
        clock(plan, bus, &mut rx)
    });
    assert_eq!(b.diag.chain_errors, 1);
    assert!(
        !b.axis(0).is_some_and(|a| a.is_configured()),
        "set up again"
    );
    assert_eq!(step, PipelinedTick::Started);
    b.tick_end(Ok(&rx));

    // The driver refused to start one.
    now += 1;
    let step = b.tick_pipelined(now, BatchState::Idle, |_, _| Err(()));
    assert_eq!(step, PipelinedTick::StartFailed);
    assert_eq!(b.diag.chain_errors, 2);

    run_manual(&mut b, &mut now, 60);
    assert!(
        b.axis(0).is_some_and(|a| a.is_configured()),
        "configured again"
    );
    assert!(!b.chain_dead());
    assert_eq!(b.tick_overruns(), 0);
}

/// A chain that never answers.
#[derive(Debug)]
struct Dead;

impl ChainBus for Dead {
    type Error = ();
    fn window(&mut self, _: &[u8], _: &mut [u8]) -> Result<(), ()> {
        Err(())
    }
}

#[test]
fn without_axes_no_batch_is_started() {
    let mut b = Bridge::new(
        Dead,
        BOARD,
        Settings::FACTORY,
        SettingsSource::Stored,
        TICK_US,
    );
    assert_eq!(b.axes(), 0);
    let step = b.tick_pipelined(1, BatchState::Idle, |_, _| panic!("nothing to clock"));
    assert_eq!(step, PipelinedTick::NoBatch);
}

/// Overlapped, a failed batch drops the one planned behind it (that tick
/// sends nothing): both count toward the chain's death, so a chain whose
/// every batch fails is dead after `CHAIN_DEAD_TICKS` ticks, as in a row.
#[test]
fn overlapped_a_chain_whose_every_batch_fails_is_dead_after_ten_ticks() {
    let mut b = manual(2);
    b.set_overlapped(true);
    let mut now = 0;
    run_manual(&mut b, &mut now, 30);
    assert!(b.axis(0).is_some_and(|a| a.is_configured()));
    let mut rx = EMPTY;
    let mut pending = true;
    let mut ticks = 0;
    while !b.chain_dead() {
        now += 1;
        ticks += 1;
        let previous = if pending {
            BatchState::Done(Err(()))
        } else {
            BatchState::Idle
        };
        let step = b.tick_pipelined(now, previous, |plan, bus| clock(plan, bus, &mut rx));
        pending = step == PipelinedTick::Started;
        assert!(ticks <= 10, "not dead after {ticks} failed ticks");
    }
    // The batch the last good tick started is the first of the ten.
    assert_eq!(ticks, 9);
}
