//! The firmware's I/O extension driver (`drivers_core::ioext_spi`, the code
//! the board runs) against the RM0090 model of SPI2, TIM1, DMA1 streams 3/4,
//! DMA2 streams 2/6 and GPIOB's pins, with 74HC165s and 74HC595s on the
//! pins (`host_tests::rm0090::ioext`): one test or more per rule (X1–X13),
//! every plan shape the logic produces through driver and model — bit
//! counts 1, 7, 8, 9, 31, 32, 33, 255, 256, both engines, all four SPI
//! modes, CS hold — with each CS window compared with the plan and the bits
//! compared with what the logic expects (its wire reference on
//! `stepbridge_sim::ShiftChain`, and the plan's own bits where the mode
//! is exact), a DMA error on every stream under the one FIFO-error rule, a
//! stuck stream aborted at the plan's timeout, and a deliberate slip the
//! model catches.

use bridge_logic::ioext::{Action, Clocks, Engine, SpiMode, TransferPlan, WireBits};
use drivers_core::dma::bits::*;
use drivers_core::dma::Flags;
use drivers_core::ioext_spi::bits::*;
use drivers_core::ioext_spi::{
    GpioReg, IoExtBuffers, IoExtError, IoExtHw, IoExtPort, IoReg, Started, Target, TimReg,
};
use drivers_core::spi::bits::*;
use drivers_core::spi::SpiReg;
use drivers_core::Regs;
use host_tests::ioext_wire::transfer as wire_transfer;
use host_tests::rm0090::ioext::{
    cycles_of_ns, CsWindow, IoHandle, ShiftRegs, CLOCK_HZ, GPIOB_BSRR, GPIOB_IDR, PINS, SPI2_DR,
};
use stepbridge_sim::ShiftChain;

/// A full chain: 32 '165s and 32 '595s, every one of 256 bits reaches a
/// chip.
const CHIPS: usize = 32;
const BITS: [u16; 9] = [1, 7, 8, 9, 31, 32, 33, 255, 256];

/// The '165 inputs: neither all 0 nor all 1 in any byte.
fn input(i: usize) -> bool {
    (i * 5 + 1) % 7 < 3
}

/// Driver, model and the logic's reference chain, both chains with the
/// same inputs.
struct Rig<H: IoExtHw = IoHandle> {
    port: IoExtPort<H>,
    hw: IoHandle,
    logic: ShiftChain,
}

fn rig() -> Rig {
    let hw = IoHandle::new(ShiftRegs::new(CHIPS, CHIPS));
    rig_on(hw.clone(), hw)
}

fn rig_on<H: IoExtHw>(driver_hw: H, hw: IoHandle) -> Rig<H> {
    let mut logic = ShiftChain::new(CHIPS, CHIPS);
    for i in 0..8 * CHIPS {
        hw.model_mut().chips.set_rx_bit(i, input(i));
        logic.set_rx_bit(i, input(i));
    }
    Rig {
        port: IoExtPort::new(driver_hw, CLOCK_HZ as u32),
        hw,
        logic,
    }
}

fn plan(bits: u16, mode: SpiMode, n: u8) -> TransferPlan {
    let tx = WireBits::from_fn(bits, |i| (i * 7 + 3) % 5 < 2);
    TransferPlan::single(bits, mode, n, Clocks::BOARD, tx)
}

fn is_spi(p: &TransferPlan) -> bool {
    matches!(p.clock.engine, Engine::Spi { .. })
}

impl<H: IoExtHw> Rig<H> {
    /// Run `action` to its end as the app does: start it, then serve
    /// `DMA1_STREAM3` / `DMA2_STREAM2` `latency_ns` after their line rises,
    /// until the end or the plan's timeout (then `abort`).
    fn run(&mut self, action: Action, latency_ns: u64) -> Started {
        let started = self.port.run(&action);
        let Action::Transfer(plan) = action else {
            return started;
        };
        if started != Started::Running {
            return started;
        }
        let deadline = self.hw.model().now() + cycles_of_ns(plan.timeout_us() * 1_000);
        loop {
            let line = {
                let m = self.hw.model();
                m.irq_spi() || m.irq_timer()
            };
            assert!(!self.hw.model().irq_other(), "an interrupt no task serves");
            if line {
                let t = self.hw.model().now() + cycles_of_ns(latency_ns);
                self.hw.model_mut().advance_to(t);
                if let Some(r) = self.port.on_interrupt() {
                    return Started::Ended(r);
                }
                continue;
            }
            let next = self.hw.model().next_event();
            match next {
                Some(t) if t <= deadline => self.hw.model_mut().advance_to(t),
                _ => {
                    self.hw.model_mut().advance_to(deadline);
                    let r = self.port.abort();
                    return Started::Ended(r.expect("something to abort"));
                }
            }
        }
    }

