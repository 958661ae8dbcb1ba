//! The powerSTEP01 chain on SPI1, DMA2 streams 0/3, TIM7 and the CS line
//! PA4: the PAC glue under [`drivers_core::chain_spi`], where the one
//! driver — blocking windows, the DMA batch and every register sequence —
//! lives (tested on the host against the RM0090 model
//! `host_tests::rm0090::chain_spi`, with the bridge's control ticks through
//! driver and model into the simulated chips). This module clocks and
//! resets SPI1 and TIM7, clocks DMA2, maps the driver's register ids to the
//! PAC's register blocks, drives CS through GPIOA_BSRR, busy-waits CPU
//! cycles, clears the two interrupts' NVIC pending bits, and gives the DMA
//! the `'static` buffers' addresses.
//!
//! [`ChainCell`] is where the one driver lives on the chip: the bridge's
//! chain bus ([`ChainLink`], a handle that asks the driver for each
//! blocking window), the control tick (start, poll) and the two interrupts
//! reach it, each access in a critical section.

// Register blocks, DMA addresses: each block says why it is sound.
#![allow(unsafe_code)]

use bridge_logic::powerstep::chain::{ChainBus, Frames};
use core::cell::RefCell;
use cortex_m::interrupt::Mutex;
use cortex_m::peripheral::NVIC;
use drivers_core::chain_spi::{self as core_spi, ChainClocks, ChainHw, ChainMemory, ChainReg};
use drivers_core::spi::SpiReg;
use drivers_core::Regs;
use stm32f4xx_hal::pac::{self, Interrupt};
use stm32f4xx_hal::rcc::{Enable, Rcc, Reset};

use crate::drivers::dma;
use crate::pins::{ChainGapTimer, ChainLines, ChainSpi as ChainSpiPeriph, CHAIN_CS_PIN};

pub use drivers_core::chain_spi::{
    ChainBuffers, ChainDmaStats, ChainSpiError, CS_DESELECT_NS, CS_SETUP_NS, DMEIF0, DMEIF3, FEIF0,
    SCK_MAX_HZ, TCIF0, TEIF0, TEIF3,
};

/// The chain's one driver: blocking windows and the control tick's batches.
pub type ChainSpi = core_spi::ChainSpi<ChainRegs>;

/// SPI1's registers.
fn spi1() -> &'static pac::spi1::RegisterBlock {
    // SAFETY: SPI1 is always mapped; its PAC singleton was consumed by
    // `chain_spi`, and the one driver it returned is its only user.
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

/// TIM7's registers.
fn tim7() -> &'static pac::tim6::RegisterBlock {
    // SAFETY: TIM7 is always mapped; its PAC singleton was consumed by
    // `chain_spi` and the one driver is its only user.
    unsafe { &*pac::TIM7::ptr() }
}

/// The chain's hardware as the driver's [`ChainHw`], with the batch
/// buffers.
pub struct ChainRegs {
    bufs: &'static mut ChainBuffers,
}

impl Regs<ChainReg> for ChainRegs {
    #[inline]
    fn read(&mut self, reg: ChainReg) -> u32 {
        read(reg)
    }

    #[inline]
    fn write(&mut self, reg: ChainReg, value: u32) {
        write(reg, value);
    }
}

impl ChainHw for ChainRegs {
    #[inline]
    fn cs(&mut self, high: bool) {
        cs(high);
    }

    #[inline]
    fn delay_cycles(&mut self, cycles: u32) {
        cortex_m::asm::delay(cycles);
    }

    fn unpend_interrupts(&mut self) {
        NVIC::unpend(Interrupt::TIM7);
        NVIC::unpend(Interrupt::DMA2_STREAM0);
    }
}

/// CS (PA4) high or low.
#[inline]
fn cs(high: bool) {
    // SAFETY: GPIOA is always mapped; BSRR writes are atomic and touch
    // only the bit written. The CS pin's HAL handle was consumed by
    // `chain_spi` (configured as a push-pull output, high); nothing else
    // drives it.
    let gpioa = unsafe { &*pac::GPIOA::ptr() };
    gpioa.bsrr().write(|w| {
        if high {
            w.bs(CHAIN_CS_PIN).set_bit()
        } else {
            w.br(CHAIN_CS_PIN).set_bit()
        }
    });
}

