//! The I/O extension's port (Copley-style raw SPI, `docs/ioext.md`): runs a
//! [`TransferPlan`] exactly as `bridge_logic::ioext::plan` describes it, and
//! decides nothing — every number (divider, timer registers, CS handling,
//! bits, half period) comes from the plan.
//!
//! Every register access goes through an [`IoExtHw`] — on the chip the
//! firmware's PAC glue (`firmware::drivers::ioext_spi`: SPI2, DMA1, DMA2,
//! TIM1, GPIOB, cycle delays, a critical section), on the host the RM0090
//! model `host_tests::rm0090::ioext` (SPI2 and TIM1 edge by edge, both DMA
//! controllers' streams, GPIOB's pins as levels, 74HC165/595 shift
//! registers behind MISO and MOSI).
//!
//! # Engines
//!
//! Both engines are one sequence ([`IoExtPort::run`]): the engine's
//! buffers from the plan, its streams stopped, the engine set up and the
//! pins given to it (SCK at CPOL), both streams' flags cleared and the
//! streams configured and loaded (EN = 0), the requests opened in the
//! order RM0090 asks for, CS low, and the engine started; at the end
//! ([`IoExtPort::on_interrupt`], the input stream's transfer complete) the
//! flags of both streams under [`Role::errors`](crate::dma::Role::errors),
//! the engine idle, its requests closed, half a period, CS. What differs is
//! in [`SPI_ENGINE`] and [`TIMER_ENGINE`] and four short `match`es.
//!
//! * **SPI engine** ([`TransferPlan::spi`]): SPI2 master, 8-bit frames, MSB
//!   first, software NSS, CR1.BR and CPOL/CPHA from the plan. DMA1 stream 3
//!   channel 0 (SPI2_RX, RM0090 table 42) moves the bytes in and interrupts
//!   at its end (`DMA1_STREAM3`); stream 4 channel 0 (SPI2_TX) moves them
//!   out. RXDMAEN, then the streams, then (after CS and the set-up wait)
//!   TXDMAEN (RM0090 §28.3.9). The end: BSY = 0, then both DMA requests
//!   closed.
//! * **Bit engine** ([`TransferPlan::timer`]): TIM1 in one-pulse PWM mode 2
//!   with RCR = bits − 1 makes exactly `bits` SCK periods on CH1N (PB13,
//!   AF1; CC1E = 0, CC1NE = 1, CC1NP = CPOL, MOE = 1). CC3 requests DMA2
//!   stream 6 (channel 6, TIM1_CH3, table 43) to write the plan's MOSI table
//!   to GPIOB_BSRR; CC2 requests DMA2 stream 2 (channel 6, TIM1_CH2) to copy
//!   GPIOB_IDR into the sample buffer, and that stream interrupts at its
//!   end (`DMA2_STREAM2`). The end: CEN = 0 (one-pulse mode clears it at
//!   the update after the last period), then the compare requests closed.
//!   DMA2, not DMA1: only DMA2's peripheral port reaches the GPIO ports on
//!   AHB1 (RM0090 §2.1).
//!
//! # CS and the half-period waits
//!
//! CS falls (unless the plan says it is still low) at least
//! [`TransferPlan::half_period_ns`] before the first clock edge: the SPI
//! engine busy-waits that long before it opens the TX request; the bit
//! engine's first phase (CNT < CCR1) is at least that long
//! ([`TimerSetup::ccr_sck`](bridge_logic::ioext::TimerSetup)). At the end
//! the driver busy-waits half a period after the last edge, then raises CS
//! unless the plan holds it. The waits are ≤ 3.05 µs on the SPI engine
//! (/256) and ≤ 12.8 µs on the bit engine (N = 255): they run in the DMA
//! interrupt, at the driver's priority.
//!
//! # Errors (never a hang)
//!
//! * TEIF or DMEIF of either stream, FEIF of every stream but the SPI
//!   engine's transmit stream (the one rule of [`crate::dma`]: its master
//!   clocks only the bytes it has; the bit engine's MOSI stream is paced by
//!   the timer, which does not wait): [`IoExtError::Dma`]; so is an output
//!   stream that has not finished (no TCIF) when the input stream has —
//!   its requests come first in every frame and bit.
//! * SPI2 still busy or TIM1 still counting after the last item (bounded
//!   polls), or a stream that does not stop: [`IoExtError::EngineStuck`].
//! * No end by the plan's timeout: the caller's [`IoExtPort::abort`] stops
//!   the engine ([`IoExtError::Timeout`]).
//!
//! Every error stops both engines: TIM1 stopped with SCK forced back to
//! CPOL, the streams disabled, SPI2 let finish its frame (BSY, bounded) and
//! disabled, its requests closed (RM0090 §28.3.9's closing order), the
//! flags cleared, CS high.
//!
//! # Pins
//!
//! `pins::configure` leaves SCK and MOSI as floating inputs and MISO as an
//! input with a pull-up; CS is high (and needs an external pull-up). The
//! first transfer takes them: SCK AF5 (SPI2_SCK) or AF1 (TIM1_CH1N) with an
//! internal pull towards CPOL, MOSI AF5 or a GPIO output, MISO AF5 (the bit
//! engine reads it through IDR, which works in AF mode). [`Action::Disable`]
//! raises CS and returns SCK and MOSI to inputs. Mode changes touch only
//! these pins' fields of GPIOB's MODER/AFRH/PUPDR, with interrupts masked
//! ([`IoExtHw::masked`]); CS and the bit engine's MOSI go through BSRR.

