//! The I/O extension's port (Copley-style raw SPI, `docs/ioext.md`): runs a
//! [`TransferPlan`] exactly as `bridge_logic::ioext::plan` describes it, and
//! decides nothing — every number (divider, timer registers, CS handling,
//! bits, half-period) comes from the plan.
//!
//! # Engines
//!
//! * **SPI engine** ([`TransferPlan::spi`]): SPI2 master, 8-bit frames, MSB
//!   first, software NSS, CR1.BR and CPOL/CPHA from the plan. DMA1 stream 4
//!   (channel 0, SPI2_TX) moves the bytes out, stream 3 (channel 0,
//!   SPI2_RX) the bytes in. Ends in the stream 3 transfer-complete
//!   interrupt (`DMA1_STREAM3`), then BSY = 0.
//! * **Bit engine** ([`TransferPlan::timer`]): TIM1 in one-pulse PWM mode 2
//!   with RCR = bits − 1 makes exactly `bits` SCK periods on CH1N (PB13,
//!   AF1; CC1E = 0, CC1NE = 1, CC1NP = CPOL, MOE = 1). CC3 requests DMA2
//!   stream 6 (channel 6) to write the plan's MOSI table to GPIOB_BSRR, CC2
//!   requests DMA2 stream 2 (channel 6) to copy GPIOB_IDR into the sample
//!   buffer. Ends in the stream 2 transfer-complete interrupt
//!   (`DMA2_STREAM2`), then CEN = 0. DMA2, not DMA1: only DMA2's peripheral
//!   port reaches the GPIO ports on AHB1.
//!
//! # CS and the half-period waits
//!
//! CS falls (unless the plan says it is still low) at least half a period
//! before the first clock edge: the SPI engine busy-waits that long before
//! it enables the TX DMA request; the bit engine's first phase (CNT <
//! CCR1) is exactly that. At the end the driver busy-waits half a period
//! after the last edge, then raises CS unless the plan holds it. The waits
//! are ≤ 3.05 µs on the SPI engine (/256) and ≤ 12.8 µs on the bit engine
//! (N = 255): they run in the DMA interrupt, at the driver's priority.
//!
//! # Pins
//!
//! `board::configure` leaves SCK and MOSI as floating inputs and MISO as an
//! input with a pull-up; CS is high (and needs an external pull-up). The
//! first transfer takes them: SCK AF5 (SPI2_SCK) or AF1 (TIM1_CH1N) with an
//! internal pull towards CPOL, MOSI AF5 or a GPIO output, MISO AF5 (the bit
//! engine reads it through IDR, which works in AF mode). [`Action::Disable`]
//! raises CS and returns SCK and MOSI to inputs. Mode changes touch only
//! these pins' fields of GPIOB's MODER/AFRH/PUPDR, inside a critical
//! section; every other GPIOB user at run time writes BSRR.
//!
//! # Unsafe
//!
//! Two kinds of `unsafe`, each with a `SAFETY:` comment: the DMA
//! addresses (SPI2_DR, GPIOB_BSRR/IDR and the driver's own `'static`
//! buffers) and the shared GPIOB register block for the pins this driver
//! owns.
//!
//! # What is not verified
//!
//! Built, never run on a board: the register sequences follow RM0090 and
//! the plan's recipe; `tests/ioext_spi.rs` (board only, MOSI jumpered to
//! MISO) checks loopback, CS and the interrupt on hardware. QEMU 7.2
//! models neither DMA nor TIM1, so the QEMU image replaces this driver
//! (`platform/qemu.rs`); `tests/ioext_abort.rs` runs this driver under
//! QEMU, where no transfer ends (SPI2 set-up, the timeout path).

// DMA addresses and the shared GPIOB block (see the module docs).
#![allow(unsafe_code)]

use bridge_logic::ioext::{Action, SpiSetup, TimerSetup, TransferPlan, WireBits, MAX_BITS};
use core::sync::atomic::{compiler_fence, Ordering};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::{Enable, Rcc, Reset};

