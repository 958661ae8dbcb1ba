//! The firmware's chain driver (`drivers_core::chain_spi`: the one owner of
//! SPI1, blocking windows and DMA batches, the code the board runs) against
//! the RM0090 model of SPI1, DMA2 streams 0/3, TIM7 and CS
//! (`host_tests::rm0090::chain_spi`) with simulated powerSTEP01s behind
//! MISO: one test per rule (S1–S11), then the bridge's control ticks
//! through driver and model into the chips — the bridge's chain bus a
//! handle on the same driver that runs the batches — compared with the
//! blocking tick on the bare simulator.

use bridge_logic::bridge::{BatchState, Bridge, SettingsSource};
use bridge_logic::postep60::analog::AnalogSample;
use bridge_logic::postep60::{PowerStage, Query, Request, Settings, Value};
use bridge_logic::powerstep::chain::{Batch, ChainBus, Frames, Plan, MAX_DEVICES, MAX_WINDOWS};
use bridge_logic::powerstep::commands::Command;
use drivers_core::chain_spi::bits::*;
use drivers_core::chain_spi::{ChainClocks, ChainSpi, ChainSpiError, RX_STREAM, TEIF0, TX_STREAM};
use host_tests::rm0090::chain_spi::{ChainHandle, SharedChain, PCLK2_HZ, SYSCLK_HZ, TIMCLK_HZ};
use host_tests::sim_bridge::{all_settled, chip, new_bridge, TICK_US};
use stepbridge_sim::SimChain;

const EMPTY: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];

fn clocks() -> ChainClocks {
    ChainClocks {
        pclk2_hz: PCLK2_HZ as u32,
        sysclk_hz: SYSCLK_HZ as u32,
        timclk_hz: TIMCLK_HZ as u32,
    }
}

/// The driver on a model with `n` simulated chips.
fn rig(n: usize) -> (ChainSpi<ChainHandle>, ChainHandle) {
    let hw = ChainHandle::new(SimChain::new(n));
    (ChainSpi::new(hw.clone(), clocks()), hw)
}

fn now_us(hw: &ChainHandle) -> u64 {
    hw.model().now_ns() / 1000
}

/// Let the model run to `until_us`, serving TIM7 and DMA2_STREAM0 (TIM7
/// first: the lower IRQ number, both at one priority) `latency_ns` after
/// their line rises.
fn run_until(hw: &ChainHandle, dma: &mut ChainSpi<ChainHandle>, until_us: u64, latency_ns: u64) {
    let until = until_us * 1_000_000;
    let mut served = 0;
    loop {
        let (tim, d) = {
            let m = hw.model();
            (m.tim_irq(), m.dma_irq())
        };
        if tim || d {
            if latency_ns > 0 {
                let t = hw.model().now_ns() * 1000 + latency_ns * 1000;
                hw.model_mut().advance_to(t);
            }
            if hw.model().tim_irq() {
                dma.on_timer();
            } else if hw.model().dma_irq() {
                dma.on_dma();
            }
            served += 1;
            assert!(served < 10_000, "interrupt storm: {:?}", hw.model());
            continue;
        }
        let next = hw.model().next_event();
        match next {
            Some(t) if t <= until => hw.model_mut().advance_to(t),
            _ => {
                hw.model_mut().advance_to(until);
                return;
            }
        }
    }
}

fn clean(hw: &ChainHandle) {
    let m = hw.model();
    assert_eq!(m.violations(), &[] as &[String]);
    assert!(m.cs_high(), "CS high at rest");
    assert!(
        !m.tim_irq() && !m.dma_irq(),
        "interrupt left pending: {m:?}"
    );
}

fn status_plan(n: usize) -> Plan {
    Plan::new(&Batch::all(n, Command::GetStatus)).expect("plan")
}

/// Start `plan`, run the model 1 ms, collect it.
fn batch(
    dma: &mut ChainSpi<ChainHandle>,
    hw: &ChainHandle,
    plan: &Plan,
    latency_ns: u64,
) -> Result<Frames, ChainSpiError> {
    let t0 = now_us(hw);
    dma.start(plan, t0)?;
    run_until(hw, dma, t0 + 1000, latency_ns);
    let mut rx = EMPTY;
    match dma.poll(now_us(hw), &mut rx) {
        BatchState::Done(Ok(rows)) => Ok(*rows),
        BatchState::Done(Err(e)) => Err(e),
        other => panic!("batch not over after 1 ms: {other:?}"),
    }
}

