//! DMA1/DMA2 register access for the drivers' PAC glue (`chain_spi`,
//! `ioext_spi`): one `match` from `drivers_core::dma::DmaReg` to a
//! controller's registers. Both controllers have the same register block;
//! which streams a driver may name is its own glue's business.

// Whole-register writes through the PAC (see the block below).
#![allow(unsafe_code)]

use drivers_core::dma::DmaReg;
use stm32f4xx_hal::pac;

/// One read of `reg` on `dma`.
#[inline]
pub fn read(dma: &pac::dma2::RegisterBlock, reg: DmaReg) -> u32 {
    let st = |n: u8| dma.st(usize::from(n % 8));
    match reg {
        DmaReg::Lisr => dma.lisr().read().bits(),
        DmaReg::Hisr => dma.hisr().read().bits(),
        // Write-only.
        DmaReg::Lifcr | DmaReg::Hifcr => 0,
        DmaReg::Cr(n) => st(n).cr().read().bits(),
        DmaReg::Ndtr(n) => st(n).ndtr().read().bits(),
        DmaReg::Par(n) => st(n).par().read().bits(),
        DmaReg::M0ar(n) => st(n).m0ar().read().bits(),
        DmaReg::Fcr(n) => st(n).fcr().read().bits(),
    }
}

/// One write of `value` to `reg` on `dma`.
#[inline]
pub fn write(dma: &pac::dma2::RegisterBlock, reg: DmaReg, value: u32) {
    let st = |n: u8| dma.st(usize::from(n % 8));
    // SAFETY: one volatile write of the whole register. The values come
    // from `drivers_core` (`chain_spi`, `ioext_spi`, through
    // `drivers_core::dma`), checked against the RM0090 models on the host:
    // a stream's PAR is its peripheral's data register (SPI1_DR, SPI2_DR,
    // GPIOB_IDR/BSRR) and its M0AR one of the driver's `'static` buffers;
    // the clear registers are write-1-to-clear, each driver writing only
    // its own streams' bits.
    unsafe {
        match reg {
            // Read-only.
            DmaReg::Lisr | DmaReg::Hisr => {}
            DmaReg::Lifcr => {
                dma.lifcr().write(|w| w.bits(value));
            }
            DmaReg::Hifcr => {
                dma.hifcr().write(|w| w.bits(value));
            }
            DmaReg::Cr(n) => {
                st(n).cr().write(|w| w.bits(value));
            }
            DmaReg::Ndtr(n) => {
                st(n).ndtr().write(|w| w.bits(value));
            }
            DmaReg::Par(n) => {
                st(n).par().write(|w| w.bits(value));
            }
            DmaReg::M0ar(n) => {
                st(n).m0ar().write(|w| w.bits(value));
            }
            DmaReg::Fcr(n) => {
                st(n).fcr().write(|w| w.bits(value));
            }
        };
    }
}
