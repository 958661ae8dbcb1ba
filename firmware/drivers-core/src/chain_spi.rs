//! The powerSTEP01 chain on SPI1 and the common CS line: one driver
//! ([`ChainSpi`], the only owner of SPI1, DMA2 streams 0/3, TIM7 and CS)
//! clocks a batch of CS windows by DMA for the control tick
//! ([`ChainSpi::start`] / [`ChainSpi::poll`]) and the blocking windows
//! ([`ChainSpi::window`], its [`ChainBus`]) for chain detection at boot and
//! the recovery windows after a bus error. Which bytes go into a window is
//! the logic crate's job; this driver moves them and decides nothing else.
//!
//! Every register access goes through a [`ChainHw`] — on the chip the
//! firmware's PAC glue (`firmware::drivers::chain_spi`: SPI1, DMA2, TIM7,
//! GPIOA_BSRR, NVIC, cycle delays), on the host the RM0090 model
//! `host_tests::rm0090::chain_spi` (SPI1 as master, DMA2 streams 0/3,
//! TIM7, CS timing, the simulated chips behind MISO).
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
//! of the bridge's plan by [`ChainSpi::start`] into this driver's `'static`
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
//! The control tick collects the batch with [`ChainSpi::poll`] at its next
//! run. The streams are armed before TXDMAEN opens the TX request, and TX
//! requests are closed again (TXDMAEN = 0) before the TX stream is enabled
//! for the next window, so no byte can leave while CS is high. RXDMAEN stays
//! set for the whole batch: nothing is received without a clock.
//!
//! # Errors (never a hang)
//!
//! * A transfer or direct-mode error of either stream, a FIFO error of the
//!   receive stream, SPI1 overrun or mode fault: [`ChainSpiError::Dma`] /
//!   [`ChainSpiError::Spi`]. The transmit stream's FIFO-error flag is
//!   ignored: in direct mode, memory to peripheral, it also rises when the
//!   stream is enabled with the request already active, and nothing is lost
//!   (the master's clock waits for its data). Both are the one rule of
//!   [`crate::dma`] ([`Role::Receive`], [`Role::TransmitWaited`]), which the
//!   I/O extension's driver follows too.
//! * A batch not over by its deadline (twice its nominal time + 100 µs,
//!   from [`ChainSpi::start`]): [`ChainSpi::poll`] stops the streams and
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
//! [`ChainSpi::window`]: CS high for t_disCS (a DMA batch may have raised
//! it just before), CS low, t_setCS, the bytes polled through SPI1_DR, CS
//! high, t_disCS — busy-waits of CPU cycles, at boot and after a bus error
//! only. Refused ([`ChainSpiError::Busy`]) while a DMA batch runs: the
//! driver's own phase says so, no flag shared with anything else.
//!
//! # One owner
//!
//! One [`ChainSpi`] value holds SPI1, DMA2 streams 0 and 3, TIM7 and CS; the
//! bridge's [`ChainBus`] is a handle that asks it for each blocking window
//! (the firmware keeps the driver in one critical-section cell that the
//! bridge's handle, the control tick and the two interrupts reach; the
//! host tests share it the same way). DMA2 streams 2 and 6 are the I/O
//! extension's (the flag-clear register is write-1-to-clear, so each driver
//! writes only its own bits, through [`crate::dma`]).
//!
//! # What is not verified
//!
//! Never run on a board: the register sequences are tested on the host
//! against the RM0090 model (`host-tests/tests/rm0090_chain_spi.rs`: one
//! test per rule, and control ticks of the bridge through driver and model
//! into the simulated chips); `firmware/tests/chain_spi.rs` (board only)
//! checks the real window timing. QEMU 7.2 has no DMA controller and no
//! TIM7, so the QEMU image's chain is the simulator (`platform/qemu.rs`).

use core::sync::atomic::{compiler_fence, Ordering};
use powerstep01::chain::{BatchState, ChainBus, Frames, Plan, MAX_DEVICES, MAX_WINDOWS};