    fn transfer(&mut self, plan: TransferPlan) -> Result<WireBits, IoExtError> {
        match self.run(Action::Transfer(plan), 0) {
            Started::Ended(r) => r,
            other => panic!("{other:?}"),
        }
    }

    /// Transfer `plan` and compare it with the logic: the received bits,
    /// the '595 stages this transfer filled, and (modes 0, 2, 3, exact in
    /// both directions) the plan's own bits and the inputs.
    fn check(&mut self, plan: TransferPlan) {
        let got = self
            .transfer(plan)
            .unwrap_or_else(|e| panic!("{e:?}: {plan:?}"));
        let want = wire_transfer(&mut self.logic, &plan);
        let n = usize::from(plan.bits);
        let what = format!("{} bits, {:?}, {:?}", n, plan.mode, plan.clock.engine);
        assert_eq!(got, want, "received bits against the logic: {what}");
        let m = self.hw.model();
        for i in 0..n {
            if n - 1 - i >= m.chips.stages() {
                continue;
            }
            // The SPI engine does not promise MOSI before the first leading
            // edge (`bridge_logic::ioext::wire`): in mode 1 that is the
            // level the '595 takes for bit 0.
            if is_spi(&plan) && plan.mode == SpiMode::MODE1 && i == 0 {
                continue;
            }
            assert_eq!(
                m.chips.tx_bit_output(n, i),
                self.logic.tx_bit_output(n, i),
                "'595 output of bit {i}: {what}"
            );
        }
        if plan.mode != SpiMode::MODE1 && !plan.cs_hold && !plan.cs_low_before {
            for i in 0..n {
                let want_in = i < 8 * CHIPS && input(i);
                assert_eq!(got.get(i), want_in, "input {i}: {what}");
                assert_eq!(
                    m.chips.tx_bit_output(n, i),
                    plan.tx.get(i),
                    "bit {i} out: {what}"
                );
            }
        }
    }
}

/// The last CS window against `plans` (the transfers it carried, in
/// order): 2 edges a bit, the first edge no earlier than the first plan's
/// half period after CS fell, CS up no earlier than the last plan's half
/// period after the last edge, no period shorter than its plan's.
fn window_against(w: &CsWindow, plans: &[TransferPlan]) -> Result<(), String> {
    let bits: usize = plans.iter().map(|p| usize::from(p.bits)).sum();
    if w.edges.len() != 2 * bits {
        return Err(format!("{} SCK edges for {bits} bits", w.edges.len()));
    }
    let ns = |c: u64| c as f64 * 1e9 / CLOCK_HZ as f64;
    let at_least = |cycles: u64, want_ns: u64| cycles * 1_000 >= want_ns * (CLOCK_HZ / 1_000_000);
    let first = w.edges[0] - w.fell;
    let half = plans[0].half_period_ns();
    if !at_least(first, half) {
        return Err(format!(
            "first SCK edge {:.1} ns after CS fell (the plan promises {half} ns)",
            ns(first)
        ));
    }
    // The bit engine's first phase makes the set-up by itself: it must
    // keep the promise without the CPU's time from CS to CEN.
    if let (Some(start), false) = (w.engine_start, is_spi(&plans[0])) {
        let phase = w.edges[0] - start;
        if !at_least(phase, half) {
            return Err(format!(
                "first SCK edge {:.1} ns after TIM1 started (the plan promises {half} ns)",
                ns(phase)
            ));
        }
    }
    if let Some(rose) = w.rose {
        let last = rose - w.edges[w.edges.len() - 1];
        let half = plans[plans.len() - 1].half_period_ns();
        if !at_least(last, half) {
            return Err(format!(
                "CS rose {:.1} ns after the last SCK edge (the plan promises {half} ns)",
                ns(last)
            ));
        }
    }
    let mut k = 0;
    for p in plans {
        let edges = &w.edges[k..k + 2 * usize::from(p.bits)];
        k += edges.len();
        let period = p.clock.period;
        for pair in edges.chunks(2).collect::<Vec<_>>().windows(2) {
            let d = pair[1][0] - pair[0][0];
            // d / CLOCK_HZ ≥ ticks / hz, exactly.
            if u128::from(d) * u128::from(period.hz)
                < u128::from(period.ticks) * u128::from(CLOCK_HZ)
            {
                return Err(format!(
                    "a period of {:.1} ns, the plan's is {} ns",
                    ns(d),
                    period.nanos_ceil()
                ));
            }
        }
    }
    Ok(())
}

