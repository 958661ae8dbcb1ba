//! The powerSTEP01 chain on SPI1 and the common CS line: a batch of CS
//! windows clocked by DMA ([`ChainDma`]) for the control tick, and blocking
//! windows ([`ChainPort`], the bridge's [`ChainBus`]) for chain detection at
//! boot and the recovery windows after a bus error. Which bytes go into a
//! window is the logic crate's job; this driver moves them and decides
//! nothing else.
//!
//! # SPI1
//!
//! Master, mode 3 (CPOL = 1, CPHA = 1), MSB first, 8-bit frames, software
//! NSS. SCK is the fastest APB2 division that does not exceed
//! [`SCK_MAX_HZ`]: with APB2 = 84 MHz that is /32 = **2.625 MHz** (/16
//! would be 5.25 MHz, above the chip's 5 MHz), 3.05 µs a byte.
//!
//! # A batch by DMA
//!
//! Up to [`MAX_WINDOWS`] windows of N ≤ [`MAX_DEVICES`] bytes, copied out
//! of the bridge's plan by [`ChainDma::start`] into this driver's `'static`
//! buffers. DMA2 stream 3 channel 3 (SPI1_TX) moves a window's N bytes out,
//! stream 0 channel 3 (SPI1_RX) the N bytes that come back (RM0090 table
//! 43; stream 2, SPI1_RX's other choice, is the I/O extension's). Every
//! window, the first included, goes through three phases, each ended by an
//! interrupt, so the CPU never waits on the bus:
//!
//! 1. **gap**: CS high for at least [`CS_DESELECT_NS`] (t_disCS), timed by
//!    TIM7 in one-pulse mode (`TIM7` interrupt);
//! 2. **setup**: CS low, then at least [`CS_SETUP_NS`] (t_setCS) before the
//!    first clock edge, timed by TIM7 again (`TIM7` interrupt);
//! 3. **shift**: TXDMAEN set, the N bytes go out and in; stream 0's
//!    transfer-complete interrupt (`DMA2_STREAM0`) raises CS, arms both
//!    streams for the next window and starts its gap — or, after the last
//!    window, marks the batch done.
//!
//! The control tick collects the batch with [`ChainDma::poll`] at its next
//! run. The streams are armed before TXDMAEN opens the TX request, and TX
//! requests are closed again (TXDMAEN = 0) before the TX stream is enabled
//! for the next window, so no byte can leave while CS is high. RXDMAEN stays
//! set for the whole batch: nothing is received without a clock.
//!
//! # Errors (never a hang)
//!
//! * A transfer or direct-mode error of either stream, a FIFO error of the
//!   receive stream (a byte lost), SPI1 overrun or mode fault:
//!   [`ChainSpiError::Dma`] / [`ChainSpiError::Spi`]. The transmit stream's
//!   FIFO-error flag is ignored: in direct mode, memory to peripheral, it
//!   also rises when the stream is enabled with the request already active
//!   (nothing is lost: the master's clock waits for its data).
//! * A batch not over by its deadline (twice its nominal time + 100 µs,
//!   from [`ChainDma::start`]): [`ChainDma::poll`] stops the streams and
//!   TIM7, raises CS and reports [`ChainSpiError::Timeout`] (or `Dma` if the
//!   transmit stream, whose errors raise no interrupt here, has an error).
//! * SPI1 still busy after the last byte of a window (bounded status polls,
//!   normally none): [`ChainSpiError::Stuck`].
//!
//! The bridge counts each as a chain error (`tick_end(Err(..))`), brings the
//! chain back in step with blocking windows and sets every chip up again.
//!
//! # Blocking windows
//!
//! [`ChainPort::window`]: CS high for t_disCS (a DMA batch may have raised
//! it just before), CS low, t_setCS, the bytes polled through SPI1_DR, CS
//! high, t_disCS — busy-waits of CPU cycles, at boot and after a bus error
//! only. Refused ([`ChainSpiError::Busy`]) while a DMA batch runs.
//!
//! # Unsafe
//!
//! SPI1 and the CS pin are shared by the two halves through their register
//! blocks (the PAC singleton and the HAL pin are consumed by
//! [`chain_spi`]); DMA2 streams 0 and 3 are used through DMA2's register
//! block, whose singleton the I/O extension's driver owns (it touches only
//! streams 2 and 6, and the flag-clear registers are write-1-to-clear). The
//! DMA addresses are SPI1_DR and this driver's `'static` buffers.
//!
//! # What is not verified
//!
//! Built, never run on a board: the register sequences follow RM0090;
//! `tests/chain_spi.rs` (board only) checks the window timing, the
//! completion interrupt and that the CPU runs free during a batch. QEMU
//! 7.2 has no DMA controller and no TIM7, so the QEMU image's chain is the
//! simulator (`platform/qemu.rs`) and this path is only built there.