// ------------------------------------------------------- S1, S2 SPI1 --

#[test]
fn s1_s2_spi1_is_an_enabled_mode_3_msb_first_8_bit_master_at_2_625_mhz() {
    let (port, hw) = rig(4);
    let cr1 = hw.model().spi_cr1();
    let want = SPI_CR1_CPOL | SPI_CR1_CPHA | SPI_CR1_MSTR | SPI_CR1_SSM | SPI_CR1_SSI | SPI_CR1_SPE;
    assert_eq!(cr1 & want, want);
    assert_eq!(cr1 & (SPI_CR1_LSBFIRST | SPI_CR1_DFF), 0);
    assert_eq!(hw.model().sck_hz(), 2_625_000);
    assert_eq!(port.sck_hz(), 2_625_000);
    clean(&hw);
}

// ------------------------------------- S3–S5, S11 blocking windows --

#[test]
fn s3_s4_s5_a_blocking_window_returns_the_chains_bytes_and_raises_cs_after_bsy() {
    let (mut port, hw) = rig(4);
    let tx = [0xD0, 0xD0, 0xD0, 0xD0];
    let mut rx = [0u8; 4];
    port.window(&tx, &mut rx).unwrap();
    let m = hw.model();
    assert_eq!(m.windows.len(), 1);
    assert_eq!(m.windows[0].tx, tx);
    assert_eq!(m.windows[0].rx, rx);
    assert!(!m.ovr());
    drop(m);
    clean(&hw);
}

#[test]
fn s11_blocking_windows_keep_t_discs_and_t_setcs() {
    let (mut port, hw) = rig(4);
    for _ in 0..3 {
        let mut rx = [0u8; 4];
        port.window(&[0; 4], &mut rx).unwrap();
    }
    let m = hw.model();
    for w in &m.windows {
        assert!(w.setup_ns >= 350, "{w:?}");
        assert!(w.gap_ns.is_none_or(|g| g >= 800), "{w:?}");
    }
    drop(m);
    clean(&hw);
}

#[test]
fn chain_detection_through_driver_and_model_finds_every_chip() {
    for n in [1, 4, 8] {
        let hw = ChainHandle::new(SimChain::new(n));
        let bridge = Bridge::new(
            ChainSpi::new(hw.clone(), clocks()),
            PowerStage::REFERENCE,
            Settings::FACTORY,
            SettingsSource::Stored,
            TICK_US,
        );
        assert_eq!(bridge.axes(), n, "{n} chips");
        clean(&hw);
    }
}

// -------------------------------------------- S6–S10 a DMA batch --

#[test]
fn s6_s9_s10_s11_a_dma_batch_clocks_every_window_with_the_cs_timing_the_chips_need() {
    let (mut dma, hw) = rig(4);
    let plan = status_plan(4);
    let rows = batch(&mut dma, &hw, &plan, 0).unwrap();
    let m = hw.model();
    assert_eq!(m.windows.len(), plan.windows());
    for (w, win) in m.windows.iter().enumerate() {
        assert_eq!(win.tx, plan.window(w).unwrap(), "window {w} out");
        assert_eq!(win.rx, rows[w][..4], "window {w} back");
        assert!(win.setup_ns >= 350, "{win:?}");
        assert!(win.gap_ns.is_none_or(|g| g >= 800), "{win:?}");
    }
    drop(m);
    assert!(!dma.is_running());
    assert_eq!(dma.stats().windows as usize, plan.windows());
    for s in [RX_STREAM, TX_STREAM] {
        assert_eq!(hw.model().stream_cr(s) & DMA_CR_EN, 0, "stream {s} off");
    }
    assert_eq!(
        hw.model().spi_cr2() & (SPI_CR2_TXDMAEN | SPI_CR2_RXDMAEN),
        0
    );
    clean(&hw);
}