use crate::board::{
    IoExtCs, IoExtMiso, IoExtMosi, IoExtSck, IoExtSpi, IoExtSpiDma, IoExtTimer, IoExtTimerDma,
    IOEXT_MISO_PIN, IOEXT_MOSI_PIN, IOEXT_SCK_PIN,
};

/// Most bits of a transfer, as a buffer length.
const MAX: usize = MAX_BITS as usize;
/// DMA1 streams of SPI2 and DMA2 streams of TIM1 (RM0090 tables 42/43).
const SPI_RX_STREAM: usize = 3;
const SPI_TX_STREAM: usize = 4;
const TIM_SAMPLE_STREAM: usize = 2;
const TIM_MOSI_STREAM: usize = 6;
/// DMA2 request channel of TIM1_CH2 (stream 2) and TIM1_CH3 (stream 6).
const TIM1_CHANNEL: u8 = 6;
/// GPIO alternate functions of PB13: SPI2_SCK and TIM1_CH1N.
const AF_SPI2: u8 = 5;
const AF_TIM1: u8 = 1;
/// Status-poll iterations after the last DMA transfer before the driver
/// calls the end a failure (BSY or CEN still set): far beyond the longest
/// legal wait (¾ of a 25.5 µs period), short enough not to hang.
const END_POLLS: u32 = 200_000;

// The DMA table and the samples are indexed by the GPIOB pin numbers.
const _: () = assert!(IOEXT_MOSI_PIN < 16 && IOEXT_MISO_PIN < 16 && IOEXT_SCK_PIN >= 8);

/// Why a transfer failed (the bridge counts it, `on_io_failed`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum IoExtError {
    /// A DMA stream reported a transfer or direct-mode error.
    Dma,
    /// SPI2 still busy, or TIM1 still counting, after the last DMA transfer.
    EngineStuck,
    /// No end within the plan's timeout: the driver stopped the engine.
    Timeout,
    /// A transfer was still running: nothing was started.
    Busy,
    /// The plan has no engine this driver can run (0 frames, or an empty
    /// MOSI table): nothing was started.
    BadPlan,
}

/// The DMA buffers: `'static` so a stream can own them while it runs.
pub struct IoExtBuffers {
    tx: [u8; MAX / 8],
    rx: [u8; MAX / 8],
    mosi_bsrr: [u32; MAX],
    samples: [u16; MAX],
}

impl IoExtBuffers {
    pub const fn new() -> IoExtBuffers {
        IoExtBuffers {
            tx: [0; MAX / 8],
            rx: [0; MAX / 8],
            mosi_bsrr: [0; MAX],
            samples: [0; MAX],
        }
    }
}

impl Default for IoExtBuffers {
    fn default() -> Self {
        Self::new()
    }
}

/// What [`IoExtPort::run`] did with an action.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Started {
    /// The transfer runs; its end comes from [`IoExtPort::on_interrupt`]
    /// (or [`IoExtPort::abort`] after [`TransferPlan::timeout_us`]).
    Running,
    /// The transfer has already ended (or could not start): report this.
    Ended(Result<WireBits, IoExtError>),
    /// `Action::Disable` done: CS high, port released.
    Released,
}

/// Which engine owns the pins now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PinsFor {
    Released,
    Spi,
    Timer,
}

/// The transfer in flight.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Running {
    Idle,
    Spi { frames: usize, end: End },
    Timer { bits: usize, end: End },
}

/// What to do at the end of a transfer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct End {
    half_period_cycles: u32,
    cs_hold: bool,
}

/// The extension's port: SPI2, TIM1, their DMA streams, the pins and the
/// buffers.
pub struct IoExtPort {
    spi: IoExtSpi,
    tim: IoExtTimer,
    dma1: IoExtSpiDma,
    dma2: IoExtTimerDma,
    cs: IoExtCs,
    bufs: &'static mut IoExtBuffers,
    sysclk_hz: u32,
    pins: PinsFor,
    /// CR1.BR and mode SPI2 is set up with (`None`: not set up).
    spi_setup: Option<(u8, bool, bool)>,
    running: Running,
}

