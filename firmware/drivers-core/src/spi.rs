//! SPI1/SPI2 as both SPI drivers use them (RM0090 §28): the registers, their
//! bits, and the two status sequences both need.
//!
//! The chain driver (`chain_spi`, SPI1) and the I/O extension's
//! (`ioext_spi`, SPI2) name the registers through their own register enum;
//! the functions here take the enum's constructor (`ChainReg::Spi`,
//! `IoReg::Spi`).

use crate::Regs;

/// One SPI's registers (RM0090 §28.5.1–§28.5.4; 16 bits wide).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SpiReg {
    Cr1,
    Cr2,
    Sr,
    Dr,
}

/// SPI_CR1, SPI_CR2 and SPI_SR bits (RM0090 §28.5.1–§28.5.3).
pub mod bits {
    pub const SPI_CR1_CPHA: u32 = 1 << 0;
    pub const SPI_CR1_CPOL: u32 = 1 << 1;
    pub const SPI_CR1_MSTR: u32 = 1 << 2;
    pub const SPI_CR1_BR_SHIFT: u32 = 3;
    pub const SPI_CR1_BR_MASK: u32 = 0b111 << SPI_CR1_BR_SHIFT;
    pub const SPI_CR1_SPE: u32 = 1 << 6;
    pub const SPI_CR1_LSBFIRST: u32 = 1 << 7;
    pub const SPI_CR1_SSI: u32 = 1 << 8;
    pub const SPI_CR1_SSM: u32 = 1 << 9;
    pub const SPI_CR1_RXONLY: u32 = 1 << 10;
    pub const SPI_CR1_DFF: u32 = 1 << 11;
    pub const SPI_CR1_BIDIMODE: u32 = 1 << 15;
    pub const SPI_CR2_RXDMAEN: u32 = 1 << 0;
    pub const SPI_CR2_TXDMAEN: u32 = 1 << 1;
    pub const SPI_SR_RXNE: u32 = 1 << 0;
    pub const SPI_SR_TXE: u32 = 1 << 1;
    pub const SPI_SR_MODF: u32 = 1 << 5;
    pub const SPI_SR_OVR: u32 = 1 << 6;
    pub const SPI_SR_BSY: u32 = 1 << 7;
}

use bits::*;

/// CR1 of an 8-bit, MSB-first master with software NSS held high, in
/// `cpol`/`cpha` at CR1.BR = `br`, not yet enabled (SPE = 0).
pub const fn master_cr1(br: u32, cpol: bool, cpha: bool) -> u32 {
    (if cpha { SPI_CR1_CPHA } else { 0 })
        | (if cpol { SPI_CR1_CPOL } else { 0 })
        | SPI_CR1_MSTR
        | ((br << SPI_CR1_BR_SHIFT) & SPI_CR1_BR_MASK)
        | SPI_CR1_SSM
        | SPI_CR1_SSI
}

/// Read DR, then SR: drops a stale byte and clears an overrun (RM0090
/// §28.4.8: OVR is cleared by a DR read followed by an SR read).
#[inline]
pub fn drain<R: Copy>(hw: &mut impl Regs<R>, spi: impl Fn(SpiReg) -> R + Copy) {
    let _ = hw.read(spi(SpiReg::Dr));
    let _ = hw.read(spi(SpiReg::Sr));
}

/// Wait (at most `polls` reads) until BSY is clear; false if it stays set.
#[inline]
pub fn wait_idle<R: Copy>(
    hw: &mut impl Regs<R>,
    spi: impl Fn(SpiReg) -> R + Copy,
    polls: u32,
) -> bool {
    (0..polls).any(|_| hw.read(spi(SpiReg::Sr)) & SPI_SR_BSY == 0)
}