#[test]
fn s8_the_streams_are_spi1_rx_and_tx_on_channel_3_at_spi1_dr() {
    let (_chain, hw) = rig(2);
    let m = hw.model();
    for (s, dir) in [(RX_STREAM, 0), (TX_STREAM, DMA_CR_DIR_M2P)] {
        let cr = m.stream_cr(s);
        assert_eq!((cr & DMA_CR_CHSEL_MASK) >> DMA_CR_CHSEL_SHIFT, 3);
        assert_eq!(cr & DMA_CR_DIR_MASK, dir);
        assert_eq!(m.stream_par(s), host_tests::rm0090::chain_spi::SPI1_DR);
    }
}

#[test]
fn s4_s10_a_batch_with_slow_interrupts_loses_no_byte_and_only_widens_the_gaps() {
    for latency in [500, 2_000] {
        let (mut dma, hw) = rig(8);
        let plan = status_plan(8);
        let rows = batch(&mut dma, &hw, &plan, latency).unwrap();
        let m = hw.model();
        assert!(!m.ovr());
        for (w, win) in m.windows.iter().enumerate() {
            assert_eq!(win.rx, rows[w][..8]);
        }
        drop(m);
        clean(&hw);
    }
}

#[test]
fn s7_batch_after_batch_rearms_the_streams_only_while_disabled_and_flags_clear() {
    let (mut dma, hw) = rig(4);
    let plan = status_plan(4);
    for _ in 0..5 {
        batch(&mut dma, &hw, &plan, 0).unwrap();
    }
    assert_eq!(hw.model().windows.len(), 5 * plan.windows());
    clean(&hw); // S7 violations would be listed
}

// ------------------------------------------------------------ errors --

#[test]
fn s9_a_dma_error_ends_the_batch_as_a_dma_error_and_the_next_batch_works() {
    let (mut dma, hw) = rig(4);
    let plan = status_plan(4);
    hw.model_mut().fail_stream_next(RX_STREAM, TEIF0);
    assert_eq!(batch(&mut dma, &hw, &plan, 0), Err(ChainSpiError::Dma));
    assert!(hw.model().cs_high());
    assert!(batch(&mut dma, &hw, &plan, 0).is_ok());
    clean(&hw);
}

#[test]
fn a_batch_past_its_deadline_is_stopped_as_a_timeout_with_cs_high() {
    let (mut dma, hw) = rig(4);
    let plan = status_plan(4);
    dma.start(&plan, now_us(&hw)).unwrap();
    let t = now_us(&hw);
    run_until(&hw, &mut dma, t + 5, 0);
    hw.model_mut().frozen = true; // SCK stops mid-window
    run_until(&hw, &mut dma, t + 2_000, 0);
    let mut rx = EMPTY;
    assert!(matches!(
        dma.poll(now_us(&hw), &mut rx),
        BatchState::Done(Err(ChainSpiError::Timeout))
    ));
    hw.model_mut().frozen = false;
    assert!(hw.model().cs_high());
    assert!(!dma.is_running());
    let mut one = [0u8; 4];
    assert!(
        dma.window(&[0; 4], &mut one).is_ok(),
        "blocking windows work again"
    );
}

#[test]
fn a_blocking_window_is_refused_while_a_batch_runs() {
    let (mut dma, hw) = rig(4);
    let plan = status_plan(4);
    dma.start(&plan, now_us(&hw)).unwrap();
    let mut rx = [0u8; 4];
    assert_eq!(dma.window(&[0; 4], &mut rx), Err(ChainSpiError::Busy));
    assert_eq!(dma.start(&plan, now_us(&hw)), Err(ChainSpiError::Busy));
    let t = now_us(&hw);
    run_until(&hw, &mut dma, t + 1000, 0);
    let mut rows = EMPTY;
    assert!(matches!(
        dma.poll(now_us(&hw), &mut rows),
        BatchState::Done(Ok(_))
    ));
    clean(&hw);
}

// ------------------------------------------- the bridge on the wire --