// Register blocks shared by the two halves, DMA addresses (module docs).
#![allow(unsafe_code)]

use bridge_logic::bridge::BatchState;
use bridge_logic::powerstep::chain::{ChainBus, Frames, Plan, MAX_DEVICES, MAX_WINDOWS};
use core::sync::atomic::{compiler_fence, AtomicBool, Ordering};
use cortex_m::peripheral::NVIC;
use stm32f4xx_hal::pac::{self, Interrupt};
use stm32f4xx_hal::rcc::{Enable, Rcc, Reset};

use crate::board::{
    ChainCs, ChainGapTimer, ChainMiso, ChainMosi, ChainSck, ChainSpi, CHAIN_CS_PIN,
};

/// The powerSTEP01 SPI limit is 5 MHz; stay at or below 4 MHz, the rate the
/// reference libraries use on long daisy chains.
pub const SCK_MAX_HZ: u32 = 4_000_000;
/// CS low to first SCK edge (t_setCS of the family datasheets).
pub const CS_SETUP_NS: u32 = 350;
/// CS high between windows (t_disCS).
pub const CS_DESELECT_NS: u32 = 800;

/// DMA2 streams of SPI1 and their request channel (RM0090 table 43).
const RX_STREAM: usize = 0;
const TX_STREAM: usize = 3;
const SPI1_CHANNEL: u8 = 3;

/// DMA2_LISR / LIFCR bits of streams 0 and 3 (RM0090 10.5.1).
pub const FEIF0: u32 = 1 << 0;
pub const DMEIF0: u32 = 1 << 2;
pub const TEIF0: u32 = 1 << 3;
pub const TCIF0: u32 = 1 << 5;
pub const DMEIF3: u32 = 1 << 24;
pub const TEIF3: u32 = 1 << 25;
const ERRORS: u32 = FEIF0 | DMEIF0 | TEIF0 | DMEIF3 | TEIF3;

/// Status polls before SPI1 counts as stuck on the blocking path: far
/// beyond a byte (3.05 µs ≈ 512 cycles, a poll takes several), short
/// enough not to hang.
const POLLS: u32 = 20_000;
/// Status polls inside an interrupt or a lock: BSY after a window's last
/// byte (clears within one SCK period of the last edge, 64 cycles), a
/// stream's EN after it was disabled (clears after the current beat); 256
/// polls are ≥ 4.5 µs.
const SHORT_POLLS: u32 = 256;

/// Set while a DMA batch owns SPI1 and CS.
static BATCH_RUNNING: AtomicBool = AtomicBool::new(false);

/// Why the chain bus failed (the bridge counts it as a chain error).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum ChainSpiError {
    /// A DMA stream reported a transfer, direct-mode or (receive) FIFO error.
    Dma,
    /// SPI1 reported an overrun or a mode fault.
    Spi,
    /// SPI1 did not take or give a byte, or stayed busy, within the bound.
    Stuck,
    /// The batch was not over by its deadline: stopped.
    Timeout,
    /// A batch is running: nothing was started, no window clocked.
    Busy,
    /// The plan has no window or no device, or more than the buffers hold.
    BadPlan,
}

/// A batch's buffers: `'static`, so the streams can own them while it runs.
/// Row w holds window w (the first N bytes are used).
pub struct ChainBuffers {
    tx: Frames,
    rx: Frames,
}