/// GPIOB, for this driver's pins.
fn gpiob() -> &'static pac::gpiob::RegisterBlock {
    // SAFETY: GPIOB is always mapped. The driver owns PB11/PB13/PB14/PB15
    // (their HAL pins were moved into `IoExtPort::new`) and changes only
    // their fields of MODER/AFRH/PUPDR, with interrupts masked;
    // BSRR writes are atomic by design.
    unsafe { &*pac::GPIOB::ptr() }
}

impl IoExtPort {
    /// Clock and reset SPI2, TIM1, DMA1 and DMA2; take the pins as
    /// `board::configure` left them (CS high). Nothing is driven until the
    /// first transfer.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        spi: IoExtSpi,
        tim: IoExtTimer,
        dma1: IoExtSpiDma,
        dma2: IoExtTimerDma,
        pins: (IoExtSck, IoExtMiso, IoExtMosi),
        cs: IoExtCs,
        bufs: &'static mut IoExtBuffers,
        rcc: &mut Rcc,
    ) -> IoExtPort {
        IoExtSpi::enable(rcc);
        IoExtSpi::reset(rcc);
        IoExtTimer::enable(rcc);
        IoExtTimer::reset(rcc);
        IoExtSpiDma::enable(rcc);
        IoExtTimerDma::enable(rcc);
        // The pins' modes are switched through GPIOB from here on.
        let _ = pins;
        IoExtPort {
            spi,
            tim,
            dma1,
            dma2,
            cs,
            bufs,
            sysclk_hz: rcc.clocks.sysclk().raw(),
            pins: PinsFor::Released,
            spi_setup: None,
            running: Running::Idle,
        }
    }

    /// A transfer is in flight.
    pub fn is_running(&self) -> bool {
        self.running != Running::Idle
    }

    /// Execute the bridge's action (`Bridge::take_io_action`).
    pub fn run(&mut self, action: &Action) -> Started {
        if self.is_running() {
            // The bridge never hands out an action while its transfer runs.
            return Started::Ended(Err(IoExtError::Busy));
        }
        match action {
            Action::Disable => {
                self.release();
                Started::Released
            }
            Action::Transfer(plan) => {
                let end = End {
                    half_period_cycles: self.cycles(plan.half_period_ns()),
                    cs_hold: plan.cs_hold,
                };
                if let Some(s) = plan.spi() {
                    self.start_spi(plan, s, end)
                } else if let Some(t) = plan.timer() {
                    self.start_timer(plan, t, end)
                } else {
                    Started::Ended(Err(IoExtError::BadPlan))
                }
            }
        }
    }

    /// From the DMA interrupts (`DMA1_STREAM3`, `DMA2_STREAM2`): the end
    /// of the running transfer with its received bits, or `None` if it is
    /// still running (or nothing runs).
    pub fn on_interrupt(&mut self) -> Option<Result<WireBits, IoExtError>> {
        match self.running {
            Running::Idle => {
                self.clear_all_flags();
                None
            }
            Running::Spi { frames, end } => {
                let lisr = self.dma1.lisr().read();
                let hisr = self.dma1.hisr().read();
                let error = lisr.teif3().bit_is_set()
                    || lisr.dmeif3().bit_is_set()
                    || hisr.teif4().bit_is_set()
                    || hisr.dmeif4().bit_is_set();
                if error {
                    return Some(Err(self.stop(IoExtError::Dma)));
                }
                if !lisr.tcif3().bit_is_set() {
                    self.clear_spi_flags(false);
                    return None;
                }
                Some(self.finish_spi(frames, end))
            }
            Running::Timer { bits, end } => {
                let lisr = self.dma2.lisr().read();
                let hisr = self.dma2.hisr().read();
                let error = lisr.teif2().bit_is_set()
                    || lisr.dmeif2().bit_is_set()
                    || hisr.teif6().bit_is_set()
                    || hisr.dmeif6().bit_is_set();
                if error {
                    return Some(Err(self.stop(IoExtError::Dma)));
                }
                if !lisr.tcif2().bit_is_set() {
                    self.clear_timer_flags(false);
                    return None;
                }
                Some(self.finish_timer(bits, end))
            }
        }
    }

    /// The plan's timeout has passed: if the transfer has ended meanwhile
    /// (its interrupt still pending), its result; otherwise stop the
    /// engine, raise CS and return [`IoExtError::Timeout`]. `None` if
    /// nothing runs.
    pub fn abort(&mut self) -> Option<Result<WireBits, IoExtError>> {
        if !self.is_running() {
            return None;
        }
        match self.on_interrupt() {
            Some(done) => Some(done),
            None => Some(Err(self.stop(IoExtError::Timeout))),
        }
    }

    // --- SPI engine ----------------------------------------------------------

    fn start_spi(&mut self, plan: &TransferPlan, s: SpiSetup, end: End) -> Started {
        let frames = usize::from(s.frames).min(self.bufs.tx.len());
        if frames == 0 {
            return Started::Ended(Err(IoExtError::BadPlan));
        }
        if !streams_stopped(&self.dma1, [SPI_RX_STREAM, SPI_TX_STREAM]) {
            return Started::Ended(Err(self.stop(IoExtError::EngineStuck)));
        }
        for (j, b) in self.bufs.tx.iter_mut().enumerate().take(frames) {
            *b = plan.tx_byte(j);
        }
        // SPI2 set-up: only when it changes (never while CS is held low:
        // the logic refuses a CPOL change then), so SCK keeps its level.
        let setup = (s.br, s.mode.cpol, s.mode.cpha);
        if self.spi_setup != Some(setup) {
            self.spi.cr1().modify(|_, w| w.spe().clear_bit());
            self.spi.cr1().write(|w| {
                w.cpha()
                    .bit(s.mode.cpha)
                    .cpol()
                    .bit(s.mode.cpol)
                    .mstr()
                    .set_bit()
                    .br()
                    .set(s.br & 0b111)
                    .ssm()
                    .set_bit()
                    .ssi()
                    .set_bit()
            });
            self.spi.cr1().modify(|_, w| w.spe().set_bit());
            self.spi_setup = Some(setup);
        }
        self.take_pins(PinsFor::Spi, s.mode.cpol);
        // Stale receive data or overrun from an aborted transfer.
        let _ = self.spi.dr().read();
        let _ = self.spi.sr().read();
        self.clear_spi_flags(true);

        let dr = self.spi.dr().as_ptr() as u32;
        let n = u16::try_from(frames).unwrap_or(0);
        let rx = self.bufs.rx.as_mut_ptr() as u32;
        let tx = self.bufs.tx.as_ptr() as u32;
        let rx_stream = self.dma1.st(SPI_RX_STREAM);
        // SAFETY: the peripheral address is SPI2_DR; the memory address is
        // this driver's `'static` receive buffer, at least `n` bytes long,
        // which the CPU reads only after the stream has finished.
        rx_stream.par().write(|w| unsafe { w.pa().bits(dr) });
        rx_stream.m0ar().write(|w| unsafe { w.m0a().bits(rx) });
        rx_stream.ndtr().write(|w| w.ndt().set(n));
        rx_stream.fcr().reset();
        rx_stream.cr().write(|w| {
            w.chsel()
                .set(0)
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
        let tx_stream = self.dma1.st(SPI_TX_STREAM);
        // SAFETY: SPI2_DR again; the memory address is this driver's
        // `'static` transmit buffer (`n` bytes), not written while the
        // stream runs.
        tx_stream.par().write(|w| unsafe { w.pa().bits(dr) });
        tx_stream.m0ar().write(|w| unsafe { w.m0a().bits(tx) });
        tx_stream.ndtr().write(|w| w.ndt().set(n));
        tx_stream.fcr().reset();
        tx_stream.cr().write(|w| {
            w.chsel()
                .set(0)
                .dir()
                .memory_to_peripheral()
                .minc()
                .incremented()
                .pl()
                .high()
                .teie()
                .enabled()
                .dmeie()
                .enabled()
        });
        // RM0090 28.3.9: RX DMA request first, streams, then TX request.
        self.spi.cr2().modify(|_, w| w.rxdmaen().set_bit());
        compiler_fence(Ordering::SeqCst);
        rx_stream.cr().modify(|_, w| w.en().enabled());
        tx_stream.cr().modify(|_, w| w.en().enabled());
        if !plan.cs_low_before {
            self.cs.set_low();
            cortex_m::asm::delay(end.half_period_cycles);
        }
        self.running = Running::Spi { frames, end };
        compiler_fence(Ordering::SeqCst);
        self.spi.cr2().modify(|_, w| w.txdmaen().set_bit());
        Started::Running
    }

    fn finish_spi(&mut self, frames: usize, end: End) -> Result<WireBits, IoExtError> {
        self.clear_spi_flags(true);
        // The last byte is in: wait until SPI2 has let go of the bus.
        let mut polls = 0;
        while self.spi.sr().read().bsy().bit_is_set() {
            polls += 1;
            if polls > END_POLLS {
                return Err(self.stop(IoExtError::EngineStuck));
            }
        }
        self.spi
            .cr2()
            .modify(|_, w| w.rxdmaen().clear_bit().txdmaen().clear_bit());
        compiler_fence(Ordering::SeqCst);
        self.end_cs(end);
        self.running = Running::Idle;
        let rx = self.bufs.rx.get(..frames).unwrap_or(&[]);
        Ok(WireBits::from_bytes(rx))
    }

    fn clear_spi_flags(&mut self, all: bool) {
        self.dma1.lifcr().write(|w| {
            let w = w.chtif3().set_bit().cfeif3().set_bit();
            if all {
                w.ctcif3().set_bit().cteif3().set_bit().cdmeif3().set_bit()
            } else {
                w
            }
        });
        self.dma1.hifcr().write(|w| {
            w.ctcif4()
                .set_bit()
                .chtif4()
                .set_bit()
                .cfeif4()
                .set_bit()
                .cteif4()
                .set_bit()
                .cdmeif4()
                .set_bit()
        });
    }

    // --- bit engine ----------------------------------------------------------

    fn start_timer(&mut self, plan: &TransferPlan, t: TimerSetup, end: End) -> Started {
        let bits = plan.mosi_bsrr(IOEXT_MOSI_PIN, &mut self.bufs.mosi_bsrr);
        if bits == 0 {
            return Started::Ended(Err(IoExtError::BadPlan));
        }
        if !streams_stopped(&self.dma2, [TIM_SAMPLE_STREAM, TIM_MOSI_STREAM]) {
            return Started::Ended(Err(self.stop(IoExtError::EngineStuck)));
        }
        let tim = &self.tim;
        // Stopped, one-pulse, upcounting; registers loaded by UG below.
        tim.cr1().write(|w| w.opm().set_bit());
        tim.dier().reset();
        tim.psc().write(|w| w.psc().set(t.psc));
        tim.arr().write(|w| w.arr().set(t.arr));
        tim.rcr().write(|w| w.rep().set(t.rcr));
        tim.ccr(0).write(|w| w.ccr().set(t.ccr_sck));
        tim.ccr(1).write(|w| w.ccr().set(t.ccr_sample));
        tim.ccr(2).write(|w| w.ccr().set(t.ccr_mosi));
        // CH1 forced inactive until the start (OC1N = CPOL), CH2/CH3 pure
        // compares (no output) for the DMA requests.
        tim.ccmr1_output()
            .write(|w| w.oc1m().force_inactive().oc2m().frozen());
        tim.ccmr2_output().write(|w| w.oc3m().frozen());
        tim.ccer()
            .write(|w| w.cc1ne().set_bit().cc1np().bit(plan.mode.cpol));
        tim.bdtr().write(|w| w.moe().set_bit());
        tim.egr().write(|w| w.ug().set_bit());
        tim.sr().reset();

        // MOSI takes bit 0 before the pin becomes an output.
        gpiob().bsrr().write(|w| {
            if t.first_mosi {
                w.bs(IOEXT_MOSI_PIN).set_bit()
            } else {
                w.br(IOEXT_MOSI_PIN).set_bit()
            }
        });
        self.take_pins(PinsFor::Timer, plan.mode.cpol);
        self.clear_timer_flags(true);

        let n = u16::try_from(bits).unwrap_or(0);
        let gpio = pac::GPIOB::ptr() as u32;
        let (bsrr_addr, idr_addr) = (gpio + 0x18, gpio + 0x10);
        let table = self.bufs.mosi_bsrr.as_ptr() as u32;
        let samples = self.bufs.samples.as_mut_ptr() as u32;
        let mosi = self.dma2.st(TIM_MOSI_STREAM);
        // SAFETY: the peripheral address is GPIOB_BSRR (RM0090 8.4.7),
        // written with entries that set or reset MOSI only; the memory
        // address is this driver's `'static` table of `n` words.
        mosi.par().write(|w| unsafe { w.pa().bits(bsrr_addr) });
        mosi.m0ar().write(|w| unsafe { w.m0a().bits(table) });
        mosi.ndtr().write(|w| w.ndt().set(n));
        mosi.fcr().reset();
        mosi.cr().write(|w| {
            w.chsel()
                .set(TIM1_CHANNEL)
                .dir()
                .memory_to_peripheral()
                .minc()
                .incremented()
                .psize()
                .bits32()
                .msize()
                .bits32()
                .pl()
                .very_high()
                .teie()
                .enabled()
                .dmeie()
                .enabled()
        });
        let sample = self.dma2.st(TIM_SAMPLE_STREAM);
        // SAFETY: the peripheral address is GPIOB_IDR (read only); the
        // memory address is this driver's `'static` buffer of `n`
        // half-words, read by the CPU only after the stream has finished.
        sample.par().write(|w| unsafe { w.pa().bits(idr_addr) });
        sample.m0ar().write(|w| unsafe { w.m0a().bits(samples) });
        sample.ndtr().write(|w| w.ndt().set(n));
        sample.fcr().reset();
        sample.cr().write(|w| {
            w.chsel()
                .set(TIM1_CHANNEL)
                .dir()
                .peripheral_to_memory()
                .minc()
                .incremented()
                .psize()
                .bits16()
                .msize()
                .bits16()
                .pl()
                .very_high()
                .tcie()
                .enabled()
                .teie()
                .enabled()
                .dmeie()
                .enabled()
        });
        compiler_fence(Ordering::SeqCst);
        mosi.cr().modify(|_, w| w.en().enabled());
        sample.cr().modify(|_, w| w.en().enabled());
        let tim = &self.tim;
        tim.dier().write(|w| w.cc2de().set_bit().cc3de().set_bit());
        // PWM mode 2: OC1REF low while CNT < CCR1, so SCK stays at CPOL
        // for the first half period (the CS set-up), then the periods run.
        tim.ccmr1_output().modify(|_, w| w.oc1m().pwm_mode2());
        if !plan.cs_low_before {
            self.cs.set_low();
        }
        self.running = Running::Timer { bits, end };
        compiler_fence(Ordering::SeqCst);
        self.tim.cr1().modify(|_, w| w.cen().set_bit());
        Started::Running
    }

    fn finish_timer(&mut self, bits: usize, end: End) -> Result<WireBits, IoExtError> {
        self.clear_timer_flags(true);
        // The last sample is in; the last period ends at the update event,
        // where one-pulse mode clears CEN (SCK back at CPOL).
        let mut polls = 0;
        while self.tim.cr1().read().cen().bit_is_set() {
            polls += 1;
            if polls > END_POLLS {
                return Err(self.stop(IoExtError::EngineStuck));
            }
        }
        self.tim.dier().reset();
        compiler_fence(Ordering::SeqCst);
        self.end_cs(end);
        self.running = Running::Idle;
        let samples = self.bufs.samples.get(..bits).unwrap_or(&[]);
        Ok(WireBits::from_port_samples(samples, IOEXT_MISO_PIN))
    }

    fn clear_timer_flags(&mut self, all: bool) {
        self.dma2.lifcr().write(|w| {
            let w = w.chtif2().set_bit().cfeif2().set_bit();
            if all {
                w.ctcif2().set_bit().cteif2().set_bit().cdmeif2().set_bit()
            } else {
                w
            }
        });
        self.dma2.hifcr().write(|w| {
            w.ctcif6()
                .set_bit()
                .chtif6()
                .set_bit()
                .cfeif6()
                .set_bit()
                .cteif6()
                .set_bit()
                .cdmeif6()
                .set_bit()
        });
    }

    fn clear_all_flags(&mut self) {
        self.clear_spi_flags(true);
        self.clear_timer_flags(true);
    }

    // --- common --------------------------------------------------------------

    /// Half a period after the last edge, CS up unless the plan holds it.
    fn end_cs(&mut self, end: End) {
        cortex_m::asm::delay(end.half_period_cycles);
        if !end.cs_hold {
            self.cs.set_high();
        }
    }

    /// Stop whichever engine runs, raise CS, forget the transfer; `why`
    /// goes back to the caller.
    fn stop(&mut self, why: IoExtError) -> IoExtError {
        self.tim.cr1().modify(|_, w| w.cen().clear_bit());
        self.tim.dier().reset();
        self.spi
            .cr2()
            .modify(|_, w| w.rxdmaen().clear_bit().txdmaen().clear_bit());
        for s in [SPI_RX_STREAM, SPI_TX_STREAM] {
            self.dma1.st(s).cr().modify(|_, w| w.en().disabled());
        }
        for s in [TIM_SAMPLE_STREAM, TIM_MOSI_STREAM] {
            self.dma2.st(s).cr().modify(|_, w| w.en().disabled());
        }
        // SPI2 may have stopped mid-frame: set it up again next time.
        self.spi.cr1().modify(|_, w| w.spe().clear_bit());
        self.spi_setup = None;
        self.clear_all_flags();
        self.cs.set_high();
        self.running = Running::Idle;
        why
    }

    /// `Action::Disable`: CS high, SCK and MOSI back to inputs, engines off.
    fn release(&mut self) {
        self.cs.set_high();
        cortex_m::interrupt::free(|_| {
            gpiob()
                .moder()
                .modify(|_, w| w.moder(IOEXT_SCK_PIN).input().moder(IOEXT_MOSI_PIN).input());
        });
        self.spi.cr1().modify(|_, w| w.spe().clear_bit());
        self.spi_setup = None;
        self.tim.bdtr().modify(|_, w| w.moe().clear_bit());
        self.pins = PinsFor::Released;
    }

    /// Give the pins to `engine`, SCK pulled towards `cpol`.
    fn take_pins(&mut self, engine: PinsFor, cpol: bool) {
        let (sck, miso, mosi) = (IOEXT_SCK_PIN, IOEXT_MISO_PIN, IOEXT_MOSI_PIN);
        let switch = self.pins != engine;
        cortex_m::interrupt::free(|_| {
            let g = gpiob();
            g.pupdr().modify(|_, w| {
                let w = w.pupdr(sck);
                if cpol {
                    w.pull_up()
                } else {
                    w.pull_down()
                }
            });
            if !switch {
                return;
            }
            let af = if engine == PinsFor::Spi {
                AF_SPI2
            } else {
                AF_TIM1
            };
            g.afrh().modify(|_, w| {
                w.afr(sck - 8)
                    .set(af)
                    .afr(miso - 8)
                    .set(AF_SPI2)
                    .afr(mosi - 8)
                    .set(AF_SPI2)
            });
            g.moder().modify(|_, w| {
                let w = w.moder(sck).alternate().moder(miso).alternate();
                if engine == PinsFor::Spi {
                    w.moder(mosi).alternate()
                } else {
                    w.moder(mosi).output()
                }
            });
        });
        self.pins = engine;
    }

    /// CPU cycles for `ns`, rounded up.
    fn cycles(&self, ns: u64) -> u32 {
        let c = (ns * u64::from(self.sysclk_hz)).div_ceil(1_000_000_000);
        u32::try_from(c).unwrap_or(u32::MAX)
    }
}

/// Both streams read EN = 0 (a stream disabled by software finishes its
/// current beat first; its registers are only writable after that).
fn streams_stopped(dma: &pac::dma2::RegisterBlock, streams: [usize; 2]) -> bool {
    streams
        .iter()
        .all(|&s| (0..END_POLLS).any(|_| dma.st(s).cr().read().en().is_disabled()))
}