fn last_window(hw: &IoHandle) -> CsWindow {
    hw.model().windows().last().cloned().expect("a CS window")
}

/// A 16-bit transfer after a failed one is whole: every input as the
/// chips hold it and every output as the plan says (the logic's chain did
/// not see the cut one), and it leaves the peripherals clean.
fn next_transfer_is_whole(r: &mut Rig, after: &str) {
    let next = plan(16, SpiMode::MODE0, 5);
    let got = r.transfer(next).unwrap();
    for i in 0..16 {
        assert_eq!(got.get(i), input(i), "input {i} after {after}");
        assert_eq!(r.hw.model().chips.tx_bit_output(16, i), next.tx.get(i));
    }
    clean(&r.hw);
}

fn clean(hw: &IoHandle) {
    let m = hw.model();
    assert_eq!(m.violations(), &[] as &[String]);
    assert!(m.cs_high(), "CS high at rest");
    assert!(
        !m.irq_spi() && !m.irq_timer(),
        "interrupt left pending: {m:?}"
    );
}

// ---------------------------------------------------- X1–X5: SPI2 --

#[test]
fn x1_x2_x3_spi2_is_set_up_as_the_plan_says_only_while_disabled_and_clocks_its_period() {
    let mut r = rig();
    // (mode, N, CR1.BR): N = 0 → /2, N = 5 → /32, N = 50 → /256.
    for (mode, n, br) in [
        (SpiMode::MODE0, 0u8, 0u32),
        (SpiMode::MODE3, 5, 4),
        (SpiMode::MODE1, 50, 7),
        (SpiMode::MODE2, 1, 2),
    ] {
        let p = plan(32, mode, n);
        assert_eq!(p.spi().map(|s| u32::from(s.br)), Some(br));
        r.check(p);
        let cr1 = r.hw.model().spi_cr1();
        let want = SPI_CR1_MSTR | SPI_CR1_SSM | SPI_CR1_SSI | SPI_CR1_SPE;
        assert_eq!(cr1 & want, want);
        assert_eq!(cr1 & SPI_CR1_CPOL != 0, mode.cpol);
        assert_eq!(cr1 & SPI_CR1_CPHA != 0, mode.cpha);
        assert_eq!((cr1 & SPI_CR1_BR_MASK) >> SPI_CR1_BR_SHIFT, br);
        assert_eq!(cr1 & (SPI_CR1_DFF | SPI_CR1_LSBFIRST), 0);
        // 32 bits, back to back: every period exactly 2^(BR+1) / 42 MHz.
        let w = last_window(&r.hw);
        window_against(&w, &[p]).unwrap();
        let period = (2u64 << br) * 4;
        for pair in w.edges.chunks(2).collect::<Vec<_>>().windows(2) {
            assert_eq!(pair[1][0] - pair[0][0], period, "{mode:?} N {n}");
        }
    }
    clean(&r.hw);
}

#[test]
fn x3_x5_frames_follow_back_to_back_and_cs_rises_after_bsy_half_a_period_later() {
    let mut r = rig();
    for mode in SpiMode::ALL {
        let p = plan(256, mode, 0);
        r.check(p);
        let w = last_window(&r.hw);
        window_against(&w, &[p]).unwrap();
        // 256 bits at 21 MHz: 12.19 µs of edges, no gap between frames.
        let span = w.edges[w.edges.len() - 1] - w.edges[0];
        assert_eq!(span, 255 * 8 + 4, "{mode:?}");
    }
    clean(&r.hw);
}

#[test]
fn x4_the_spi_dma_requests_open_in_rm0090s_order_and_close_at_the_end() {
    let mut r = rig();
    let p = plan(64, SpiMode::MODE0, 5);
    assert_eq!(r.port.run(&Action::Transfer(p)), Started::Running);
    {
        let m = r.hw.model();
        assert_eq!(
            m.spi_cr2() & (SPI_CR2_RXDMAEN | SPI_CR2_TXDMAEN),
            SPI_CR2_RXDMAEN | SPI_CR2_TXDMAEN
        );
        assert_ne!(m.stream_cr(1, 3) & DMA_CR_EN, 0, "RX stream on");
        assert_eq!(
            m.violations(),
            &[] as &[String],
            "RXDMAEN, streams, TXDMAEN"
        );
    }
    let _ = r.port.abort();
    let r2 = r.run(Action::Transfer(p), 0);
    assert!(matches!(r2, Started::Ended(Ok(_))));
    assert_eq!(r.hw.model().spi_cr2() & 0b11, 0, "both requests closed");
    clean(&r.hw);
}