use bridge_logic::ioext::{Action, SpiSetup, TimerSetup, TransferPlan, WireBits};
use core::sync::atomic::{compiler_fence, Ordering};

use crate::dma::{self, Flags};
use crate::spi::bits::{SPI_CR1_SPE, SPI_CR2_RXDMAEN, SPI_CR2_TXDMAEN};
use crate::spi::{self, SpiReg};

mod map;
use map::bits::*;
pub use map::*;

/// Status polls after the last DMA item before the engine counts as
/// stuck (BSY or CEN still set), and for a stream's EN after a stop: far
/// beyond the longest legal wait (¾ of a 25.5 µs period), short enough not
/// to hang.
const END_POLLS: u32 = 200_000;

/// Which engine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Engine {
    Spi,
    Timer,
}

/// The plan's engine with its settings (worked out once a transfer).
#[derive(Clone, Copy, Debug)]
enum Setup {
    Spi(SpiSetup),
    Timer(TimerSetup),
}

impl Setup {
    fn engine(self) -> Engine {
        match self {
            Setup::Spi(_) => Engine::Spi,
            Setup::Timer(_) => Engine::Timer,
        }
    }
}

impl Engine {
    fn streams(self) -> &'static EngineStreams {
        match self {
            Engine::Spi => &SPI_ENGINE,
            Engine::Timer => &TIMER_ENGINE,
        }
    }
}

/// Which engine owns the pins now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Owner {
    Released,
    Spi,
    Timer,
}

/// The transfer in flight.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Transfer {
    engine: Engine,
    /// Frames (SPI) or bits (timer).
    items: u16,
    half_period_cycles: u32,
    cs_hold: bool,
}

/// The extension's port: SPI2, TIM1, their DMA streams, the pins and the
/// buffers (module docs).
#[derive(Debug)]
pub struct IoExtPort<H> {
    hw: H,
    sysclk_hz: u32,
    owner: Owner,
    /// CR1 SPI2 is enabled with (`None`: not set up).
    spi_cr1: Option<u32>,
    running: Option<Transfer>,
}

impl<H: IoExtHw> IoExtPort<H> {
    /// The port on `hw`, with CS high as `pins::configure` left it;
    /// nothing is driven until the first transfer. The caller has clocked
    /// and reset SPI2 and TIM1 and clocked DMA1 and DMA2.
    pub fn new(hw: H, sysclk_hz: u32) -> IoExtPort<H> {
        IoExtPort {
            hw,
            sysclk_hz,
            owner: Owner::Released,
            spi_cr1: None,
            running: None,
        }
    }

    /// The hardware handle (on the host: the model).
    pub fn hw(&self) -> &H {
        &self.hw
    }