use crate::dma::{self, DmaReg, Flags, Role, Size, Stream};
use crate::spi::{self, SpiReg};
use crate::Regs;

/// The powerSTEP01 SPI limit is 5 MHz; stay at or below 4 MHz, the rate the
/// reference libraries use on long daisy chains.
pub const SCK_MAX_HZ: u32 = 4_000_000;
/// CS low to first SCK edge (t_setCS of the family datasheets).
pub const CS_SETUP_NS: u32 = 350;
/// CS high between windows (t_disCS).
pub const CS_DESELECT_NS: u32 = 800;

/// DMA2 streams of SPI1 and their request channel (RM0090 table 43).
pub const RX_STREAM: u8 = 0;
pub const TX_STREAM: u8 = 3;
pub const SPI1_CHANNEL: u32 = 3;

/// The receive stream: bytes in, very high priority, interrupts at its end
/// and on its errors.
pub const RX: Stream = Stream {
    number: RX_STREAM,
    channel: SPI1_CHANNEL as u8,
    role: Role::Receive,
    size: Size::Byte,
    priority: DMA_CR_PL_VERY_HIGH,
    interrupts: DMA_CR_TCIE | DMA_CR_TEIE | DMA_CR_DMEIE,
};
/// The transmit stream: bytes out, high priority, no interrupt (its errors
/// are read at the receive stream's interrupt and at the deadline).
pub const TX: Stream = Stream {
    number: TX_STREAM,
    channel: SPI1_CHANNEL as u8,
    role: Role::TransmitWaited,
    size: Size::Byte,
    priority: DMA_CR_PL_HIGH,
    interrupts: 0,
};

/// DMA2_LISR / LIFCR bits of streams 0 and 3 (RM0090 10.5.1), from
/// [`crate::dma::Flags`].
pub const FEIF0: u32 = Flags::FEIF.at(RX_STREAM);
pub const DMEIF0: u32 = Flags::DMEIF.at(RX_STREAM);
pub const TEIF0: u32 = Flags::TEIF.at(RX_STREAM);
pub const HTIF0: u32 = Flags::HTIF.at(RX_STREAM);
pub const TCIF0: u32 = Flags::TCIF.at(RX_STREAM);
pub const FEIF3: u32 = Flags::FEIF.at(TX_STREAM);
pub const DMEIF3: u32 = Flags::DMEIF.at(TX_STREAM);
pub const TEIF3: u32 = Flags::TEIF.at(TX_STREAM);
pub const HTIF3: u32 = Flags::HTIF.at(TX_STREAM);
pub const TCIF3: u32 = Flags::TCIF.at(TX_STREAM);
/// Every flag of streams 0 and 3 (their LIFCR bits).
pub const STREAM_FLAGS: u32 = Flags::ALL.at(RX_STREAM) | Flags::ALL.at(TX_STREAM);

/// The registers the chain driver touches: SPI1, DMA2 (LISR/LIFCR and the
/// stream registers of stream `n`), TIM7 (RM0090 §28.5, §10.5, §20.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ChainReg {
    Spi(SpiReg),
    Dma(DmaReg),
    TimCr1,
    TimDier,
    TimSr,
    TimEgr,
    TimCnt,
    TimPsc,
    TimArr,
}

/// Register bits (RM0090 §28.5.1–§28.5.4, §10.5.5, §10.5.10, §20.4): SPI
/// and DMA from [`crate::spi`] and [`crate::dma`], TIM7's here.
pub mod bits {
    pub use crate::dma::bits::*;
    pub use crate::spi::bits::*;
    pub const TIM_CR1_CEN: u32 = 1 << 0;
    pub const TIM_CR1_URS: u32 = 1 << 2;
    pub const TIM_CR1_OPM: u32 = 1 << 3;
    pub const TIM_DIER_UIE: u32 = 1 << 0;
    pub const TIM_SR_UIF: u32 = 1 << 0;
    pub const TIM_EGR_UG: u32 = 1 << 0;
}

