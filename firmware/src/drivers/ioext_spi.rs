//! The I/O extension's port (Copley-style raw SPI, `docs/ioext.md`) on
//! SPI2, TIM1, DMA1 streams 3/4, DMA2 streams 2/6 and PB11/PB13–PB15: the
//! PAC glue under [`drivers_core::ioext_spi`], where both engines, the CS
//! handling, the end, the abort and every register sequence live (tested on
//! the host against the RM0090 model `host_tests::rm0090::ioext`, with
//! 74HC165/595 shift registers behind the pins). This module clocks and
//! resets SPI2 and TIM1, clocks DMA1 and DMA2, maps the driver's register
//! ids to the PAC's register blocks, busy-waits CPU cycles, masks
//! interrupts for the driver's GPIOB read-modify-writes and gives the DMA
//! the `'static` buffers' and the data registers' addresses.
//!
//! # What is not verified
//!
//! Built, never run on a board: `tests/ioext_spi.rs` (board only, MOSI
//! jumpered to MISO) checks loopback, CS and the interrupt on hardware.
//! QEMU 7.2 models neither DMA nor TIM1, so the QEMU image replaces this
//! driver (`platform/qemu.rs`); `tests/ioext_abort.rs` runs it under QEMU,
//! where no transfer ends (SPI2 set-up, the timeout path).

// The register blocks and whole-register writes (see each block).
#![allow(unsafe_code)]

use drivers_core::ioext_spi::{self as core_io, GpioReg, IoExtHw, IoReg, Pins, Target, TimReg};
use drivers_core::spi::SpiReg;
use drivers_core::Regs;
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::{Enable, Rcc, Reset};

use crate::drivers::dma;
use crate::pins::{
    IoExtLines, IoExtSpi, IoExtSpiDma, IoExtTimer, IoExtTimerDma, IOEXT_CS_PIN, IOEXT_MISO_PIN,
    IOEXT_MOSI_PIN, IOEXT_SCK_PIN,
};

pub use drivers_core::ioext_spi::{IoExtBuffers, IoExtError, Started};

/// The extension's port: the driver on this chip's registers.
pub type IoExtPort = core_io::IoExtPort<IoExtRegs>;

/// The port's pins on GPIOB (`pins.rs`).
pub const PINS: Pins = Pins {
    cs: IOEXT_CS_PIN,
    sck: IOEXT_SCK_PIN,
    miso: IOEXT_MISO_PIN,
    mosi: IOEXT_MOSI_PIN,
};

// The driver's AFRH fields and the samples' bits.
const _: () = assert!(
    IOEXT_MOSI_PIN < 16
        && IOEXT_MISO_PIN < 16
        && IOEXT_CS_PIN < 16
        && IOEXT_SCK_PIN >= 8
        && IOEXT_MISO_PIN >= 8
        && IOEXT_MOSI_PIN >= 8
);

/// Register offsets (RM0090 §28.5.4, §8.4.5, §8.4.7).
const SPI_DR: u32 = 0x0C;
const GPIO_IDR: u32 = 0x10;
const GPIO_BSRR: u32 = 0x18;

/// The register blocks the driver names.
struct Blocks {
    spi: &'static pac::spi1::RegisterBlock,
    dma1: &'static pac::dma2::RegisterBlock,
    dma2: &'static pac::dma2::RegisterBlock,
    tim: &'static pac::tim1::RegisterBlock,
    gpio: &'static pac::gpiob::RegisterBlock,
}

#[inline]
fn blocks() -> Blocks {
    // SAFETY: every block is always mapped. SPI2's, TIM1's and DMA1's PAC
    // singletons were consumed by `ioext_port`, and the one port it
    // returned is their only user. DMA2 is shared with the chain driver:
    // this one names only streams 2 and 6 and their bits of the
    // write-1-to-clear LIFCR/HIFCR (`drivers_core::ioext_spi`). GPIOB is
    // shared with other pins: the port writes its BSRR (atomic, only CS and
    // MOSI) and changes only PB13–PB15's fields of MODER/PUPDR/AFRH, with
    // interrupts masked (`masked`).
    unsafe {
        Blocks {
            spi: &*pac::SPI2::ptr(),
            dma1: &*pac::DMA1::ptr(),
            dma2: &*pac::DMA2::ptr(),
            tim: &*pac::TIM1::ptr(),
            gpio: &*pac::GPIOB::ptr(),
        }
    }
}

/// The port's hardware as the driver's [`IoExtHw`], with its buffers.
pub struct IoExtRegs {
    bufs: &'static mut IoExtBuffers,
}