impl ChainBuffers {
    pub const fn new() -> ChainBuffers {
        ChainBuffers {
            tx: [[0; MAX_DEVICES]; MAX_WINDOWS],
            rx: [[0; MAX_DEVICES]; MAX_WINDOWS],
        }
    }
}

impl ChainBuffers {
    /// The receive rows (QEMU's stand-in clocks its simulated chips into
    /// them).
    pub fn rx_mut(&mut self) -> &mut Frames {
        &mut self.rx
    }
}

impl Default for ChainBuffers {
    fn default() -> Self {
        Self::new()
    }
}

/// Smallest SPI baud-rate divider (2, 4, …, 256) giving at most `max_hz`,
/// and its CR1.BR code.
fn sck_divider(pclk_hz: u32, max_hz: u32) -> (u32, u8) {
    let mut div = 2;
    let mut br = 0;
    while div < 256 && pclk_hz / div > max_hz {
        div *= 2;
        br += 1;
    }
    (div, br)
}

/// Clock cycles of `hz` for `ns` nanoseconds, rounded up.
fn cycles(ns: u32, hz: u32) -> u32 {
    let c = (u64::from(ns) * u64::from(hz)).div_ceil(1_000_000_000);
    u32::try_from(c).unwrap_or(u32::MAX)
}

/// SPI1's registers.
fn spi1() -> &'static pac::spi1::RegisterBlock {
    // SAFETY: SPI1 is always mapped; its PAC singleton was consumed by
    // `chain_spi`, and only `ChainPort` and `ChainDma` use it, never at the
    // same time: `ChainPort` refuses while `BATCH_RUNNING` is set, which
    // `ChainDma` sets before it touches SPI1 for a batch and clears after.
    unsafe { &*pac::SPI1::ptr() }
}

/// DMA2's registers (streams 0 and 3 are this driver's).
fn dma2() -> &'static pac::dma2::RegisterBlock {
    // SAFETY: DMA2 is always mapped. This driver writes only streams 0 and
    // 3 and their bits of LIFCR (write-1-to-clear: other streams' bits are
    // written 0, which changes nothing); the I/O extension's driver uses
    // streams 2 and 6 only.
    unsafe { &*pac::DMA2::ptr() }
}

/// CS (PA4) high or low through GPIOA_BSRR.
fn cs(high: bool) {
    // SAFETY: GPIOA is always mapped; BSRR writes are atomic and touch only
    // the bit written. The CS pin's HAL handle was consumed by `chain_spi`
    // (configured as a push-pull output, high); nothing else drives it.
    let gpioa = unsafe { &*pac::GPIOA::ptr() };
    gpioa.bsrr().write(|w| {
        if high {
            w.bs(CHAIN_CS_PIN).set_bit()
        } else {
            w.br(CHAIN_CS_PIN).set_bit()
        }
    });
}

/// Set SPI1 up (mode 3, MSB first, 8-bit, master, software NSS held high,
/// CR1.BR = `br`) and enable it.
fn configure_spi(br: u8) {
    let spi = spi1();
    spi.cr1().write(|w| {
        w.cpha()
            .set_bit()
            .cpol()
            .set_bit()
            .mstr()
            .set_bit()
            .br()
            .set(br & 0b111)
            .ssm()
            .set_bit()
            .ssi()
            .set_bit()
    });
    spi.cr2().reset();
    spi.cr1().modify(|_, w| w.spe().set_bit());
}

/// Read DR and SR: drops a stale byte and clears an overrun.
fn drain_spi() {
    let spi = spi1();
    let _ = spi.dr().read();
    let _ = spi.sr().read();
}

/// Wait (at most `polls` reads) until SPI1 is not busy; false if it stays
/// busy.
fn spi_idle(polls: u32) -> bool {
    (0..polls).any(|_| spi1().sr().read().bsy().bit_is_clear())
}