    pub fn hw_mut(&mut self) -> &mut H {
        &mut self.hw
    }

    /// A transfer is in flight.
    pub fn is_running(&self) -> bool {
        self.running.is_some()
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
            Action::Transfer(plan) => self.start(plan),
        }
    }

    /// From the input stream's interrupt (`DMA1_STREAM3`, `DMA2_STREAM2`):
    /// the end of the running transfer with its received bits, or `None`
    /// if it is still running (or nothing runs).
    pub fn on_interrupt(&mut self) -> Option<Result<WireBits, IoExtError>> {
        let Some(t) = self.running else {
            self.clear_all_flags();
            return None;
        };
        let s = t.engine.streams();
        let dma = s.controller.reg();
        let (input, output) = dma::read_pair(&mut self.hw, dma, s.input.number, s.output.number);
        if input.intersects(s.input.role.errors()) || output.intersects(s.output.role.errors()) {
            return Some(Err(self.stop(IoExtError::Dma)));
        }
        if !input.contains(Flags::TCIF) {
            // Exactly the flags seen (one that sets after the read stays),
            // but the output stream's TCIF, which the end looks for.
            let output = Flags::from_bits(output.bits() & !Flags::TCIF.bits());
            dma::clear(
                &mut self.hw,
                dma,
                &[(s.input.number, input), (s.output.number, output)],
            );
            return None;
        }
        // Every item out before the last one came in (the output's requests
        // come first in every bit and frame): a stream that fell silent
        // (stuck, or disabled) ends the transfer as a DMA error.
        if !output.contains(Flags::TCIF) {
            return Some(Err(self.stop(IoExtError::Dma)));
        }
        dma::clear(
            &mut self.hw,
            dma,
            &[(s.input.number, input), (s.output.number, output)],
        );
        Some(self.finish(t))
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

    // --- the one sequence -----------------------------------------------------

    fn start(&mut self, plan: &TransferPlan) -> Started {
        let setup = match plan.spi() {
            Some(s) => Setup::Spi(s),
            None => match plan.timer() {
                Some(t) => Setup::Timer(t),
                None => return Started::Ended(Err(IoExtError::BadPlan)),
            },
        };
        let engine = setup.engine();
        let s = engine.streams();
        let dma = s.controller.reg();
        // A stream disabled by a stop finishes its item first; its
        // registers (and buffer) are free only once EN reads 0.
        let (input, output) = (s.input.number, s.output.number);
        if !dma::wait_disabled(&mut self.hw, dma, input, output, END_POLLS) {
            return Started::Ended(Err(self.stop(IoExtError::EngineStuck)));
        }
        let items = self.load(setup, plan);
        if items == 0 {
            return Started::Ended(Err(IoExtError::BadPlan));
        }
        self.set_up(setup, plan.mode.cpol);
        // The streams: flags of the last transfer cleared, then configured
        // and loaded while EN = 0 (RM0090 §10.3.17).
        dma::clear_with(&mut self.hw, dma, s.clear_all);
        for (stream, par, mem) in [
            (&s.input, s.input_par, s.input_mem),
            (&s.output, s.output_par, s.output_mem),
        ] {
            let (par, mem) = (self.hw.address(par), self.hw.address(mem));
            dma::configure(&mut self.hw, dma, stream, par);
            dma::load(&mut self.hw, dma, stream.number, mem, u32::from(items));
        }
        // The buffers are written before a stream can read them.
        compiler_fence(Ordering::SeqCst);
        // The requests in RM0090's order: SPI2's RX request before the
        // streams (§28.3.9), the timer's compare requests after them (a
        // request while its stream is off would be lost).
        if engine == Engine::Spi {
            self.hw
                .modify(IoReg::Spi(SpiReg::Cr2), |cr2| cr2 | SPI_CR2_RXDMAEN);
        }
        dma::enable(&mut self.hw, dma, s.input.number);
        dma::enable(&mut self.hw, dma, s.output.number);
        if engine == Engine::Timer {
            let hw = &mut self.hw;
            hw.write(IoReg::Tim(TimReg::Dier), TIM_DIER_CC2DE | TIM_DIER_CC3DE);
            // PWM mode 2: OC1REF low while CNT < CCR1, so SCK stays at
            // CPOL for the first phase (the CS set-up), then the periods
            // run.
            hw.modify(IoReg::Tim(TimReg::Ccmr1), |m| {
                (m & !TIM_CCMR1_OC1M_MASK) | (TIM_OCM_PWM2 << TIM_CCMR1_OC1M_SHIFT)
            });
        }
        let half_period_cycles = cycles(plan.half_period_ns(), self.sysclk_hz);
        if !plan.cs_low_before {
            self.cs(false);
            if engine == Engine::Spi {
                // The bit engine's first phase is this wait.
                self.hw.delay_cycles(half_period_cycles);
            }
        }
        self.running = Some(Transfer {
            engine,
            items,
            half_period_cycles,
            cs_hold: plan.cs_hold,
        });
        compiler_fence(Ordering::SeqCst);
        match engine {
            Engine::Spi => self
                .hw
                .modify(IoReg::Spi(SpiReg::Cr2), |cr2| cr2 | SPI_CR2_TXDMAEN),
            Engine::Timer => self
                .hw
                .modify(IoReg::Tim(TimReg::Cr1), |cr1| cr1 | TIM_CR1_CEN),
        }
        Started::Running
    }

    /// The engine's buffers from the plan: the number of DMA items (frames
    /// or bits), 0 if there is nothing to move.
    fn load(&mut self, setup: Setup, plan: &TransferPlan) -> u16 {
        let mosi = H::PINS.mosi;
        let n = self.hw.buffers(|b| match setup {
            Setup::Spi(s) => {
                let frames = usize::from(s.frames).min(b.tx.len());
                for (j, byte) in b.tx.iter_mut().enumerate().take(frames) {
                    *byte = plan.tx_byte(j);
                }
                frames
            }
            Setup::Timer(_) => plan.mosi_bsrr(mosi, &mut b.mosi_bsrr),
        });
        u16::try_from(n).unwrap_or(0)
    }

    /// The engine set up as the plan says, the pins given to it, SCK at
    /// CPOL throughout.
    fn set_up(&mut self, setup: Setup, cpol: bool) {
        match setup {
            Setup::Spi(s) => {
                // Only when it changes (never while CS is held low: the
                // logic refuses a CPOL change then), so SCK keeps its level.
                let cr1 = spi::master_cr1(u32::from(s.br), s.mode.cpol, s.mode.cpha);
                if self.spi_cr1 != Some(cr1) {
                    let hw = &mut self.hw;
                    hw.modify(IoReg::Spi(SpiReg::Cr1), |v| v & !SPI_CR1_SPE);
                    hw.write(IoReg::Spi(SpiReg::Cr1), cr1);
                    hw.modify(IoReg::Spi(SpiReg::Cr1), |v| v | SPI_CR1_SPE);
                    self.spi_cr1 = Some(cr1);
                }
                self.take_pins(Owner::Spi, cpol);
                // A stale byte or an overrun from an aborted transfer.
                spi::drain(&mut self.hw, IoReg::Spi);
            }
            Setup::Timer(t) => {
                let hw = &mut self.hw;
                let tim = IoReg::Tim;
                // Stopped, one-pulse, upcounting; PSC and RCR loaded by UG.
                hw.write(tim(TimReg::Cr1), TIM_CR1_OPM);
                hw.write(tim(TimReg::Dier), 0);
                hw.write(tim(TimReg::Psc), u32::from(t.psc));
                hw.write(tim(TimReg::Arr), u32::from(t.arr));
                hw.write(tim(TimReg::Rcr), u32::from(t.rcr));
                hw.write(tim(TimReg::Ccr1), u32::from(t.ccr_sck));
                hw.write(tim(TimReg::Ccr2), u32::from(t.ccr_sample));
                hw.write(tim(TimReg::Ccr3), u32::from(t.ccr_mosi));
                // CH1 forced inactive until the start (OC1N = CPOL), CH2
                // and CH3 pure compares (no output) for the DMA requests.
                hw.write(
                    tim(TimReg::Ccmr1),
                    (TIM_OCM_FORCE_INACTIVE << TIM_CCMR1_OC1M_SHIFT)
                        | (TIM_OCM_FROZEN << TIM_CCMR1_OC2M_SHIFT),
                );
                hw.write(tim(TimReg::Ccmr2), TIM_OCM_FROZEN << TIM_CCMR2_OC3M_SHIFT);
                hw.write(
                    tim(TimReg::Ccer),
                    TIM_CCER_CC1NE | if cpol { TIM_CCER_CC1NP } else { 0 },
                );
                hw.write(tim(TimReg::Bdtr), TIM_BDTR_MOE);
                hw.write(tim(TimReg::Egr), TIM_EGR_UG);
                hw.write(tim(TimReg::Sr), 0);
                // MOSI takes bit 0 before the pin becomes an output.
                let mosi = H::PINS.mosi;
                hw.write(IoReg::Gpio(GpioReg::Bsrr), bsrr(mosi, t.first_mosi));
                self.take_pins(Owner::Timer, cpol);
            }
        }
    }

    /// The input stream's last item is in: the engine idle, its requests
    /// closed, half a period, CS; the received bits.
    fn finish(&mut self, t: Transfer) -> Result<WireBits, IoExtError> {
        let idle = match t.engine {
            // The last byte is in: SPI2 lets go of the bus (BSY).
            Engine::Spi => spi::wait_idle(&mut self.hw, IoReg::Spi, END_POLLS),
            // The last sample is in; the last period ends at the update
            // event, where one-pulse mode clears CEN (SCK back at CPOL).
            Engine::Timer => {
                (0..END_POLLS).any(|_| self.hw.read(IoReg::Tim(TimReg::Cr1)) & TIM_CR1_CEN == 0)
            }
        };
        if !idle {
            return Err(self.stop(IoExtError::EngineStuck));
        }
        match t.engine {
            Engine::Spi => self.hw.modify(IoReg::Spi(SpiReg::Cr2), |cr2| {
                cr2 & !(SPI_CR2_RXDMAEN | SPI_CR2_TXDMAEN)
            }),
            Engine::Timer => self.hw.write(IoReg::Tim(TimReg::Dier), 0),
        }
        compiler_fence(Ordering::SeqCst);
        // Half a period after the last edge, CS up unless the plan holds it.
        self.hw.delay_cycles(t.half_period_cycles);
        if !t.cs_hold {
            self.cs(true);
        }
        self.running = None;
        let (items, miso) = (usize::from(t.items), H::PINS.miso);
        Ok(self.hw.buffers(|b| match t.engine {
            Engine::Spi => WireBits::from_bytes(b.rx.get(..items).unwrap_or(&[])),
            Engine::Timer => {
                WireBits::from_port_samples(b.samples.get(..items).unwrap_or(&[]), miso)
            }
        }))
    }

    /// Stop both engines, raise CS, forget the transfer; `why` goes back to
    /// the caller (module docs, "Errors").
    fn stop(&mut self, why: IoExtError) -> IoExtError {
        let hw = &mut self.hw;
        let tim = IoReg::Tim;
        // TIM1: no more periods or requests, SCK back to CPOL.
        hw.write(tim(TimReg::Cr1), TIM_CR1_OPM);
        hw.write(tim(TimReg::Dier), 0);
        hw.modify(tim(TimReg::Ccmr1), |m| {
            (m & !TIM_CCMR1_OC1M_MASK) | (TIM_OCM_FORCE_INACTIVE << TIM_CCMR1_OC1M_SHIFT)
        });
        // SPI2, in RM0090's closing order: streams, the SPI (its frame
        // finished, then SPE = 0), then its requests.
        for s in [&SPI_ENGINE, &TIMER_ENGINE] {
            let dma = s.controller.reg();
            dma::disable(hw, dma, s.input.number);
            dma::disable(hw, dma, s.output.number);
        }
        let _ = spi::wait_idle(hw, IoReg::Spi, END_POLLS);
        hw.modify(IoReg::Spi(SpiReg::Cr1), |v| v & !SPI_CR1_SPE);
        self.spi_cr1 = None;
        hw.modify(IoReg::Spi(SpiReg::Cr2), |cr2| {
            cr2 & !(SPI_CR2_RXDMAEN | SPI_CR2_TXDMAEN)
        });
        self.clear_all_flags();
        self.cs(true);
        self.running = None;
        why
    }

    /// Every flag of the four streams.
    fn clear_all_flags(&mut self) {
        for s in [&SPI_ENGINE, &TIMER_ENGINE] {
            dma::clear_with(&mut self.hw, s.controller.reg(), s.clear_all);
        }
    }

    /// `Action::Disable`: CS high, SCK and MOSI back to inputs, engines off.
    fn release(&mut self) {
        self.cs(true);
        let (sck, mosi) = (H::PINS.sck, H::PINS.mosi);
        self.hw.masked(|hw| {
            hw.modify(IoReg::Gpio(GpioReg::Moder), |m| {
                set_field(
                    set_field(m, sck, 2, GPIO_MODE_INPUT),
                    mosi,
                    2,
                    GPIO_MODE_INPUT,
                )
            });
        });
        let hw = &mut self.hw;
        hw.modify(IoReg::Spi(SpiReg::Cr1), |v| v & !SPI_CR1_SPE);
        self.spi_cr1 = None;
        hw.modify(IoReg::Tim(TimReg::Bdtr), |v| v & !TIM_BDTR_MOE);
        self.owner = Owner::Released;
    }

    /// Give the pins to `owner`, SCK pulled towards `cpol`.
    fn take_pins(&mut self, owner: Owner, cpol: bool) {
        let Pins {
            sck, miso, mosi, ..
        } = H::PINS;
        let switch = self.owner != owner;
        self.hw.masked(|hw| {
            let pull = if cpol { GPIO_PULL_UP } else { GPIO_PULL_DOWN };
            hw.modify(IoReg::Gpio(GpioReg::Pupdr), |p| set_field(p, sck, 2, pull));
            if !switch {
                return;
            }
            let af = if owner == Owner::Spi {
                AF_SPI2
            } else {
                AF_TIM1
            };
            hw.modify(IoReg::Gpio(GpioReg::Afrh), |a| {
                let a = set_field(a, sck.wrapping_sub(8), 4, af);
                let a = set_field(a, miso.wrapping_sub(8), 4, AF_SPI2);
                set_field(a, mosi.wrapping_sub(8), 4, AF_SPI2)
            });
            let mosi_mode = if owner == Owner::Spi {
                GPIO_MODE_AF
            } else {
                GPIO_MODE_OUTPUT
            };
            hw.modify(IoReg::Gpio(GpioReg::Moder), |m| {
                let m = set_field(m, sck, 2, GPIO_MODE_AF);
                let m = set_field(m, miso, 2, GPIO_MODE_AF);
                set_field(m, mosi, 2, mosi_mode)
            });
        });
        self.owner = owner;
    }

    /// CS high or low (GPIOB_BSRR).
    fn cs(&mut self, high: bool) {
        let cs = H::PINS.cs;
        self.hw.write(IoReg::Gpio(GpioReg::Bsrr), bsrr(cs, high));
    }
}

/// The GPIO BSRR word that drives `pin` (0..=15) to `level`.
const fn bsrr(pin: u8, level: bool) -> u32 {
    let bit = 1u32 << (pin % 16);
    if level {
        bit
    } else {
        bit << 16
    }
}

/// `reg` with the `width`-bit field of index `field` set to `value`
/// (fields past bit 31 change nothing).
const fn set_field(reg: u32, field: u8, width: u32, value: u32) -> u32 {
    let shift = (field as u32).wrapping_mul(width);
    if shift >= 32 {
        return reg;
    }
    let ones = match 1u32.checked_shl(width) {
        Some(v) => v.wrapping_sub(1),
        None => u32::MAX,
    };
    let mask = ones << shift;
    (reg & !mask) | ((value << shift) & mask)
}

/// CPU cycles of `hz` for `ns`, rounded up.
fn cycles(ns: u64, hz: u32) -> u32 {
    let c = ns.saturating_mul(u64::from(hz)).div_ceil(1_000_000_000);
    u32::try_from(c).unwrap_or(u32::MAX)
}