impl Regs<IoReg> for IoExtRegs {
    #[inline]
    fn read(&mut self, reg: IoReg) -> u32 {
        let b = blocks();
        match reg {
            IoReg::Spi(r) => u32::from(match r {
                SpiReg::Cr1 => b.spi.cr1().read().bits(),
                SpiReg::Cr2 => b.spi.cr2().read().bits(),
                SpiReg::Sr => b.spi.sr().read().bits(),
                SpiReg::Dr => b.spi.dr().read().bits(),
            }),
            // One copy of the DMA `match` for both controllers.
            IoReg::Dma1(r) | IoReg::Dma2(r) => {
                let block = if matches!(reg, IoReg::Dma1(_)) {
                    b.dma1
                } else {
                    b.dma2
                };
                dma::read(block, r)
            }
            IoReg::Tim(r) => {
                let t = b.tim;
                match r {
                    TimReg::Cr1 => t.cr1().read().bits(),
                    TimReg::Dier => t.dier().read().bits(),
                    TimReg::Sr => t.sr().read().bits(),
                    TimReg::Egr => 0,
                    TimReg::Ccmr1 => t.ccmr1_output().read().bits(),
                    TimReg::Ccmr2 => t.ccmr2_output().read().bits(),
                    TimReg::Ccer => t.ccer().read().bits(),
                    TimReg::Cnt => t.cnt().read().bits(),
                    TimReg::Psc => t.psc().read().bits(),
                    TimReg::Arr => t.arr().read().bits(),
                    TimReg::Rcr => t.rcr().read().bits(),
                    TimReg::Ccr1 => t.ccr(0).read().bits(),
                    TimReg::Ccr2 => t.ccr(1).read().bits(),
                    TimReg::Ccr3 => t.ccr(2).read().bits(),
                    TimReg::Bdtr => t.bdtr().read().bits(),
                }
            }
            IoReg::Gpio(r) => match r {
                GpioReg::Moder => b.gpio.moder().read().bits(),
                GpioReg::Pupdr => b.gpio.pupdr().read().bits(),
                GpioReg::Afrh => b.gpio.afrh().read().bits(),
                GpioReg::Idr => b.gpio.idr().read().bits(),
                // Write-only.
                GpioReg::Bsrr => 0,
            },
        }
    }

    #[inline]
    fn write(&mut self, reg: IoReg, value: u32) {
        let b = blocks();
        let v16 = value as u16;
        let (spi, t, g) = (b.spi, b.tim, b.gpio);
        if let IoReg::Dma1(r) | IoReg::Dma2(r) = reg {
            let block = if matches!(reg, IoReg::Dma1(_)) {
                b.dma1
            } else {
                b.dma2
            };
            return dma::write(block, r, value);
        }
        // SAFETY: one volatile write of the whole register. The values come
        // from `drivers_core::ioext_spi` (SPI2 as the plan's master, TIM1's
        // bit engine, GPIOB fields of the port's own pins, BSRR words for CS
        // and MOSI), checked against the RM0090 model on the host.
        unsafe {
            match reg {
                IoReg::Spi(SpiReg::Cr1) => {
                    spi.cr1().write(|w| w.bits(v16));
                }
                IoReg::Spi(SpiReg::Cr2) => {
                    spi.cr2().write(|w| w.bits(v16));
                }
                IoReg::Spi(SpiReg::Sr) => {
                    spi.sr().write(|w| w.bits(v16));
                }
                IoReg::Spi(SpiReg::Dr) => {
                    spi.dr().write(|w| w.bits(v16));
                }
                IoReg::Dma1(_) | IoReg::Dma2(_) => {}
                IoReg::Tim(r) => write_tim(t, r, value),
                IoReg::Gpio(r) => write_gpio(g, r, value),
            }
        }
    }
}

impl IoExtHw for IoExtRegs {
    const PINS: Pins = PINS;

    #[inline]
    fn delay_cycles(&mut self, cycles: u32) {
        cortex_m::asm::delay(cycles);
    }

    #[inline]
    fn masked<R>(&mut self, f: impl FnOnce(&mut Self) -> R) -> R {
        cortex_m::interrupt::free(|_| f(self))
    }

    #[inline]
    fn buffers<R>(&mut self, f: impl FnOnce(&mut IoExtBuffers) -> R) -> R {
        f(self.bufs)
    }