/// Take SPI1, TIM7 and the chain's pins as `board::configure` left them (CS
/// high): the blocking half for the bridge and the DMA half for the control
/// tick. Clocks and resets SPI1 and TIM7, clocks DMA2 (never reset: the I/O
/// extension uses it too).
pub fn chain_spi(
    spi: ChainSpi,
    pins: (ChainSck, ChainMiso, ChainMosi),
    cs_pin: ChainCs,
    tim: ChainGapTimer,
    bufs: &'static mut ChainBuffers,
    rcc: &mut Rcc,
) -> (ChainPort, ChainDma) {
    ChainSpi::enable(rcc);
    ChainSpi::reset(rcc);
    ChainGapTimer::enable(rcc);
    ChainGapTimer::reset(rcc);
    pac::DMA2::enable(rcc);
    let pclk = rcc.clocks.pclk2().raw();
    let sysclk = rcc.clocks.sysclk().raw();
    let timclk = rcc.clocks.timclk1().raw();
    let (div, br) = sck_divider(pclk, SCK_MAX_HZ);
    let sck_hz = pclk / div;
    // The pins keep the modes `board::configure` gave them; from here on
    // SPI1 and CS are driven through their registers (module docs).
    let _ = (spi, pins, cs_pin);
    cs(true);
    configure_spi(br);

    // TIM7: one-pulse, only an overflow raises the update interrupt; the
    // prescaler (1) is loaded by the UG event, which sets no flag with URS.
    tim.cr1().write(|w| w.opm().set_bit().urs().set_bit());
    tim.psc().write(|w| w.psc().set(0));
    tim.egr().write(|w| w.ug().set_bit());
    tim.sr().write(|w| w.uif().clear_bit());
    tim.dier().write(|w| w.uie().set_bit());

    // Both streams: byte to byte, memory incremented, direct mode. The
    // receive stream interrupts on transfer complete and its errors; the
    // transmit stream's errors raise no interrupt (its IRQ is not bound):
    // they are read at the receive stream's interrupt and at the deadline.
    let dr = spi1().dr().as_ptr() as u32;
    let d = dma2();
    for s in [RX_STREAM, TX_STREAM] {
        d.st(s).cr().modify(|_, w| w.en().disabled());
    }
    let rx = d.st(RX_STREAM);
    // SAFETY: the peripheral address is SPI1_DR.
    rx.par().write(|w| unsafe { w.pa().bits(dr) });
    rx.fcr().reset();
    rx.cr().write(|w| {
        w.chsel()
            .set(SPI1_CHANNEL)
            .dir()
            .peripheral_to_memory()
            .minc()
            .incremented()
            .pl()
            .very_high()
            .tcie()
            .enabled()
            .teie()
            .enabled()
            .dmeie()
            .enabled()
    });
    let tx = d.st(TX_STREAM);
    // SAFETY: the peripheral address is SPI1_DR.
    tx.par().write(|w| unsafe { w.pa().bits(dr) });
    tx.fcr().reset();
    tx.cr().write(|w| {
        w.chsel()
            .set(SPI1_CHANNEL)
            .dir()
            .memory_to_peripheral()
            .minc()
            .incremented()
            .pl()
            .high()
    });
    clear_flags();

    let gap_ticks = cycles(CS_DESELECT_NS, timclk);
    let setup_ticks = cycles(CS_SETUP_NS, timclk);
    let port = ChainPort {
        setup_cycles: cycles(CS_SETUP_NS, sysclk),
        deselect_cycles: cycles(CS_DESELECT_NS, sysclk),
        sck_hz,
    };
    let dma = ChainDma {
        tim,
        bufs,
        // The counter runs 0..=ARR and overflows one tick later, so ARR =
        // ticks waits at least `ticks` + 1 periods of the timer clock.
        gap_arr: u16::try_from(gap_ticks).unwrap_or(u16::MAX),
        setup_arr: u16::try_from(setup_ticks).unwrap_or(u16::MAX),
        timing: Timing::new(gap_ticks, setup_ticks, timclk, sck_hz),
        sck_hz,
        deselect_cycles: port.deselect_cycles,
        windows: 0,
        n: 0,
        window: 0,
        phase: Phase::Idle,
        deadline_us: 0,
        stats: ChainDmaStats::default(),
    };
    (port, dma)
}