/// A bridge whose chain is driver + model, ticked the firmware's way: the
/// bridge's bus a handle on the one driver that also runs the batches.
struct Wire {
    bridge: Bridge<SharedChain>,
    chain: SharedChain,
    hw: ChainHandle,
    rx: Frames,
    now_us: u64,
    tick_us: u32,
    /// Interrupt latency the model serves TIM7 and DMA2 with, ns.
    latency_ns: u64,
}

impl Wire {
    fn new(n: usize) -> Wire {
        let hw = ChainHandle::new(SimChain::new(n));
        let chain = SharedChain::new(ChainSpi::new(hw.clone(), clocks()));
        let bridge = Bridge::new(
            chain.clone(),
            PowerStage::REFERENCE,
            Settings::FACTORY,
            SettingsSource::Stored,
            TICK_US,
        );
        Wire::on(bridge, chain, hw, TICK_US, 300)
    }

    /// The firmware's `init`: the rate (and whether the tick overlaps) as
    /// `rate::fit` says for `n` chips in a `build_hz` build, 1 µs of
    /// interrupt latency (what the fit allows for).
    fn fitted(n: usize, settings: Settings, build_hz: u32) -> (Wire, bridge_logic::rate::Rate) {
        let hw = ChainHandle::new(SimChain::new(n));
        let chain = SharedChain::new(ChainSpi::new(hw.clone(), clocks()));
        let (bridge, rate) = Bridge::new_fitted(
            chain.clone(),
            PowerStage::REFERENCE,
            settings,
            SettingsSource::Stored,
            build_hz,
        );
        (Wire::on(bridge, chain, hw, rate.us, 1000), rate)
    }

    fn on(
        mut bridge: Bridge<SharedChain>,
        chain: SharedChain,
        hw: ChainHandle,
        tick_us: u32,
        latency_ns: u64,
    ) -> Wire {
        bridge.on_analog(AnalogSample::NOMINAL_24V_25C);
        Wire {
            bridge,
            chain,
            hw,
            rx: EMPTY,
            now_us: 0,
            tick_us,
            latency_ns,
        }
    }

    /// One control tick (main.rs's `control_tick`: poll, then
    /// `tick_pipelined` starting the next batch), then the period runs on
    /// the model and the chips.
    fn tick(&mut self) {
        self.now_us += u64::from(self.tick_us);
        let (now_us, lat) = (self.now_us, self.latency_ns);
        let hw = &self.hw;
        self.chain.with(|d| run_until(hw, d, now_us, lat));
        let rx = &mut self.rx;
        let previous = self.chain.with(|d| d.poll(now_us, rx));
        self.bridge
            .tick_pipelined(now_us / 1000, previous, |plan, link| {
                link.with(|d| d.start(plan, now_us))
            });
        let end = now_us + u64::from(self.tick_us) - 1;
        self.chain.with(|d| run_until(hw, d, end, lat));
        self.hw
            .model_mut()
            .chain
            .advance(u64::from(self.tick_us) * 1000);
    }
}

#[test]
fn control_ticks_through_driver_and_model_send_the_chips_what_the_blocking_tick_sends() {
    let mut a = new_bridge(4, Settings::FACTORY, PowerStage::REFERENCE);
    let mut w = Wire::new(4);
    for now in 1..=300 {
        a.tick(now);
        a.chain_mut().bus_mut().advance(u64::from(TICK_US) * 1000);
        w.tick();
        let m = w.hw.model();
        for k in 0..4 {
            assert!(
                chip(&a, k)
                    .received()
                    .eq(m.chain.device(k).unwrap().received()),
                "chip {k}: the same commands at {now} ms"
            );
        }
    }
    assert!(all_settled(&a));
    assert_eq!(w.bridge.diag.chain_errors, 0);
    clean(&w.hw);
}