use bits::*;

/// What the driver needs besides the registers.
pub trait ChainHw: Regs<ChainReg> {
    /// Drive the common CS line (PA4) high or low.
    fn cs(&mut self, high: bool);
    /// Busy-wait `cycles` CPU cycles (blocking windows only).
    fn delay_cycles(&mut self, cycles: u32);
    /// Clear the pending bits of the batch's two interrupts (TIM7,
    /// DMA2_STREAM0) after a stop.
    fn unpend_interrupts(&mut self);
}

/// The batch's memory: the rows the streams read and write.
pub trait ChainMemory {
    /// Fill the first `windows` transmit rows from `frames` (read by the
    /// transmit stream while the batch runs).
    fn write_tx_rows(&mut self, frames: &Frames, windows: usize);
    /// Copy the first `windows` receive rows (written by the receive
    /// stream) into `out`, once the batch is over.
    fn read_rx_rows(&self, out: &mut Frames, windows: usize);
    /// The bus address of transmit (`rx` false) or receive row `w` (M0AR).
    fn row_address(&self, rx: bool, w: usize) -> Option<u32>;
    /// The bus address of SPI1_DR (PAR).
    fn dr_address(&self) -> u32;
}

/// Status polls before SPI1 counts as stuck on the blocking path: far
/// beyond a byte (3.05 µs ≈ 512 cycles, a poll takes several), short
/// enough not to hang.
const POLLS: u32 = 20_000;
/// Status polls inside an interrupt or a lock: BSY after a window's last
/// byte (clears within one SCK period of the last edge, 64 cycles), a
/// stream's EN after it was disabled (clears after the current beat); 256
/// polls are ≥ 4.5 µs.
const SHORT_POLLS: u32 = 256;

/// Why the chain bus failed (the bridge counts it as a chain error).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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

/// A batch's buffers: `'static` on the chip, so the streams can own them
/// while it runs. Row w holds window w (the first N bytes are used).
#[derive(Clone, Debug)]
pub struct ChainBuffers {
    pub tx: Frames,
    pub rx: Frames,
}