/// One read of the chain register `reg`.
#[inline]
fn read(reg: ChainReg) -> u32 {
    let (spi, tim) = (spi1(), tim7());
    match reg {
        ChainReg::Spi(SpiReg::Cr1) => u32::from(spi.cr1().read().bits()),
        ChainReg::Spi(SpiReg::Cr2) => u32::from(spi.cr2().read().bits()),
        ChainReg::Spi(SpiReg::Sr) => u32::from(spi.sr().read().bits()),
        ChainReg::Spi(SpiReg::Dr) => u32::from(spi.dr8().read().dr().bits()),
        ChainReg::Dma(r) => dma::read(dma2(), r),
        ChainReg::TimCr1 => tim.cr1().read().bits(),
        ChainReg::TimDier => tim.dier().read().bits(),
        ChainReg::TimSr => tim.sr().read().bits(),
        ChainReg::TimEgr => 0,
        ChainReg::TimCnt => tim.cnt().read().bits(),
        ChainReg::TimPsc => tim.psc().read().bits(),
        ChainReg::TimArr => tim.arr().read().bits(),
    }
}

/// One write of `value` to the chain register `reg`.
#[inline]
fn write(reg: ChainReg, value: u32) {
    let (spi, tim) = (spi1(), tim7());
    // SPI1's registers are 16 bits wide (RM0090 §28.5).
    let v16 = value as u16;
    if let ChainReg::Dma(r) = reg {
        dma::write(dma2(), r, value);
        return;
    }
    // SAFETY: one volatile write of the whole register. The values come
    // from `drivers_core::chain_spi` (SPI1 mode 3 master, TIM7 one-pulse),
    // checked against the RM0090 model on the host.
    unsafe {
        match reg {
            ChainReg::Spi(SpiReg::Cr1) => {
                spi.cr1().write(|w| w.bits(v16));
            }
            ChainReg::Spi(SpiReg::Cr2) => {
                spi.cr2().write(|w| w.bits(v16));
            }
            ChainReg::Spi(SpiReg::Sr) => {
                spi.sr().write(|w| w.bits(v16));
            }
            ChainReg::Spi(SpiReg::Dr) => {
                spi.dr8().write(|w| w.dr().set(value as u8));
            }
            ChainReg::Dma(_) => {}
            ChainReg::TimCr1 => {
                tim.cr1().write(|w| w.bits(value));
            }
            ChainReg::TimDier => {
                tim.dier().write(|w| w.bits(value));
            }
            ChainReg::TimSr => {
                tim.sr().write(|w| w.bits(value));
            }
            ChainReg::TimEgr => {
                tim.egr().write(|w| w.bits(value));
            }
            ChainReg::TimCnt => {
                tim.cnt().write(|w| w.bits(value));
            }
            ChainReg::TimPsc => {
                tim.psc().write(|w| w.bits(value));
            }
            ChainReg::TimArr => {
                tim.arr().write(|w| w.bits(value));
            }
        };
    }
}

impl ChainMemory for ChainRegs {
    #[inline]
    fn write_tx_rows(&mut self, frames: &Frames, windows: usize) {
        for (dst, src) in self.bufs.tx.iter_mut().zip(frames).take(windows) {
            *dst = *src;
        }
    }

    #[inline]
    fn read_rx_rows(&self, out: &mut Frames, windows: usize) {
        for (dst, src) in out.iter_mut().zip(&self.bufs.rx).take(windows) {
            *dst = *src;
        }
    }

    #[inline]
    fn row_address(&self, rx: bool, w: usize) -> Option<u32> {
        let row = if rx {
            self.bufs.rx.get(w)?
        } else {
            self.bufs.tx.get(w)?
        };
        // RAM addresses fit in 32 bits on the Cortex-M4.
        Some(row.as_ptr() as usize as u32)
    }

    fn dr_address(&self) -> u32 {
        spi1().dr().as_ptr() as usize as u32
    }
}