    fn address(&self, target: Target) -> u32 {
        // RAM and peripheral addresses fit in 32 bits on the Cortex-M4.
        let gpio = pac::GPIOB::ptr() as usize as u32;
        match target {
            Target::TxBytes => self.bufs.tx.as_ptr() as usize as u32,
            Target::RxBytes => self.bufs.rx.as_ptr() as usize as u32,
            Target::MosiTable => self.bufs.mosi_bsrr.as_ptr() as usize as u32,
            Target::Samples => self.bufs.samples.as_ptr() as usize as u32,
            // Register offsets within a peripheral's block: far from the
            // top of the address space.
            Target::SpiDr => (pac::SPI2::ptr() as usize as u32).wrapping_add(SPI_DR),
            Target::GpioBsrr => gpio.wrapping_add(GPIO_BSRR),
            Target::GpioIdr => gpio.wrapping_add(GPIO_IDR),
        }
    }
}

/// What the I/O extension owns: SPI2, TIM1, DMA1, DMA2 and its lines (as
/// `pins::configure` left them, CS high).
#[derive(Debug)]
pub struct IoExtPeripherals {
    pub spi: IoExtSpi,
    pub tim: IoExtTimer,
    pub dma1: IoExtSpiDma,
    pub dma2: IoExtTimerDma,
    pub lines: IoExtLines,
}

/// Take the extension's peripherals and return the port; nothing is
/// driven until the first transfer. Clocks and resets SPI2 and TIM1,
/// clocks DMA1 and DMA2 (DMA2 is never reset: the chain uses it too).
pub fn ioext_port(
    peripherals: IoExtPeripherals,
    bufs: &'static mut IoExtBuffers,
    rcc: &mut Rcc,
) -> IoExtPort {
    IoExtSpi::enable(rcc);
    IoExtSpi::reset(rcc);
    IoExtTimer::enable(rcc);
    IoExtTimer::reset(rcc);
    IoExtSpiDma::enable(rcc);
    IoExtTimerDma::enable(rcc);
    // The pins' modes and CS are driven through GPIOB from here on.
    let _ = peripherals;
    core_io::IoExtPort::new(IoExtRegs { bufs }, rcc.clocks.sysclk().raw())
}

/// One volatile write of a whole TIM1 register.
///
/// # Safety
///
/// As for [`IoExtRegs::write`]: the value comes from
/// `drivers_core::ioext_spi`, checked against the RM0090 model on the host.
#[inline]
unsafe fn write_tim(t: &pac::tim1::RegisterBlock, r: TimReg, value: u32) {
    // SAFETY: the caller's (above).
    unsafe {
        match r {
            TimReg::Cr1 => {
                t.cr1().write(|w| w.bits(value));
            }
            TimReg::Dier => {
                t.dier().write(|w| w.bits(value));
            }
            TimReg::Sr => {
                t.sr().write(|w| w.bits(value));
            }
            TimReg::Egr => {
                t.egr().write(|w| w.bits(value));
            }
            TimReg::Ccmr1 => {
                t.ccmr1_output().write(|w| w.bits(value));
            }
            TimReg::Ccmr2 => {
                t.ccmr2_output().write(|w| w.bits(value));
            }
            TimReg::Ccer => {
                t.ccer().write(|w| w.bits(value));
            }
            TimReg::Cnt => {
                t.cnt().write(|w| w.bits(value));
            }
            TimReg::Psc => {
                t.psc().write(|w| w.bits(value));
            }
            TimReg::Arr => {
                t.arr().write(|w| w.bits(value));
            }
            TimReg::Rcr => {
                t.rcr().write(|w| w.bits(value));
            }
            TimReg::Ccr1 => {
                t.ccr(0).write(|w| w.bits(value));
            }
            TimReg::Ccr2 => {
                t.ccr(1).write(|w| w.bits(value));
            }
            TimReg::Ccr3 => {
                t.ccr(2).write(|w| w.bits(value));
            }
            TimReg::Bdtr => {
                t.bdtr().write(|w| w.bits(value));
            }
        }
    }
}

/// One volatile write of a whole GPIOB register (only the port's pins'
/// fields change: `drivers_core::ioext_spi`).
///
/// # Safety
///
/// As for [`write_tim`].
#[inline]
unsafe fn write_gpio(g: &pac::gpiob::RegisterBlock, r: GpioReg, value: u32) {
    // SAFETY: the caller's (above).
    unsafe {
        match r {
            GpioReg::Moder => {
                g.moder().write(|w| w.bits(value));
            }
            GpioReg::Pupdr => {
                g.pupdr().write(|w| w.bits(value));
            }
            GpioReg::Afrh => {
                g.afrh().write(|w| w.bits(value));
            }
            GpioReg::Bsrr => {
                g.bsrr().write(|w| w.bits(value));
            }
            // Read-only.
            GpioReg::Idr => {}
        }
    }
}