/// Clear every flag of streams 0 and 3.
fn clear_flags() {
    dma2().lifcr().write(|w| {
        w.cfeif0()
            .set_bit()
            .cdmeif0()
            .set_bit()
            .cteif0()
            .set_bit()
            .chtif0()
            .set_bit()
            .ctcif0()
            .set_bit()
            .cfeif3()
            .set_bit()
            .cdmeif3()
            .set_bit()
            .cteif3()
            .set_bit()
            .chtif3()
            .set_bit()
            .ctcif3()
            .set_bit()
    });
}

// --- the blocking half --------------------------------------------------------

/// Blocking windows on SPI1 (the bridge's [`ChainBus`]): chain detection
/// and the recovery windows after a bus error.
pub struct ChainPort {
    setup_cycles: u32,
    deselect_cycles: u32,
    sck_hz: u32,
}

impl ChainPort {
    /// The SCK rate actually configured.
    pub fn sck_hz(&self) -> u32 {
        self.sck_hz
    }
}

impl ChainBus for ChainPort {
    type Error = ChainSpiError;

    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ChainSpiError> {
        if BATCH_RUNNING.load(Ordering::Acquire) {
            return Err(ChainSpiError::Busy);
        }
        // CS is high; a DMA batch may have raised it just now.
        cortex_m::asm::delay(self.deselect_cycles);
        cs(false);
        cortex_m::asm::delay(self.setup_cycles);
        let result = transfer_polled(tx, rx);
        cs(true);
        cortex_m::asm::delay(self.deselect_cycles);
        result
    }
}

/// Full duplex, byte by byte through SPI1_DR (pads with 0x00 / drops extra
/// bytes if the lengths ever differ; the chain always passes equal ones).
fn transfer_polled(tx: &[u8], rx: &mut [u8]) -> Result<(), ChainSpiError> {
    let spi = spi1();
    drain_spi();
    for i in 0..tx.len().max(rx.len()) {
        if !(0..POLLS).any(|_| spi.sr().read().txe().bit_is_set()) {
            return Err(ChainSpiError::Stuck);
        }
        let byte = tx.get(i).copied().unwrap_or(0);
        spi.dr8().write(|w| w.dr().set(byte));
        if !(0..POLLS).any(|_| spi.sr().read().rxne().bit_is_set()) {
            return Err(ChainSpiError::Stuck);
        }
        let got = spi.dr8().read().dr().bits();
        if let Some(slot) = rx.get_mut(i) {
            *slot = got;
        }
    }
    let sr = spi.sr().read();
    if sr.ovr().bit_is_set() || sr.modf().bit_is_set() {
        drain_spi();
        configure_spi(spi.cr1().read().br().bits());
        return Err(ChainSpiError::Spi);
    }
    if spi_idle(POLLS) {
        Ok(())
    } else {
        Err(ChainSpiError::Stuck)
    }
}

// --- the DMA half -------------------------------------------------------------

/// Where the batch is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Idle,
    /// CS high, TIM7 times t_disCS before window `window`.
    Gap,
    /// CS low, TIM7 times t_setCS.
    Setup,
    /// The window's bytes are on the wire.
    Shift,
    /// Over, not yet collected by `poll`.
    Done(Result<(), ChainSpiError>),
}

/// Counts since boot (the bridge counts chain errors of every kind).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
pub struct ChainDmaStats {
    pub batches: u32,
    pub windows: u32,
    pub dma_errors: u32,
    pub spi_errors: u32,
    pub stuck: u32,
    pub timeouts: u32,
}

/// The DMA half's times, worked out once (no division per batch).
#[derive(Clone, Copy, Debug)]
struct Timing {
    /// TIM7's gap and set-up, ns.
    gap_ns: u32,
    setup_ns: u32,
    /// Gap + set-up + 3 µs for a window's three interrupts, ns.
    window_ns: u32,
    /// One byte on the wire, ns (rounded up).
    byte_ns: u32,
}

