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
    now_ms: u64,
}

impl Wire {
    fn new(n: usize) -> Wire {
        let hw = ChainHandle::new(SimChain::new(n));
        let chain = SharedChain::new(ChainSpi::new(hw.clone(), clocks()));
        let mut bridge = Bridge::new(
            chain.clone(),
            PowerStage::REFERENCE,
            Settings::FACTORY,
            SettingsSource::Stored,
            TICK_US,
        );
        bridge.on_analog(AnalogSample::NOMINAL_24V_25C);
        Wire {
            bridge,
            chain,
            hw,
            rx: EMPTY,
            now_ms: 0,
        }
    }

    /// One control tick (main.rs's `control_tick`: poll, then
    /// `tick_pipelined` starting the next batch), then the period runs on
    /// the model and the chips.
    fn tick(&mut self) {
        self.now_ms += 1;
        let now_us = self.now_ms * 1000;
        let hw = &self.hw;
        self.chain.with(|d| run_until(hw, d, now_us, 300));
        let rx = &mut self.rx;
        let previous = self.chain.with(|d| d.poll(now_us, rx));
        self.bridge
            .tick_pipelined(self.now_ms, previous, |plan, link| {
                link.with(|d| d.start(plan, now_us))
            });
        self.chain.with(|d| run_until(hw, d, now_us + 999, 300));
        self.hw.model_mut().chain.advance(u64::from(TICK_US) * 1000);
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