#[test]
fn x5_a_stopped_transfer_lets_spi2_finish_its_frame_before_spe_clears() {
    let mut r = rig();
    let p = plan(256, SpiMode::MODE3, 50);
    assert_eq!(r.port.run(&Action::Transfer(p)), Started::Running);
    // Mid-transfer: 3 frames of 48.8 µs in.
    let t = r.hw.model().now() + cycles_of_ns(150_000);
    r.hw.model_mut().advance_to(t);
    assert_eq!(r.port.abort(), Some(Err(IoExtError::Timeout)));
    let m = r.hw.model();
    assert_eq!(m.spi_cr1() & SPI_CR1_SPE, 0);
    assert_eq!(m.spi_cr2() & 0b11, 0);
    assert!(m.sck(), "SCK back at CPOL = 1");
    drop(m);
    clean(&r.hw);
    r.check(plan(16, SpiMode::MODE3, 50));
    clean(&r.hw);
}

// ------------------------------------------------- X6–X9: DMA --

#[test]
fn x6_x7_x8_the_streams_are_the_ports_on_their_channels_registers_and_sizes() {
    let mut r = rig();
    for (p, ctl, streams) in [
        (
            plan(8, SpiMode::MODE0, 5),
            1u8,
            [(3u8, 0u32, SPI2_DR, 0u32), (4, 0, SPI2_DR, 0)],
        ),
        (
            plan(9, SpiMode::MODE0, 5),
            2,
            [(2, 6, GPIOB_IDR, 1), (6, 6, GPIOB_BSRR, 2)],
        ),
    ] {
        assert_eq!(r.port.run(&Action::Transfer(p)), Started::Running);
        let m = r.hw.model();
        for (s, ch, par, size) in streams {
            let cr = m.stream_cr(ctl, s);
            assert_eq!(
                (cr & DMA_CR_CHSEL_MASK) >> DMA_CR_CHSEL_SHIFT,
                ch,
                "DMA{ctl} S{s}"
            );
            assert_eq!(m.stream_par(ctl, s), par);
            assert_eq!((cr & DMA_CR_PSIZE_MASK) >> DMA_CR_PSIZE_SHIFT, size);
            assert_eq!((cr & DMA_CR_MSIZE_MASK) >> DMA_CR_MSIZE_SHIFT, size);
        }
        assert_eq!(m.violations(), &[] as &[String]);
        drop(m);
        let _ = r.port.abort();
    }
    clean(&r.hw);
}

#[test]
fn x6_transfer_after_transfer_rearms_the_streams_only_while_disabled_with_flags_clear() {
    let mut r = rig();
    for k in 0..24u16 {
        let mode = SpiMode::ALL[usize::from(k % 4)];
        let bits = if k % 3 == 0 { 9 } else { 16 };
        r.check(plan(bits, mode, 5));
    }
    clean(&r.hw); // X6 violations would be listed
}

#[test]
fn x6_a_flag_left_between_transfers_is_cleared_before_the_stream_is_enabled() {
    // A late event between two transfers leaves a flag on a stream whose
    // interrupt is off (the output streams): the next start clears it
    // before EN, on both engines.
    let mut r = rig();
    for (ctl, stream, p) in [
        (1u8, 4u8, plan(16, SpiMode::MODE0, 5)),
        (2, 6, plan(9, SpiMode::MODE0, 5)),
    ] {
        r.check(p);
        r.hw.model_mut()
            .raise(ctl, stream, Flags::HTIF.union(Flags::TCIF));
        r.check(p);
        assert!(r.hw.model().stream_flags(ctl, stream).is_empty());
    }
    clean(&r.hw);
}

/// Each of the four DMA streams with a plan that runs on it: the SPI
/// engine's (64 bits: DMA1 S3 transmit, S4 receive), then the timer
/// engine's (33 bits: DMA2 S2 samples, S6 the MOSI table).
fn each_stream() -> [(TransferPlan, u8, u8); 4] {
    let spi = plan(64, SpiMode::MODE0, 5);
    let timer = plan(33, SpiMode::MODE3, 5);
    [(spi, 1, 3), (spi, 1, 4), (timer, 2, 2), (timer, 2, 6)]
}

#[test]
fn x9_a_transfer_error_on_any_stream_ends_the_transfer_as_a_dma_error_and_the_next_works() {
    for (p, ctl, stream) in each_stream() {
        let mut r = rig();
        r.hw.model_mut().fail_next(ctl, stream, Flags::TEIF);
        assert_eq!(
            r.transfer(p),
            Err(IoExtError::Dma),
            "TEIF on DMA{ctl} stream {stream}"
        );
        assert!(r.hw.model().cs_high());
        clean(&r.hw);
        next_transfer_is_whole(&mut r, "the error");
    }
}

