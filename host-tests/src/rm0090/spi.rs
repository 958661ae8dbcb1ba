//! The part of RM0090 §28's SPI that both SPI models share (the chain's
//! SPI1 in [`super::chain_spi`], the I/O extension's SPI2 in
//! [`super::ioext`]): the control registers, the status flags, the data
//! buffers and the two-step OVR clear (a DR read, then an SR read). What a
//! frame does on the wire, and which misuse each model reports, stays in
//! the model.

use drivers_core::spi::bits::*;
use drivers_core::spi::SpiReg;

/// One SPI's registers and flags.
#[derive(Clone, Copy, Debug, Default)]
pub struct SpiPort {
    pub cr1: u32,
    pub cr2: u32,
    /// A received byte waits in DR.
    pub rxne: bool,
    pub ovr: bool,
    pub modf: bool,
    /// DR read since the last SR read (first half of the OVR clear).
    pub dr_read: bool,
    /// The byte written to DR, not yet on the wire (TXE = 0).
    pub tx_buf: Option<u8>,
    /// The last byte received.
    pub rx_buf: u8,
}

impl SpiPort {
    /// SR as read; `busy` is BSY (the model's frame in progress). Reading
    /// SR after DR completes the OVR clear.
    pub fn read_sr(&mut self, busy: bool) -> u32 {
        let v = (u32::from(self.rxne) * SPI_SR_RXNE)
            | (u32::from(self.tx_buf.is_none()) * SPI_SR_TXE)
            | (u32::from(self.modf) * SPI_SR_MODF)
            | (u32::from(self.ovr) * SPI_SR_OVR)
            | (u32::from(busy) * SPI_SR_BSY);
        if self.dr_read {
            self.ovr = false;
            self.dr_read = false;
        }
        v
    }

    /// A register read; `busy` is BSY (the model's frame in progress).
    pub fn read(&mut self, reg: SpiReg, busy: bool) -> u32 {
        match reg {
            SpiReg::Cr1 => self.cr1,
            SpiReg::Cr2 => self.cr2,
            SpiReg::Sr => self.read_sr(busy),
            SpiReg::Dr => self.read_dr(),
        }
    }

    /// DR as read: the last byte received; clears RXNE.
    pub fn read_dr(&mut self) -> u32 {
        self.rxne = false;
        self.dr_read = true;
        u32::from(self.rx_buf)
    }
}