#[test]
fn a_move_through_driver_and_model_lands_where_the_blocking_tick_lands() {
    let mut a = new_bridge(2, Settings::FACTORY, PowerStage::REFERENCE);
    let mut w = Wire::new(2);
    for now in 1..=6_000u64 {
        if now == 50 {
            let _ = a.request(0, Request::SetMode(4));
            let _ = a.request(0, Request::RunSleep(1));
            a.request(0, Request::SetPosition(4_000)).unwrap();
            let _ = w.bridge.request(0, Request::SetMode(4));
            let _ = w.bridge.request(0, Request::RunSleep(1));
            w.bridge.request(0, Request::SetPosition(4_000)).unwrap();
        }
        a.tick(now);
        a.chain_mut().bus_mut().advance(u64::from(TICK_US) * 1000);
        w.tick();
    }
    assert_eq!(w.bridge.query(0, Query::Position), Some(Value::I32(4_000)));
    assert_eq!(a.query(0, Query::Position), Some(Value::I32(4_000)));
    let wire_pos = w.hw.model().chain.device(0).unwrap().abs_pos();
    assert_eq!(
        wire_pos,
        chip(&a, 0).abs_pos(),
        "the chip stands where the blocking tick puts it"
    );
    assert_ne!(wire_pos, 0);
    assert_eq!(w.bridge.diag.chain_errors, 0);
    clean(&w.hw);
}

#[test]
fn the_bridges_chain_bus_asks_the_driver_that_runs_the_batches() {
    // One owner: a blocking window through the bridge's handle is refused
    // while the same driver runs a batch, and goes through once it is over.
    let hw = ChainHandle::new(SimChain::new(4));
    let chain = SharedChain::new(ChainSpi::new(hw.clone(), clocks()));
    let mut link = chain.clone();
    let plan = status_plan(4);
    chain.with(|d| d.start(&plan, now_us(&hw))).unwrap();
    let mut rx = [0u8; 4];
    assert_eq!(link.window(&[0; 4], &mut rx), Err(ChainSpiError::Busy));
    let t = now_us(&hw);
    chain.with(|d| run_until(&hw, d, t + 1000, 0));
    let mut rows = EMPTY;
    assert!(matches!(
        chain.with(|d| d.poll(now_us(&hw), &mut rows)),
        BatchState::Done(Ok(_))
    ));
    let before = hw.model().windows.len();
    link.window(&[0xD0; 4], &mut rx).unwrap();
    assert_eq!(hw.model().windows.len(), before + 1);
    assert_eq!(hw.model().windows.last().unwrap().rx, rx);
    clean(&hw);
}

// ------------------------------------- 8 chips at 5 kHz, overlapped --

/// Eight chips in a 5 kHz build tick overlapped at 5 kHz (`rate::fit`):
/// `ticks` control ticks through driver and model (1 µs interrupt
/// latency), every axis moving to random targets one after the other.
/// Returns (moves, overruns, the most windows of a tick); panics on a
/// move that did not arrive.
fn overlapped_run(ticks: u64, seed: u64) -> (u64, u32, usize) {
    use bridge_logic::motion::axis::logical_to_physical;
    use bridge_logic::powerstep::registers::wrap_22;
    let mut settings = Settings::FACTORY;
    for a in settings.axes.iter_mut() {
        a.max_speed = 16_000;
        a.acc = 60_000;
        a.dec = 60_000;
    }
    let (mut w, rate) = Wire::fitted(8, settings, 5000);
    assert_eq!(
        (rate.hz, rate.overlapped, rate.derated),
        (5000, true, false)
    );
    assert!(w.bridge.is_overlapped());
    let mut rng = host_tests::rng::Rng(seed);
    let mut target: [Option<i32>; 8] = [None; 8];
    let mut moves = 0u64;
    let mut most_windows = 0;
    for t in 0..ticks {
        w.tick();
        // The model's log of windows, one tick's worth at a time.
        most_windows = most_windows.max(w.hw.model().windows.len());
        w.hw.model_mut().windows.clear();
        if t < 200 {
            continue; // the set-up
        }
        for (k, target) in target.iter_mut().enumerate() {
            let Some(a) = w.bridge.axis(k) else { continue };
            if !a.is_settled() {
                continue;
            }
            if let Some(p) = *target {
                // Arrived: the chip where the move said, exactly.
                let mode = settings.axes[k].step_mode;
                let phys = logical_to_physical(i64::from(p), mode, PowerStage::REFERENCE.step);
                let chip = w.hw.model().chain.device(k).unwrap().abs_pos();
                assert_eq!(
                    wrap_22(chip),
                    wrap_22(phys as i32),
                    "axis {k} at tick {t}: move to {p}"
                );
                assert_eq!(w.bridge.query(k, Query::Position), Some(Value::I32(p)));
            }
            if rng.below(8) != 0 {
                continue; // a pause at rest
            }
            let p = rng.range(0, 40_000) as i32 - 20_000;
            let _ = w.bridge.request(k, Request::SetMode(4));
            let _ = w.bridge.request(k, Request::RunSleep(1));
            w.bridge.request(k, Request::SetPosition(p)).unwrap();
            *target = Some(p);
            moves += 1;
        }
    }
    assert_eq!(w.bridge.diag.chain_errors, 0);
    clean(&w.hw);
    (moves, w.bridge.tick_overruns(), most_windows)
}