#[test]
fn fifo_errors_follow_the_one_rule_counted_unless_the_peripheral_waits_for_the_data() {
    // (plan, DMA, stream, counts): the SPI engine's transmit stream feeds a
    // master that clocks only what it has; every other stream's FEIF is an
    // error (the receive streams fell behind their peripheral, the MOSI
    // table's timer does not wait).
    for ((p, ctl, stream), counts) in each_stream().into_iter().zip([true, false, true, true]) {
        let mut r = rig();
        r.hw.model_mut().fail_next(ctl, stream, Flags::FEIF);
        if counts {
            assert_eq!(
                r.transfer(p),
                Err(IoExtError::Dma),
                "FEIF on DMA{ctl} S{stream}"
            );
        } else {
            r.check(p);
        }
        clean(&r.hw);
    }
}

#[test]
fn a_stuck_stream_is_aborted_at_the_plans_timeout_and_the_next_transfer_works() {
    for (p, ctl, stream) in [
        (plan(256, SpiMode::MODE1, 1), 1u8, 3u8),
        (plan(256, SpiMode::MODE1, 1), 1, 4),
        (plan(37, SpiMode::MODE2, 5), 2, 2),
        (plan(9, SpiMode::MODE0, 255), 2, 6),
    ] {
        let mut r = rig();
        r.hw.model_mut().stall(ctl, stream, true);
        let t0 = r.hw.model().now();
        let result = r.transfer(p);
        let took_us = (r.hw.model().now() - t0) / 168;
        // A stuck MOSI stream still lets the samples complete: the end
        // finds the MOSI stream unfinished (no TCIF) and reports it.
        if (ctl, stream) == (2, 6) {
            assert_eq!(result, Err(IoExtError::Dma));
        } else {
            assert_eq!(result, Err(IoExtError::Timeout), "DMA{ctl} S{stream}");
            assert!(took_us >= p.timeout_us(), "aborted at the timeout");
        }
        let m = r.hw.model();
        assert!(m.cs_high());
        assert_eq!(m.sck(), p.mode.cpol, "SCK back at CPOL");
        assert_eq!(m.tim_cr1() & TIM_CR1_CEN, 0);
        assert_eq!(m.spi_cr2() & 0b11, 0);
        drop(m);
        clean(&r.hw);
        r.hw.model_mut().stall(ctl, stream, false);
        next_transfer_is_whole(&mut r, "the abort");
    }
}

// -------------------------------------------- X10, X11: TIM1 --

#[test]
fn x10_x11_the_bit_engine_makes_exactly_bits_periods_of_the_plans_length() {
    let mut r = rig();
    for n in [0u8, 22, 50, 255] {
        for bits in [1u16, 7, 9, 33] {
            for mode in [SpiMode::MODE0, SpiMode::MODE3] {
                let p = plan(bits, mode, n);
                let Engine::Timer { psc, period } = p.clock.engine else {
                    panic!("{bits} bits: the timer engine")
                };
                r.check(p);
                let w = last_window(&r.hw);
                window_against(&w, &[p]).unwrap();
                let ticks = (u64::from(psc) + 1) * u64::from(period);
                for pair in w.edges.chunks(2).collect::<Vec<_>>().windows(2) {
                    assert_eq!(pair[1][0] - pair[0][0], ticks, "N {n}");
                }
                let t = p.timer().unwrap();
                // The active phase: leading to trailing edge.
                for e in w.edges.chunks(2) {
                    let active = e[1] - e[0];
                    assert_eq!(active, ticks - u64::from(t.ccr_sck) * (u64::from(psc) + 1));
                }
                assert_eq!(r.hw.model().tim_cr1() & TIM_CR1_CEN, 0, "one pulse over");
                assert_eq!(r.hw.model().tim_dier(), 0, "requests closed");
            }
        }
    }
    clean(&r.hw);
}

#[test]
fn the_first_edge_is_never_earlier_than_the_plans_half_period_for_any_n_on_either_engine() {
    // The odd-period flaw: ⌊period / 2⌋ put the first edge 1 107 ns after
    // CS fell at N = 22, where the plan promises 1 111 ns.
    let mut r = rig();
    let p = plan(9, SpiMode::MODE0, 22);
    assert_eq!(p.half_period_ns(), 1_111);
    r.check(p);
    let w = last_window(&r.hw);
    let start = w.engine_start.expect("TIM1 started after CS fell");
    // 187 ticks from CEN to the first edge: 1 113 ns.
    assert_eq!(w.edges[0] - start, 187);
    let first_ns = (w.edges[0] - w.fell) * 1_000_000_000 / CLOCK_HZ;
    assert!(first_ns >= 1_111, "first edge {first_ns} ns after CS fell");
    assert!(first_ns <= 1_113 + 60, "and not much later: {first_ns} ns");
    for n in 0..=255u8 {
        for bits in [8u16, 9] {
            let p = plan(bits, SpiMode::ALL[usize::from(n % 4)], n);
            r.check(p);
            window_against(&last_window(&r.hw), &[p])
                .unwrap_or_else(|e| panic!("N {n}, {bits} bits: {e}"));
        }
    }
    clean(&r.hw);
}