impl Timing {
    fn new(gap_ticks: u32, setup_ticks: u32, timclk_hz: u32, sck_hz: u32) -> Timing {
        // ARR = ticks: the pulse lasts ticks + 1 timer-clock periods.
        let ns = |ticks: u32| {
            let t = (u64::from(ticks) + 1) * 1_000_000_000 / u64::from(timclk_hz.max(1));
            u32::try_from(t).unwrap_or(u32::MAX)
        };
        let (gap_ns, setup_ns) = (ns(gap_ticks), ns(setup_ticks));
        let byte = (8_000_000_000u64).div_ceil(u64::from(sck_hz.max(1)));
        Timing {
            gap_ns,
            setup_ns,
            window_ns: gap_ns.saturating_add(setup_ns).saturating_add(3_000),
            byte_ns: u32::try_from(byte).unwrap_or(u32::MAX),
        }
    }
}

/// The control tick's chain driver: batches of windows by DMA2 and TIM7
/// (module docs). `start` and `poll` from the control tick; `on_dma` from
/// `DMA2_STREAM0`, `on_timer` from `TIM7`.
pub struct ChainDma {
    tim: ChainGapTimer,
    bufs: &'static mut ChainBuffers,
    gap_arr: u16,
    setup_arr: u16,
    timing: Timing,
    sck_hz: u32,
    deselect_cycles: u32,
    windows: u8,
    n: u8,
    /// The window in its gap, setup or shift.
    window: u8,
    phase: Phase,
    deadline_us: u64,
    stats: ChainDmaStats,
}

impl ChainDma {
    /// Copy the plan's windows into the buffers and start the batch (its
    /// first gap). `now_us`: the monotonic's µs, for the deadline. The
    /// port is the bridge's blocking half (QEMU's stand-in clocks its
    /// simulated chips through it; the DMA does not need it).
    pub fn start(
        &mut self,
        plan: &Plan,
        _port: &mut ChainPort,
        now_us: u64,
    ) -> Result<(), ChainSpiError> {
        if self.phase != Phase::Idle {
            // Running, or over and not yet collected by `poll`.
            return Err(ChainSpiError::Busy);
        }
        let (windows, n) = (plan.windows(), plan.devices());
        if windows == 0 || windows > MAX_WINDOWS || n == 0 || n > MAX_DEVICES {
            return Err(ChainSpiError::BadPlan);
        }
        // Whole rows: two words each, no length to check.
        for (dst, src) in self.bufs.tx.iter_mut().zip(plan.frames()).take(windows) {
            *dst = *src;
        }
        let d = dma2();
        if !(0..SHORT_POLLS).any(|_| {
            d.st(RX_STREAM).cr().read().en().is_disabled()
                && d.st(TX_STREAM).cr().read().en().is_disabled()
        }) {
            self.stats.stuck = self.stats.stuck.saturating_add(1);
            return Err(ChainSpiError::Stuck);
        }
        // Window counts fit: at most 16 windows of 8 bytes.
        self.windows = windows as u8;
        self.n = n as u8;
        self.window = 0;
        self.deadline_us = now_us.saturating_add(self.bound_us());
        self.stats.batches = self.stats.batches.saturating_add(1);
        BATCH_RUNNING.store(true, Ordering::Release);
        drain_spi();
        spi1().cr2().modify(|_, w| w.rxdmaen().set_bit());
        self.arm();
        self.phase = Phase::Gap;
        self.timer(self.gap_arr);
        Ok(())
    }