#[test]
fn eight_chips_at_5_khz_tick_overlapped_without_an_overrun() {
    let (moves, overruns, windows) = overlapped_run(20_000, 0x0E1A_5000_0008);
    assert!(moves > 8, "{moves} moves");
    assert_eq!(overruns, 0);
    // The rate's budget: a batch of 8 chips at 5 kHz takes 5 windows.
    assert!(windows <= 5, "a tick of {windows} windows");
}

/// Issue 22's run: 10⁶ ticks (200 s of motion at 5 kHz; `cargo test
/// --release -p host-tests --test rm0090_chain_spi -- --ignored million`,
/// CI runs it).
#[test]
#[ignore]
fn a_million_overlapped_ticks_of_8_chips_at_5_khz_never_overrun() {
    let (moves, overruns, windows) = overlapped_run(1_000_000, 0x0E1A_5000_1000);
    println!(
        "RESULT 10^6 overlapped ticks, 8 chips at 5 kHz: {moves} moves arrived, {overruns} overruns, at most {windows} windows a tick"
    );
    assert_eq!(overruns, 0);
}

// ------------------------------------------- the rate fit's bus part --

/// `rate::fit` fits the board's tick rate to the bus time its driver
/// works out (`ChainSpi::timing`, the firmware asks its driver): at the
/// board's clocks that is `rate::BOARD_BUS`, and a streaming batch of 8
/// chips on the model (1 µs interrupt latency) is over within it.
#[test]
fn a_streaming_batch_takes_no_longer_than_the_timing_the_rate_is_fitted_to() {
    use bridge_logic::powerstep::commands::Direction;
    use bridge_logic::powerstep::registers::Register;
    use bridge_logic::rate;
    let (mut dma, hw) = rig(8);
    assert_eq!(dma.timing(), rate::BOARD_BUS);
    let mut b = Batch::new(8);
    for d in 0..8 {
        b.push(d, Command::GetParam(Register::AbsPos)).unwrap();
        b.push(d, Command::Run(Direction::Forward, 1000)).unwrap();
    }
    let plan = Plan::new(&b).unwrap();
    assert_eq!(plan.windows(), rate::STREAM_WINDOWS as usize);
    let need_ns = rate::BOARD_BUS.batch_ns(rate::STREAM_WINDOWS, 8);
    let t0 = now_us(&hw);
    dma.start(&plan, t0).unwrap();
    let mut rx = EMPTY;
    let mut t = t0;
    let took_us = loop {
        t += 1;
        run_until(&hw, &mut dma, t, 1000);
        if let BatchState::Done(r) = dma.poll(now_us(&hw), &mut rx) {
            assert!(r.is_ok());
            break t - t0;
        }
        assert!(t - t0 < 1000, "batch not over after 1 ms");
    };
    let w: Vec<_> = hw
        .model()
        .windows
        .iter()
        .map(|w| (w.gap_ns, w.setup_ns))
        .collect();
    assert!(
        took_us * 1000 <= need_ns + 1000,
        "the batch took {took_us} us, the fit assumes {need_ns} ns; windows {w:?}"
    );
    // And not far less: the fit is the bus's truth, not a margin.
    assert!(
        took_us * 1000 + 20_000 >= need_ns,
        "{took_us} us vs {need_ns} ns"
    );
    clean(&hw);
}