/// What the chain's driver owns: SPI1, its lines (as `pins::configure`
/// left them, CS high) and TIM7, the gap timer.
#[derive(Debug)]
pub struct ChainPeripherals {
    pub spi: ChainSpiPeriph,
    pub tim: ChainGapTimer,
    pub lines: ChainLines,
}

/// Take the chain's peripherals and return their one driver. Clocks and
/// resets SPI1 and TIM7, clocks DMA2 (never reset: the I/O extension uses
/// it too).
pub fn chain_spi(
    peripherals: ChainPeripherals,
    bufs: &'static mut ChainBuffers,
    rcc: &mut Rcc,
) -> ChainSpi {
    ChainSpiPeriph::enable(rcc);
    ChainSpiPeriph::reset(rcc);
    ChainGapTimer::enable(rcc);
    ChainGapTimer::reset(rcc);
    pac::DMA2::enable(rcc);
    let clocks = ChainClocks {
        pclk2_hz: rcc.clocks.pclk2().raw(),
        sysclk_hz: rcc.clocks.sysclk().raw(),
        timclk_hz: rcc.clocks.timclk1().raw(),
    };
    // The pins keep the modes `pins::configure` gave them; from here on
    // SPI1, TIM7 and CS are driven through their registers (module docs).
    let _ = peripherals;
    core_spi::ChainSpi::new(ChainRegs { bufs }, clocks)
}

/// Where the one chain driver lives: the bridge's [`ChainLink`], the
/// control tick and the chain's interrupts reach it through
/// [`ChainCell::with`], one critical section each. A `static` (one per
/// platform, whose driver type it holds): the interrupts need it without
/// the bridge's lock, the bridge needs it without the interrupts' priority.
pub struct ChainCell<D>(Mutex<RefCell<Slot<D>>>);

/// The cell's content. An explicit zero tag for `Empty`, so the empty
/// cell is all zeros and the `static` lands in `.bss` (an `Option`'s
/// `None` may use a niche and put the whole driver's size in `.data`).
#[repr(u8)]
enum Slot<D> {
    Empty = 0,
    Full(D),
}

impl<D> ChainCell<D> {
    pub const fn new() -> ChainCell<D> {
        ChainCell(Mutex::new(RefCell::new(Slot::Empty)))
    }

    /// Put the driver in (once, in `init`) and return the bridge's handle.
    pub fn install(&'static self, driver: D) -> ChainLink<D> {
        cortex_m::interrupt::free(|cs| {
            self.0.borrow(cs).replace(Slot::Full(driver));
        });
        ChainLink(self)
    }

    /// Run `f` on the driver with interrupts masked; `None` before
    /// [`ChainCell::install`].
    #[inline]
    pub fn with<R>(&self, f: impl FnOnce(&mut D) -> R) -> Option<R> {
        cortex_m::interrupt::free(|cs| match &mut *self.0.borrow(cs).borrow_mut() {
            Slot::Full(d) => Some(f(d)),
            Slot::Empty => None,
        })
    }
}

impl<D> Default for ChainCell<D> {
    fn default() -> Self {
        Self::new()
    }
}

/// The bridge's chain bus: a handle that asks the one driver for each
/// blocking window (refused with `Busy` while a batch runs, by the driver
/// itself). A window masks interrupts for its length: ≤ 27 µs for 8 chips
/// (t_disCS, t_setCS, 8 bytes at 2.625 MHz, t_disCS), at boot (chain
/// detection, interrupts still off) and in the three recovery windows
/// after a bus error.
pub struct ChainLink<D: 'static>(&'static ChainCell<D>);

impl<D> ChainLink<D> {
    /// Run `f` on the driver (`None` cannot happen: a link exists only
    /// once its cell holds the driver).
    #[inline]
    pub fn with<R>(&mut self, f: impl FnOnce(&mut D) -> R) -> Option<R> {
        self.0.with(f)
    }
}

impl<D: ChainBus<Error = ChainSpiError>> ChainBus for ChainLink<D> {
    type Error = ChainSpiError;

    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ChainSpiError> {
        self.0
            .with(|d| d.window(tx, rx))
            .unwrap_or(Err(ChainSpiError::Busy))
    }
}
