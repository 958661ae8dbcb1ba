//! The I/O extension model's SPI2: the register file, frames and the shift of each bit (RM0090 §28).

use super::*;

impl IoModel {
    pub(super) fn tick_access(&mut self) {
        let t = self.now + ACCESS;
        self.advance_to(t);
    }

    // ------------------------------------------------------------- SPI2 --

    pub(super) fn spi_enabled(&self) -> bool {
        self.spi.cr1 & SPI_CR1_SPE != 0
    }

    pub(super) fn cpol(&self) -> bool {
        self.spi.cr1 & SPI_CR1_CPOL != 0
    }

    pub(super) fn spi_cr1_write(&mut self, value: u32) {
        let value = value & 0xFFFF;
        let config = !SPI_CR1_SPE & 0xFFFF;
        if self.spi_enabled() && (value ^ self.spi.cr1) & config != 0 {
            self.violate(format!(
                "X2: SPI2 CR1 {:#06x} -> {value:#06x} while SPE = 1",
                self.spi.cr1
            ));
        }
        if self.spi_enabled() && value & SPI_CR1_SPE == 0 && self.busy() {
            self.violate("X5: SPE cleared while SPI2 is busy: a frame cut");
            self.frame = None;
            self.spi.tx_buf = None;
        }
        self.spi.cr1 = value;
        if !self.spi_enabled() {
            self.frame = None;
        } else if self.frame.is_none() {
            self.spi_sck = self.cpol();
            if self.spi.tx_buf.is_some() {
                self.start_frame();
            }
        }
    }

    pub(super) fn busy(&self) -> bool {
        self.frame.is_some() || self.spi.tx_buf.is_some()
    }

    pub(super) fn dr_write(&mut self, byte: u8) {
        if !self.spi_enabled() {
            self.violate("X1: SPI2 DR written with SPE = 0");
            return;
        }
        if self.spi.tx_buf.is_some() {
            self.violate("X3: SPI2 DR written while TXE = 0: a byte lost");
        }
        self.spi.tx_buf = Some(byte);
        if self.frame.is_none() {
            self.start_frame();
        }
    }

    /// X1, X3: DR's byte goes on the wire.
    pub(super) fn start_frame(&mut self) {
        let Some(out) = self.spi.tx_buf.take() else {
            return;
        };
        let cr1 = self.spi.cr1;
        if cr1 & SPI_CR1_MSTR == 0 || cr1 & (SPI_CR1_SSM | SPI_CR1_SSI) != SPI_CR1_SSM | SPI_CR1_SSI
        {
            self.spi.modf = true;
            self.violate(format!(
                "X1: SPI2 frame with CR1 = {cr1:#06x}: not a master with NSS held high"
            ));
        }
        if cr1 & (SPI_CR1_DFF | SPI_CR1_LSBFIRST | SPI_CR1_BIDIMODE | SPI_CR1_RXONLY) != 0 {
            self.violate(format!(
                "X1: SPI2 frame with CR1 = {cr1:#06x}: not 8-bit, MSB first, full duplex"
            ));
        }
        let br = (cr1 & SPI_CR1_BR_MASK) >> SPI_CR1_BR_SHIFT;
        let half = (2u64 << br) * SPI_TICK / 2;
        let cpha = cr1 & SPI_CR1_CPHA != 0;
        let cpol = self.cpol();
        self.frame = Some(Frame {
            out,
            got: 0,
            step: 0,
            next: self.now + half,
            half,
        });
        self.engine_started();
        self.spi_mosi = out & 0x80 != 0;
        if cpha {
            // The first leading edge comes with the load.
            self.spi_sck = !cpol;
        }
        self.update_pins();
        self.spi_requests();
    }

    /// X3: the next half period of the frame ends.
    pub(super) fn spi_step(&mut self) {
        let Some(mut f) = self.frame else {
            return;
        };
        f.step += 1;
        let cpha = self.spi.cr1 & SPI_CR1_CPHA != 0;
        let cpol = self.cpol();
        let k = f.step;
        if k == 16 {
            // The frame is over.
            if !cpha {
                self.spi_sck = cpol;
            }
            self.frame = None;
            if self.spi.rxne {
                self.spi.ovr = true;
            } else {
                self.spi.rx_buf = f.got;
                self.spi.rxne = true;
            }
            self.update_pins();
            if self.spi.tx_buf.is_some() {
                self.start_frame();
            }
            self.spi_requests();
            return;
        }
        let bit = usize::from(k / 2);
        // Odd steps end the first half of a bit: CPHA 0 leading (sample),
        // CPHA 1 trailing (sample); even steps start the next bit.
        if k % 2 == 1 {
            f.got = (f.got << 1) | u8::from(self.chips_miso());
            self.spi_sck = if cpha { cpol } else { !cpol };
        } else {
            self.spi_sck = if cpha { !cpol } else { cpol };
            self.spi_mosi = f.out & (0x80 >> bit) != 0;
        }
        f.next += f.half;
        self.frame = Some(f);
        self.update_pins();
    }

    /// An engine starts: noted in the open CS window.
    pub(super) fn engine_started(&mut self) {
        let now = self.now;
        if let Some(w) = self.windows.last_mut().filter(|w| w.rose.is_none()) {
            w.engine_start.get_or_insert(now);
        }
    }

    pub(super) fn chips_miso(&self) -> bool {
        self.chips.miso()
    }
}