impl ChainBuffers {
    pub const fn new() -> ChainBuffers {
        ChainBuffers {
            tx: [[0; MAX_DEVICES]; MAX_WINDOWS],
            rx: [[0; MAX_DEVICES]; MAX_WINDOWS],
        }
    }

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

/// The timing arithmetic is `bridge_logic::rate`'s, so that the rate the
/// firmware fits to a chain is worked out from this driver's own timing.
pub use bridge_logic::rate::{cycles, sck_divider, BusTiming};

/// SPI1 up (mode 3, MSB first, 8-bit, master, software NSS held high,
/// CR1.BR = `br`), then enabled.
fn configure_spi(hw: &mut impl ChainHw, br: u32) {
    hw.write(ChainReg::Spi(SpiReg::Cr1), spi::master_cr1(br, true, true));
    hw.write(ChainReg::Spi(SpiReg::Cr2), 0);
    hw.modify(ChainReg::Spi(SpiReg::Cr1), |cr1| cr1 | SPI_CR1_SPE);
}

/// Read DR, then SR: drops a stale byte and clears an overrun.
fn drain_spi(hw: &mut impl ChainHw) {
    spi::drain(hw, ChainReg::Spi);
}

/// Wait (at most `polls` reads) until SPI1 is not busy; false if it stays
/// busy.
fn spi_idle(hw: &mut impl ChainHw, polls: u32) -> bool {
    spi::wait_idle(hw, ChainReg::Spi, polls)
}

/// Clear every flag of streams 0 and 3 (one LIFCR write; the other
/// streams' bits are written 0, which changes nothing).
fn clear_flags(hw: &mut impl ChainHw) {
    const WORDS: [u32; 2] = dma::clear_words(&[(RX_STREAM, Flags::ALL), (TX_STREAM, Flags::ALL)]);
    dma::clear_with(hw, ChainReg::Dma, WORDS);
}

/// The DMA2_LISR bits that are errors of either stream, under the one rule
/// of [`crate::dma`]: the receive stream's FEIF counts, the transmit
/// stream's does not.
const ERRORS: u32 = RX.role.errors().at(RX_STREAM) | TX.role.errors().at(TX_STREAM);
/// The transmit stream's error bits (read at the deadline).
const TX_ERRORS: u32 = TX.role.errors().at(TX_STREAM);

/// The clocks the driver works from.
#[derive(Clone, Copy, Debug)]
pub struct ChainClocks {
    /// SPI1's APB2 clock.
    pub pclk2_hz: u32,
    /// The CPU clock (busy waits of the blocking windows).
    pub sysclk_hz: u32,
    /// TIM7's clock.
    pub timclk_hz: u32,
}

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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ChainDmaStats {
    pub batches: u32,
    pub windows: u32,
    pub dma_errors: u32,
    pub spi_errors: u32,
    pub stuck: u32,
    pub timeouts: u32,
}

/// The chain's one driver (module docs): blocking windows
/// ([`ChainSpi::window`], its [`ChainBus`]) and batches of windows by DMA2
/// and TIM7 — `start` and `poll` from the control tick, `on_dma` from
/// `DMA2_STREAM0`, `on_timer` from `TIM7`.
#[derive(Debug)]
pub struct ChainSpi<H> {
    hw: H,
    gap_arr: u16,
    setup_arr: u16,
    /// The batches' times, worked out once (no division per batch).
    timing: BusTiming,
    sck_hz: u32,
    setup_cycles: u32,
    deselect_cycles: u32,
    windows: u8,
    n: u8,
    /// The window in its gap, setup or shift.
    window: u8,
    phase: Phase,
    deadline_us: u64,
    stats: ChainDmaStats,
}

impl<H: ChainHw + ChainMemory> ChainSpi<H> {
    /// Set up SPI1, TIM7 and DMA2 streams 0/3 on `hw` (CS high) and return
    /// their one driver. The caller has clocked and reset SPI1 and TIM7 and
    /// clocked DMA2.
    pub fn new(mut hw: H, clocks: ChainClocks) -> ChainSpi<H> {
        let (div, br) = sck_divider(clocks.pclk2_hz, SCK_MAX_HZ);
        let sck_hz = clocks.pclk2_hz.checked_div(div).unwrap_or(clocks.pclk2_hz);
        hw.cs(true);
        configure_spi(&mut hw, br);

        // TIM7: one-pulse, only an overflow raises the update interrupt; the
        // prescaler (1) is loaded by the UG event, which sets no flag with
        // URS.
        hw.write(ChainReg::TimCr1, TIM_CR1_OPM | TIM_CR1_URS);
        hw.write(ChainReg::TimPsc, 0);
        hw.write(ChainReg::TimEgr, TIM_EGR_UG);
        hw.write(ChainReg::TimSr, 0);
        hw.write(ChainReg::TimDier, TIM_DIER_UIE);

        // Both streams: byte to byte, memory incremented, direct mode
        // ([`RX`], [`TX`]). The receive stream interrupts on transfer
        // complete and its errors; the transmit stream's errors raise no
        // interrupt (its IRQ is not bound): they are read at the receive
        // stream's interrupt and at the deadline.
        let dr = hw.dr_address();
        for s in [RX_STREAM, TX_STREAM] {
            dma::disable(&mut hw, ChainReg::Dma, s);
        }
        dma::configure(&mut hw, ChainReg::Dma, &RX, dr);
        dma::configure(&mut hw, ChainReg::Dma, &TX, dr);
        clear_flags(&mut hw);

        let gap_ticks = cycles(CS_DESELECT_NS, clocks.timclk_hz);
        let setup_ticks = cycles(CS_SETUP_NS, clocks.timclk_hz);
        ChainSpi {
            hw,
            // The counter runs 0..=ARR and overflows one tick later, so ARR
            // = ticks waits at least `ticks` + 1 periods of the timer clock.
            gap_arr: u16::try_from(gap_ticks).unwrap_or(u16::MAX),
            setup_arr: u16::try_from(setup_ticks).unwrap_or(u16::MAX),
            timing: BusTiming::of(
                clocks.pclk2_hz,
                clocks.timclk_hz,
                SCK_MAX_HZ,
                CS_DESELECT_NS,
                CS_SETUP_NS,
            ),
            sck_hz,
            setup_cycles: cycles(CS_SETUP_NS, clocks.sysclk_hz),
            deselect_cycles: cycles(CS_DESELECT_NS, clocks.sysclk_hz),
            windows: 0,
            n: 0,
            window: 0,
            phase: Phase::Idle,
            deadline_us: 0,
            stats: ChainDmaStats::default(),
        }
    }