// --------------------------------------------- X12, X13: pins --

#[test]
fn x12_only_the_ports_pins_change_inside_the_critical_section_and_disable_releases_them() {
    let mut r = rig();
    r.check(plan(16, SpiMode::MODE0, 5));
    let moder = r.hw.model().moder();
    assert_eq!((moder >> 26) & 0b11, GPIO_MODE_AF, "SCK AF");
    assert_eq!((moder >> 30) & 0b11, GPIO_MODE_AF, "MOSI AF5");
    r.check(plan(9, SpiMode::MODE0, 5));
    let moder = r.hw.model().moder();
    assert_eq!((moder >> 30) & 0b11, GPIO_MODE_OUTPUT, "MOSI a GPIO output");
    assert_eq!(r.run(Action::Disable, 0), Started::Released);
    let m = r.hw.model();
    assert_eq!((m.moder() >> 26) & 0b11, GPIO_MODE_INPUT, "SCK released");
    assert_eq!((m.moder() >> 30) & 0b11, GPIO_MODE_INPUT, "MOSI released");
    assert_eq!(
        (m.moder() >> 22) & 0b11,
        GPIO_MODE_OUTPUT,
        "CS stays an output"
    );
    assert_eq!(m.spi_cr1() & SPI_CR1_SPE, 0);
    drop(m);
    clean(&r.hw);
    // And the next transfer takes them again.
    r.check(plan(16, SpiMode::MODE0, 5));
    clean(&r.hw);
}

#[test]
fn x13_engine_switches_and_cpol_changes_move_sck_only_while_cs_is_high() {
    let mut r = rig();
    let before = r.hw.model().stray_edges();
    // Same CPOL, both engines, back and forth: SCK never moves with CS
    // high.
    for k in 0..6u16 {
        r.check(plan(if k % 2 == 0 { 16 } else { 9 }, SpiMode::MODE1, 5));
    }
    assert_eq!(r.hw.model().stray_edges(), before);
    // Each CPOL change moves SCK once, with CS high (X13 in the model).
    for (k, mode) in [
        SpiMode::MODE3,
        SpiMode::MODE0,
        SpiMode::MODE2,
        SpiMode::MODE1,
    ]
    .into_iter()
    .enumerate()
    {
        r.check(plan(16, mode, 5));
        assert_eq!(
            r.hw.model().stray_edges(),
            before + k as u32 + 1,
            "{mode:?}"
        );
    }
    clean(&r.hw);
}

// ------------------------------------------ every plan shape --

#[test]
fn every_plan_shape_through_driver_and_model_gives_the_bits_the_logic_expects() {
    let mut r = rig();
    let mut shapes = 0;
    for bits in BITS {
        for mode in SpiMode::ALL {
            // SPI engine where the bit count allows (N = 0, 5, 50), the
            // timer engine at N = 61 (no SPI divider) and 255, and at every
            // N for the odd counts.
            for n in [0u8, 5, 22, 50, 61, 255] {
                let p = plan(bits, mode, n);
                r.check(p);
                window_against(&last_window(&r.hw), &[p])
                    .unwrap_or_else(|e| panic!("{bits} bits {mode:?} N {n}: {e}"));
                shapes += 1;
            }
        }
    }
    assert_eq!(shapes, 9 * 4 * 6);
    clean(&r.hw);
}

#[test]
fn cs_hold_joins_transfers_into_one_window_across_both_engines() {
    let mut r = rig();
    for (a, b, c) in [(8u16, 9u16, 16u16), (33, 32, 7), (255, 1, 256)] {
        for mode in [SpiMode::MODE0, SpiMode::MODE3] {
            let mut pa = plan(a, mode, 5);
            pa.cs_hold = true;
            let mut pb = plan(b, mode, 5);
            pb.cs_low_before = true;
            pb.cs_hold = true;
            let mut pc = plan(c, mode, 5);
            pc.cs_low_before = true;
            let windows = r.hw.model().windows().len();
            r.check(pa);
            assert!(!r.hw.model().cs_high(), "held");
            r.check(pb);
            r.check(pc);
            let m = r.hw.model();
            assert_eq!(m.windows().len(), windows + 1, "one CS window");
            window_against(m.windows().last().unwrap(), &[pa, pb, pc]).unwrap();
        }
    }
    clean(&r.hw);
}