    /// The batch as the control tick finds it. Done: its received windows
    /// are copied into `rx` (row w = window w). A batch past its deadline
    /// is stopped and reported as [`ChainSpiError::Timeout`].
    pub fn poll<'a>(&mut self, now_us: u64, rx: &'a mut Frames) -> BatchState<'a, ChainSpiError> {
        match self.phase {
            Phase::Idle => BatchState::Idle,
            Phase::Gap | Phase::Setup | Phase::Shift => {
                if now_us < self.deadline_us {
                    return BatchState::Running;
                }
                let tx_error = dma2().lisr().read().bits() & (TEIF3 | DMEIF3) != 0;
                let why = if tx_error {
                    self.stats.dma_errors = self.stats.dma_errors.saturating_add(1);
                    ChainSpiError::Dma
                } else {
                    self.stats.timeouts = self.stats.timeouts.saturating_add(1);
                    ChainSpiError::Timeout
                };
                self.stop();
                self.phase = Phase::Idle;
                BatchState::Done(Err(why))
            }
            Phase::Done(result) => {
                self.phase = Phase::Idle;
                match result {
                    Ok(()) => {
                        let w = usize::from(self.windows);
                        for (dst, src) in rx.iter_mut().zip(self.bufs.rx.iter()).take(w) {
                            *dst = *src;
                        }
                        BatchState::Done(Ok(rx))
                    }
                    Err(e) => BatchState::Done(Err(e)),
                }
            }
        }
    }

    /// `DMA2_STREAM0`: the receive stream's transfer complete or an error.
    pub fn on_dma(&mut self) {
        let lisr = dma2().lisr().read().bits();
        self.dma_event(lisr);
    }

    /// [`ChainDma::on_dma`] with DMA2_LISR as read (`lisr`): the cost bench
    /// feeds it under QEMU, whose DMA2 reads 0.
    pub fn dma_event(&mut self, lisr: u32) {
        clear_flags();
        if self.phase != Phase::Shift {
            // Nothing of ours on the wire (a stray flag).
            return;
        }
        if lisr & ERRORS != 0 {
            self.stats.dma_errors = self.stats.dma_errors.saturating_add(1);
            self.fail(ChainSpiError::Dma);
            return;
        }
        if lisr & TCIF0 == 0 {
            return;
        }
        let spi = spi1();
        let sr = spi.sr().read();
        if sr.ovr().bit_is_set() || sr.modf().bit_is_set() {
            self.stats.spi_errors = self.stats.spi_errors.saturating_add(1);
            self.fail(ChainSpiError::Spi);
            return;
        }
        // The last byte is in, its last edge has passed: SPI1 is normally
        // idle already.
        if sr.bsy().bit_is_set() && !spi_idle(SHORT_POLLS) {
            self.stats.stuck = self.stats.stuck.saturating_add(1);
            self.fail(ChainSpiError::Stuck);
            return;
        }
        spi.cr2().modify(|_, w| w.txdmaen().clear_bit());
        compiler_fence(Ordering::SeqCst);
        self.stats.windows = self.stats.windows.saturating_add(1);
        self.window = self.window.saturating_add(1);
        if self.window >= self.windows {
            cs(true);
            spi.cr2().modify(|_, w| w.rxdmaen().clear_bit());
            self.phase = Phase::Done(Ok(()));
            BATCH_RUNNING.store(false, Ordering::Release);
            return;
        }
        // Arm first, so the gap starts right at the CS rise.
        self.arm();
        self.phase = Phase::Gap;
        cs(true);
        self.timer(self.gap_arr);
    }

    /// `TIM7`: the gap or the setup time is over.
    pub fn on_timer(&mut self) {
        self.tim.sr().write(|w| w.uif().clear_bit());
        match self.phase {
            Phase::Gap => {
                cs(false);
                self.phase = Phase::Setup;
                self.timer(self.setup_arr);
            }
            Phase::Setup => {
                self.phase = Phase::Shift;
                compiler_fence(Ordering::SeqCst);
                spi1().cr2().modify(|_, w| w.txdmaen().set_bit());
            }
            Phase::Idle | Phase::Shift | Phase::Done(_) => {}
        }
    }

    /// Counts since boot.
    pub fn stats(&self) -> ChainDmaStats {
        self.stats
    }

    /// A batch is on the bus (one that is over but not yet collected by
    /// `poll` is not).
    pub fn is_running(&self) -> bool {
        matches!(self.phase, Phase::Gap | Phase::Setup | Phase::Shift)
    }

    /// The SCK rate actually configured.
    pub fn sck_hz(&self) -> u32 {
        self.sck_hz
    }

    /// The CS-high gap and the CS set-up time TIM7 makes, in ns.
    pub fn gap_and_setup_ns(&self) -> (u32, u32) {
        (self.timing.gap_ns, self.timing.setup_ns)
    }

    /// Nominal duration of the current batch, µs (rounded up): per window
    /// the gap, the set-up, the bytes and 3 µs for the three interrupts.
    pub fn nominal_us(&self) -> u64 {
        let t = &self.timing;
        let window_ns = t
            .window_ns
            .saturating_add(u32::from(self.n).saturating_mul(t.byte_ns));
        // 16 windows of 8 bytes at 2.625 MHz: 0.46 ms, far from saturating.
        u64::from(
            u32::from(self.windows)
                .saturating_mul(window_ns)
                .div_ceil(1_000),
        )
    }

    /// How long a batch may take before `poll` stops it.
    fn bound_us(&self) -> u64 {
        2 * self.nominal_us() + 100
    }

    /// Point both streams at window `self.window` and enable them (TX
    /// requests are closed: nothing moves until TXDMAEN).
    fn arm(&mut self) {
        let w = usize::from(self.window);
        let (Some(tx), Some(rx)) = (self.bufs.tx.get(w), self.bufs.rx.get_mut(w)) else {
            return;
        };
        let (tx, rx) = (tx.as_ptr() as u32, rx.as_mut_ptr() as u32);
        let n = u16::from(self.n);
        let d = dma2();
        clear_flags();
        let rs = d.st(RX_STREAM);
        // SAFETY: the memory address is row `w` of this driver's `'static`
        // receive buffer (MAX_DEVICES ≥ n bytes), read by the CPU only once
        // the batch is over.
        rs.m0ar().write(|w| unsafe { w.m0a().bits(rx) });
        rs.ndtr().write(|w| w.ndt().set(n));
        let ts = d.st(TX_STREAM);
        // SAFETY: row `w` of this driver's `'static` transmit buffer (n
        // bytes), not written while the batch runs.
        ts.m0ar().write(|w| unsafe { w.m0a().bits(tx) });
        ts.ndtr().write(|w| w.ndt().set(n));
        compiler_fence(Ordering::SeqCst);
        rs.cr().modify(|_, w| w.en().enabled());
        ts.cr().modify(|_, w| w.en().enabled());
    }

    /// TIM7 once, `arr` + 1 timer-clock periods, then its interrupt.
    fn timer(&mut self, arr: u16) {
        let tim = &self.tim;
        tim.arr().write(|w| w.arr().set(arr));
        tim.cnt().write(|w| w.cnt().set(0));
        tim.cr1()
            .write(|w| w.opm().set_bit().urs().set_bit().cen().set_bit());
    }

    /// End the batch with `why`, everything stopped.
    fn fail(&mut self, why: ChainSpiError) {
        self.stop();
        self.phase = Phase::Done(Err(why));
    }

    /// Stop TIM7 and both streams, close the SPI requests, let SPI1 finish
    /// its byte, raise CS and hold it high for t_disCS (error paths only).
    fn stop(&mut self) {
        self.tim.cr1().write(|w| w.opm().set_bit().urs().set_bit());
        self.tim.sr().write(|w| w.uif().clear_bit());
        let spi = spi1();
        spi.cr2()
            .modify(|_, w| w.txdmaen().clear_bit().rxdmaen().clear_bit());
        let d = dma2();
        for s in [RX_STREAM, TX_STREAM] {
            d.st(s).cr().modify(|_, w| w.en().disabled());
        }
        let _ = spi_idle(SHORT_POLLS);
        drain_spi();
        clear_flags();
        // An interrupt of the stopped batch may be pending: it would find
        // the next batch's phase.
        NVIC::unpend(Interrupt::TIM7);
        NVIC::unpend(Interrupt::DMA2_STREAM0);
        cs(true);
        cortex_m::asm::delay(self.deselect_cycles);
        BATCH_RUNNING.store(false, Ordering::Release);
    }
}