    /// The hardware handle (on the host: the model).
    pub fn hw(&self) -> &H {
        &self.hw
    }

    pub fn hw_mut(&mut self) -> &mut H {
        &mut self.hw
    }

    // --- blocking windows -------------------------------------------------------

    /// One blocking window (chain detection, the recovery windows): CS high
    /// for t_disCS (a batch may have raised it just before), CS low,
    /// t_setCS, the bytes polled through SPI1_DR, CS high, t_disCS.
    /// [`ChainSpiError::Busy`] while a batch is on the bus.
    pub fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ChainSpiError> {
        if self.is_running() {
            return Err(ChainSpiError::Busy);
        }
        let hw = &mut self.hw;
        hw.delay_cycles(self.deselect_cycles);
        hw.cs(false);
        hw.delay_cycles(self.setup_cycles);
        let result = transfer_polled(hw, tx, rx);
        hw.cs(true);
        hw.delay_cycles(self.deselect_cycles);
        result
    }

    // --- batches by DMA -----------------------------------------------------------

    /// Copy the plan's windows into the buffers and start the batch (its
    /// first gap). `now_us`: the monotonic's µs, for the deadline.
    pub fn start(&mut self, plan: &Plan, now_us: u64) -> Result<(), ChainSpiError> {
        if self.phase != Phase::Idle {
            // Running, or over and not yet collected by `poll`.
            return Err(ChainSpiError::Busy);
        }
        let (windows, n) = (plan.windows(), plan.devices());
        if windows == 0 || windows > MAX_WINDOWS || n == 0 || n > MAX_DEVICES {
            return Err(ChainSpiError::BadPlan);
        }
        // Whole rows: two words each, no length to check.
        self.hw.write_tx_rows(plan.frames(), windows);
        if !dma::wait_disabled(
            &mut self.hw,
            ChainReg::Dma,
            RX_STREAM,
            TX_STREAM,
            SHORT_POLLS,
        ) {
            self.stats.stuck = self.stats.stuck.saturating_add(1);
            return Err(ChainSpiError::Stuck);
        }
        // Window counts fit: at most 16 windows of 8 bytes.
        self.windows = windows as u8;
        self.n = n as u8;
        self.window = 0;
        self.deadline_us = now_us.saturating_add(self.bound_us());
        self.stats.batches = self.stats.batches.saturating_add(1);
        drain_spi(&mut self.hw);
        self.hw
            .modify(ChainReg::Spi(SpiReg::Cr2), |cr2| cr2 | SPI_CR2_RXDMAEN);
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
                let lisr = self.hw.read(ChainReg::Dma(DmaReg::Lisr));
                let why = if lisr & TX_ERRORS != 0 {
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
                        self.hw.read_rx_rows(rx, usize::from(self.windows));
                        BatchState::Done(Ok(rx))
                    }
                    Err(e) => BatchState::Done(Err(e)),
                }
            }
        }
    }

    /// `DMA2_STREAM0`: the receive stream's transfer complete or an error.
    pub fn on_dma(&mut self) {
        let lisr = self.hw.read(ChainReg::Dma(DmaReg::Lisr));
        self.dma_event(lisr);
    }

    /// [`ChainSpi::on_dma`] with DMA2_LISR as read (`lisr`): the cost bench
    /// feeds it under QEMU, whose DMA2 reads 0.
    pub fn dma_event(&mut self, lisr: u32) {
        clear_flags(&mut self.hw);
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
        let sr = self.hw.read(ChainReg::Spi(SpiReg::Sr));
        if sr & (SPI_SR_OVR | SPI_SR_MODF) != 0 {
            self.stats.spi_errors = self.stats.spi_errors.saturating_add(1);
            self.fail(ChainSpiError::Spi);
            return;
        }
        // The last byte is in, its last edge has passed: SPI1 is normally
        // idle already.
        if sr & SPI_SR_BSY != 0 && !spi_idle(&mut self.hw, SHORT_POLLS) {
            self.stats.stuck = self.stats.stuck.saturating_add(1);
            self.fail(ChainSpiError::Stuck);
            return;
        }
        self.hw
            .modify(ChainReg::Spi(SpiReg::Cr2), |cr2| cr2 & !SPI_CR2_TXDMAEN);
        compiler_fence(Ordering::SeqCst);
        self.stats.windows = self.stats.windows.saturating_add(1);
        self.window = self.window.saturating_add(1);
        if self.window >= self.windows {
            self.hw.cs(true);
            self.hw
                .modify(ChainReg::Spi(SpiReg::Cr2), |cr2| cr2 & !SPI_CR2_RXDMAEN);
            self.phase = Phase::Done(Ok(()));
            return;
        }
        // Arm first, so the gap starts right at the CS rise.
        self.arm();
        self.phase = Phase::Gap;
        self.hw.cs(true);
        self.timer(self.gap_arr);
    }

    /// `TIM7`: the gap or the setup time is over.
    pub fn on_timer(&mut self) {
        self.hw.write(ChainReg::TimSr, 0);
        match self.phase {
            Phase::Gap => {
                self.hw.cs(false);
                self.phase = Phase::Setup;
                self.timer(self.setup_arr);
            }
            Phase::Setup => {
                self.phase = Phase::Shift;
                compiler_fence(Ordering::SeqCst);
                self.hw
                    .modify(ChainReg::Spi(SpiReg::Cr2), |cr2| cr2 | SPI_CR2_TXDMAEN);
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

    /// The bus timing this driver makes ([`BusTiming`]).
    pub fn timing(&self) -> BusTiming {
        self.timing
    }

    /// Nominal duration of the current batch, µs (rounded up): per window
    /// the gap, the set-up, the bytes and `rate::WINDOW_SLACK_NS` for the
    /// three interrupts and the DMA and SPI start.
    pub fn nominal_us(&self) -> u64 {
        // 16 windows of 8 bytes at 2.625 MHz: 0.46 ms, far from saturating.
        self.timing
            .batch_ns(u32::from(self.windows), u32::from(self.n))
            .div_ceil(1_000)
    }

    /// How long a batch may take before `poll` stops it.
    fn bound_us(&self) -> u64 {
        self.nominal_us().saturating_mul(2).saturating_add(100)
    }

    /// Point both streams at window `self.window` and enable them (TX
    /// requests are closed: nothing moves until TXDMAEN). The stream
    /// registers are written while EN = 0 and the stream's flags are
    /// cleared before EN is set (RM0090 §10.3.17).
    fn arm(&mut self) {
        let w = usize::from(self.window);
        let (Some(tx), Some(rx)) = (self.hw.row_address(false, w), self.hw.row_address(true, w))
        else {
            return;
        };
        let n = u32::from(self.n);
        let hw = &mut self.hw;
        clear_flags(hw);
        dma::load(hw, ChainReg::Dma, RX_STREAM, rx, n);
        dma::load(hw, ChainReg::Dma, TX_STREAM, tx, n);
        compiler_fence(Ordering::SeqCst);
        dma::enable(hw, ChainReg::Dma, RX_STREAM);
        dma::enable(hw, ChainReg::Dma, TX_STREAM);
    }

    /// TIM7 once, `arr` + 1 timer-clock periods, then its interrupt.
    fn timer(&mut self, arr: u16) {
        let hw = &mut self.hw;
        hw.write(ChainReg::TimArr, u32::from(arr));
        hw.write(ChainReg::TimCnt, 0);
        hw.write(ChainReg::TimCr1, TIM_CR1_OPM | TIM_CR1_URS | TIM_CR1_CEN);
    }

    /// End the batch with `why`, everything stopped.
    fn fail(&mut self, why: ChainSpiError) {
        self.stop();
        self.phase = Phase::Done(Err(why));
    }

    /// Stop TIM7 and both streams, close the SPI requests, let SPI1 finish
    /// its byte, raise CS and hold it high for t_disCS (error paths only).
    fn stop(&mut self) {
        let hw = &mut self.hw;
        hw.write(ChainReg::TimCr1, TIM_CR1_OPM | TIM_CR1_URS);
        hw.write(ChainReg::TimSr, 0);
        hw.modify(ChainReg::Spi(SpiReg::Cr2), |cr2| {
            cr2 & !(SPI_CR2_TXDMAEN | SPI_CR2_RXDMAEN)
        });
        for s in [RX_STREAM, TX_STREAM] {
            dma::disable(hw, ChainReg::Dma, s);
        }
        let _ = spi_idle(hw, SHORT_POLLS);
        drain_spi(hw);
        clear_flags(hw);
        // An interrupt of the stopped batch may be pending: it would find
        // the next batch's phase.
        hw.unpend_interrupts();
        hw.cs(true);
        hw.delay_cycles(self.deselect_cycles);
    }
}

/// The bridge's bus: blocking windows on the one driver.
impl<H: ChainHw + ChainMemory> ChainBus for ChainSpi<H> {
    type Error = ChainSpiError;

    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ChainSpiError> {
        ChainSpi::window(self, tx, rx)
    }
}

/// Full duplex, byte by byte through SPI1_DR (pads with 0x00 / drops extra
/// bytes if the lengths ever differ; the chain always passes equal ones).
fn transfer_polled(hw: &mut impl ChainHw, tx: &[u8], rx: &mut [u8]) -> Result<(), ChainSpiError> {
    let (sr, dr) = (ChainReg::Spi(SpiReg::Sr), ChainReg::Spi(SpiReg::Dr));
    drain_spi(hw);
    for i in 0..tx.len().max(rx.len()) {
        if !(0..POLLS).any(|_| hw.read(sr) & SPI_SR_TXE != 0) {
            return Err(ChainSpiError::Stuck);
        }
        let byte = tx.get(i).copied().unwrap_or(0);
        hw.write(dr, u32::from(byte));
        if !(0..POLLS).any(|_| hw.read(sr) & SPI_SR_RXNE != 0) {
            return Err(ChainSpiError::Stuck);
        }
        // 8-bit frames: DR's low byte.
        let got = hw.read(dr) as u8;
        if let Some(slot) = rx.get_mut(i) {
            *slot = got;
        }
    }
    let status = hw.read(sr);
    if status & (SPI_SR_OVR | SPI_SR_MODF) != 0 {
        drain_spi(hw);
        let cr1 = hw.read(ChainReg::Spi(SpiReg::Cr1));
        configure_spi(hw, (cr1 & SPI_CR1_BR_MASK) >> SPI_CR1_BR_SHIFT);
        return Err(ChainSpiError::Spi);
    }
    // TXE says the last byte left DR, not that it left the wire: CS may
    // rise only once BSY is clear (RM0090 §28.3.8).
    if spi_idle(hw, POLLS) {
        Ok(())
    } else {
        Err(ChainSpiError::Stuck)
    }
}