#[test]
fn slow_interrupts_only_delay_the_end() {
    for latency in [500u64, 2_000, 20_000] {
        let mut r = rig();
        for p in [plan(256, SpiMode::MODE0, 0), plan(33, SpiMode::MODE2, 50)] {
            match r.run(Action::Transfer(p), latency) {
                Started::Ended(Ok(got)) => assert_eq!(got, wire_transfer(&mut r.logic, &p)),
                other => panic!("{other:?}"),
            }
            window_against(&last_window(&r.hw), &[p]).unwrap();
        }
        clean(&r.hw);
    }
}

#[test]
fn a_second_start_while_one_runs_and_an_empty_plan_are_refused() {
    let mut r = rig();
    let p = plan(16, SpiMode::MODE0, 5);
    assert_eq!(r.port.run(&Action::Transfer(p)), Started::Running);
    assert_eq!(
        r.port.run(&Action::Transfer(p)),
        Started::Ended(Err(IoExtError::Busy))
    );
    assert_eq!(r.port.abort(), Some(Err(IoExtError::Timeout)));
    assert_eq!(r.port.abort(), None, "nothing left to abort");
    let mut empty = plan(8, SpiMode::MODE0, 5);
    empty.bits = 0;
    assert_eq!(
        r.port.run(&Action::Transfer(empty)),
        Started::Ended(Err(IoExtError::BadPlan))
    );
    clean(&r.hw);
}

// --------------------------------------------- the model itself --

#[test]
fn model_a_stream_register_written_while_enabled_and_flags_left_set_are_recorded() {
    use drivers_core::dma::DmaReg;
    let mut hw = IoHandle::new(ShiftRegs::new(1, 1));
    let dma = IoReg::Dma2;
    hw.write(dma(DmaReg::Par(2)), GPIOB_IDR);
    hw.write(dma(DmaReg::M0ar(2)), host_tests::rm0090::ioext::SAMPLES);
    hw.write(dma(DmaReg::Ndtr(2)), 4);
    let cr = (6 << DMA_CR_CHSEL_SHIFT)
        | DMA_CR_MINC
        | (1 << DMA_CR_PSIZE_SHIFT)
        | (1 << DMA_CR_MSIZE_SHIFT);
    hw.write(dma(DmaReg::Cr(2)), cr | DMA_CR_EN);
    assert_eq!(
        hw.model().violations(),
        &[] as &[String],
        "a correct enable"
    );
    hw.write(dma(DmaReg::Ndtr(2)), 8);
    let v = hw.model().violations().to_vec();
    assert!(
        v.iter()
            .any(|s| s.starts_with("X6") && s.contains("written while the stream is enabled")),
        "{v:?}"
    );
    // Disabled, a flag of the last transfer left set, enabled again.
    hw.write(dma(DmaReg::Cr(2)), cr);
    hw.model_mut().raise(2, 2, Flags::TCIF);
    hw.write(dma(DmaReg::Cr(2)), cr | DMA_CR_EN);
    let v = hw.model().violations().to_vec();
    assert!(v.iter().any(|s| s.contains("flags still set")), "{v:?}");
}

#[test]
fn model_txdmaen_before_the_tx_stream_and_sck_clocked_with_cs_high_are_recorded() {
    let mut hw = IoHandle::new(ShiftRegs::new(1, 1));
    let spi = IoReg::Spi;
    hw.write(
        spi(SpiReg::Cr1),
        SPI_CR1_MSTR | SPI_CR1_SSM | SPI_CR1_SSI | SPI_CR1_SPE,
    );
    hw.masked(|hw| {
        hw.write(
            IoReg::Gpio(GpioReg::Afrh),
            (5 << 20) | (5 << 24) | (5 << 28),
        );
        hw.write(
            IoReg::Gpio(GpioReg::Moder),
            (0b01 << 22) | (0b10 << 26) | (0b10 << 28) | (0b10 << 30),
        );
    });
    hw.write(spi(SpiReg::Cr2), SPI_CR2_TXDMAEN);
    // A byte by the CPU with CS still high.
    hw.write(spi(SpiReg::Dr), 0xA5);
    let t = hw.model().now() + 200;
    hw.model_mut().advance_to(t);
    let v = hw.model().violations().to_vec();
    assert!(v.iter().any(|s| s.starts_with("X4")), "{v:?}");
    assert!(v.iter().any(|s| s.starts_with("X13: SCK clocked")), "{v:?}");
}

#[test]
fn model_gpio_fields_of_other_pins_and_writes_outside_the_critical_section_are_recorded() {
    let mut hw = IoHandle::new(ShiftRegs::new(1, 1));
    let moder = hw.read(IoReg::Gpio(GpioReg::Moder));
    hw.write(IoReg::Gpio(GpioReg::Moder), moder | 0b01);
    hw.write(IoReg::Gpio(GpioReg::Bsrr), 1 << 3);
    let v = hw.model().violations().to_vec();
    assert!(
        v.iter().any(|s| s.contains("outside the critical section")),
        "{v:?}"
    );
    assert!(v.iter().any(|s| s.contains("changes another pin")), "{v:?}");
    assert!(v.iter().any(|s| s.contains("drives another pin")), "{v:?}");
}

// ------------------------------------------------- the slip --

thread_local! {
    /// Extra cycles before the held CS write (the slip made worse).
    static LATE: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// The driver on the model with one step mutated: the CS-low write held
/// back until just after the write that starts the engine (TIM1's CEN,
/// SPI2's TXDMAEN) — "starting SCK before CS falls".
#[derive(Clone, Debug)]
struct CsAfterStart {
    hw: IoHandle,
    held: Option<u32>,
}

impl Regs<IoReg> for CsAfterStart {
    fn read(&mut self, reg: IoReg) -> u32 {
        self.hw.read(reg)
    }

    fn write(&mut self, reg: IoReg, value: u32) {
        let cs_low = 1 << (16 + u32::from(PINS.cs));
        if reg == IoReg::Gpio(GpioReg::Bsrr) && value == cs_low {
            self.held = Some(value);
            return;
        }
        self.hw.write(reg, value);
        let starts = matches!(
            (reg, value),
            (IoReg::Tim(TimReg::Cr1), v) if v & TIM_CR1_CEN != 0
        ) || matches!((reg, value), (IoReg::Spi(SpiReg::Cr2), v) if v & SPI_CR2_TXDMAEN != 0);
        if starts {
            if let Some(v) = self.held.take() {
                let late = LATE.with(|l| l.get());
                self.hw.delay_cycles(late);
                self.hw.write(IoReg::Gpio(GpioReg::Bsrr), v);
            }
        }
    }
}

impl IoExtHw for CsAfterStart {
    const PINS: drivers_core::ioext_spi::Pins = PINS;

    fn delay_cycles(&mut self, cycles: u32) {
        self.hw.delay_cycles(cycles);
    }

    fn masked<R>(&mut self, f: impl FnOnce(&mut Self) -> R) -> R {
        let mut hw = self.hw.clone();
        hw.masked(|_| f(self))
    }

    fn buffers<R>(&mut self, f: impl FnOnce(&mut IoExtBuffers) -> R) -> R {
        self.hw.buffers(f)
    }

    fn address(&self, target: Target) -> u32 {
        self.hw.address(target)
    }
}

#[test]
fn slip_the_model_catches_the_engine_started_before_cs_falls() {
    // CS falls one register access after the start: the first edge comes
    // short of the plan's half period on both engines (the bit engine at
    // N = 22: 187 ticks less the access, the SPI engine in mode 1 at N = 0:
    // with the first frame, a DMA latency after TXDMAEN).
    for (p, promise) in [
        (plan(9, SpiMode::MODE0, 22), "promises 1111 ns"),
        (plan(16, SpiMode::MODE1, 0), "promises 24 ns"),
    ] {
        let hw = IoHandle::new(ShiftRegs::new(CHIPS, CHIPS));
        let mut r = rig_on(
            CsAfterStart {
                hw: hw.clone(),
                held: None,
            },
            hw.clone(),
        );
        assert!(r.transfer(p).is_ok());
        let e = window_against(&last_window(&hw), &[p]).unwrap_err();
        assert!(
            e.starts_with("first SCK edge") && e.contains(promise),
            "{e}"
        );
    }
    // Later still (the CS write behind 16 more cycles): SPI2 clocks with
    // CS high, which the model records, and the bits are wrong.
    let hw = IoHandle::new(ShiftRegs::new(CHIPS, CHIPS));
    let mut r = rig_on(
        CsAfterStart {
            hw: hw.clone(),
            held: None,
        },
        hw.clone(),
    );
    let p = plan(16, SpiMode::MODE1, 0);
    LATE.with(|l| l.set(16));
    let got = r.transfer(p).unwrap();
    LATE.with(|l| l.set(0));
    let v = hw.model().violations().to_vec();
    assert!(
        v.iter()
            .any(|s| s.starts_with("X13: SCK clocked by SPI2 or TIM1 while CS is high")),
        "{v:?}"
    );
    assert_ne!(
        got,
        wire_transfer(&mut r.logic, &p),
        "and the bits are wrong"
    );
}
