//! The I/O extension model's DMA1 and DMA2: requests, streams, items and their checks (RM0090 §10).

use super::*;

impl IoModel {
    /// X4: SPI2's level requests, scheduled on their streams.
    pub(super) fn spi_requests(&mut self) {
        let rx = self.spi.rxne && self.spi.cr2 & SPI_CR2_RXDMAEN != 0;
        let tx =
            self.spi.tx_buf.is_none() && self.spi.cr2 & SPI_CR2_TXDMAEN != 0 && self.spi_enabled();
        for (active, s) in [(rx, 3usize), (tx, 4)] {
            let st = &mut self.dma[0].streams[s];
            let ready = st.cr & DMA_CR_EN != 0
                && (st.cr & DMA_CR_CHSEL_MASK) >> DMA_CR_CHSEL_SHIFT == 0
                && !st.stalled;
            if active && ready && st.pending.is_none() {
                st.pending = Some(self.now + DMA_LATENCY);
            }
        }
    }

    /// X8, X9: serve every request that is due.
    pub(super) fn dma_service(&mut self) {
        for ctl in 0..2u8 {
            for s in 0..8u8 {
                let due = self.dma[usize::from(ctl)].streams[usize::from(s)]
                    .pending
                    .is_some_and(|t| t <= self.now);
                if due {
                    self.dma[usize::from(ctl)].streams[usize::from(s)].pending = None;
                    self.dma_item(ctl + 1, s);
                }
            }
        }
        self.spi_requests();
    }

    pub(super) fn dma_item(&mut self, ctl: u8, s: u8) {
        let Some(req) = Request::of(ctl, s) else {
            return;
        };
        let c = usize::from(ctl - 1);
        let st = self.dma[c].streams[usize::from(s)];
        if st.cr & DMA_CR_EN == 0 || st.ndtr == 0 {
            return;
        }
        // SPI2's requests are levels: still there?
        let still = match req {
            Request::SpiRx => self.spi.rxne && self.spi.cr2 & SPI_CR2_RXDMAEN != 0,
            Request::SpiTx => self.spi.tx_buf.is_none() && self.spi.cr2 & SPI_CR2_TXDMAEN != 0,
            Request::TimCh2 | Request::TimCh3 => true,
        };
        if !still {
            return;
        }
        let mut moves = true;
        if let Some(f) = st.fail_next {
            self.dma[c].streams[usize::from(s)].fail_next = None;
            self.dma[c].raise(s, f);
            if f.intersects(Flags::TEIF) {
                self.dma[c].streams[usize::from(s)].cr &= !DMA_CR_EN;
            }
            moves = !f.intersects(Flags::TEIF.union(Flags::DMEIF));
        }
        if !moves {
            return;
        }
        let psize = (st.cr & DMA_CR_PSIZE_MASK) >> DMA_CR_PSIZE_SHIFT;
        let bytes = 1u32 << psize;
        let mem = st.m0ar.wrapping_add(st.moved * bytes);
        let ok = if req.p2m() {
            match self.periph_read(ctl, st.par, psize) {
                Some(v) => self.mem_write(mem, psize, v),
                None => false,
            }
        } else {
            match self.mem_read(mem, psize) {
                Some(v) => self.periph_write(ctl, st.par, psize, v),
                None => false,
            }
        };
        if !ok {
            // A bus error: the stream stops (X8).
            self.dma[c].raise(s, Flags::TEIF);
            self.dma[c].streams[usize::from(s)].cr &= !DMA_CR_EN;
            return;
        }
        let st = &mut self.dma[c].streams[usize::from(s)];
        st.moved += 1;
        st.ndtr -= 1;
        let (moved, start, ndtr) = (st.moved, st.start, st.ndtr);
        if moved == start / 2 && start >= 2 {
            self.dma[c].raise(s, Flags::HTIF);
        }
        if ndtr == 0 {
            self.dma[c].streams[usize::from(s)].cr &= !DMA_CR_EN;
            self.dma[c].raise(s, Flags::TCIF);
        }
        self.spi_requests();
        self.update_pins();
    }

    pub(super) fn periph_read(&mut self, ctl: u8, par: u32, psize: u32) -> Option<u32> {
        match par {
            SPI2_DR if psize == 0 => {
                self.spi.rxne = false;
                Some(u32::from(self.spi.rx_buf))
            }
            GPIOB_IDR if ctl == 2 && psize >= 1 => Some(self.idr()),
            _ => {
                self.violate(format!(
                    "X8: DMA{ctl} read of {par:#010x} with PSIZE {psize}: a bus error"
                ));
                None
            }
        }
    }

    pub(super) fn periph_write(&mut self, ctl: u8, par: u32, psize: u32, v: u32) -> bool {
        match par {
            SPI2_DR if psize == 0 => {
                self.dr_write(v as u8);
                true
            }
            GPIOB_BSRR if ctl == 2 && psize == 2 => {
                self.bsrr_write(v);
                true
            }
            _ => {
                self.violate(format!(
                    "X8: DMA{ctl} write of {par:#010x} with PSIZE {psize}: a bus error"
                ));
                false
            }
        }
    }

    pub(super) fn mem_read(&mut self, addr: u32, psize: u32) -> Option<u32> {
        let m = &self.mem;
        let v = match psize {
            0 => addr
                .checked_sub(TX_BYTES)
                .and_then(|o| m.tx.get(o as usize))
                .map(|&b| u32::from(b)),
            2 => addr
                .checked_sub(MOSI_TABLE)
                .filter(|o| o % 4 == 0)
                .and_then(|o| m.mosi_bsrr.get(o as usize / 4))
                .copied(),
            _ => None,
        };
        if v.is_none() {
            self.violate(format!(
                "X8: DMA read of memory {addr:#010x} (size {psize}): not a transmit buffer"
            ));
        }
        v
    }

    pub(super) fn mem_write(&mut self, addr: u32, psize: u32, v: u32) -> bool {
        let slot_ok = match psize {
            0 => addr
                .checked_sub(RX_BYTES)
                .and_then(|o| self.mem.rx.get_mut(o as usize))
                .map(|b| *b = v as u8)
                .is_some(),
            1 => addr
                .checked_sub(SAMPLES)
                .filter(|o| o % 2 == 0)
                .and_then(|o| self.mem.samples.get_mut(o as usize / 2))
                .map(|b| *b = v as u16)
                .is_some(),
            _ => false,
        };
        if !slot_ok {
            self.violate(format!(
                "X8: DMA write of memory {addr:#010x} (size {psize}): not a receive buffer"
            ));
        }
        slot_ok
    }

    /// X6, X7, X8: a write to a stream register.
    pub(super) fn stream_write(&mut self, ctl: u8, reg: DmaReg, value: u32) {
        let (s, c) = match reg {
            DmaReg::Cr(s) | DmaReg::Ndtr(s) | DmaReg::Par(s) | DmaReg::M0ar(s) | DmaReg::Fcr(s) => {
                (s, usize::from(ctl - 1))
            }
            _ => return,
        };
        let Some(req) = Request::of(ctl, s) else {
            self.violate(format!(
                "X7: DMA{ctl} stream {s} is not the I/O extension's"
            ));
            return;
        };
        let st = self.dma[c].streams[usize::from(s)];
        let enabled = st.cr & DMA_CR_EN != 0;
        match reg {
            DmaReg::Cr(_) => {
                if enabled && (value ^ st.cr) & !DMA_CR_EN != 0 {
                    self.violate(format!(
                        "X6: DMA{ctl} stream {s} CR reconfigured while EN = 1"
                    ));
                }
                self.dma[c].streams[usize::from(s)].cr = value;
                if !enabled && value & DMA_CR_EN != 0 {
                    self.enable_checks(ctl, s, req);
                    let st = &mut self.dma[c].streams[usize::from(s)];
                    st.moved = 0;
                    st.start = st.ndtr;
                    st.pending = None;
                    self.spi_requests();
                }
                if enabled && value & DMA_CR_EN == 0 {
                    self.dma[c].streams[usize::from(s)].pending = None;
                }
            }
            _ if enabled => {
                self.violate(format!(
                    "X6: DMA{ctl} {reg:?} written while the stream is enabled"
                ));
            }
            DmaReg::Ndtr(_) => self.dma[c].streams[usize::from(s)].ndtr = value & 0xFFFF,
            DmaReg::Par(_) => self.dma[c].streams[usize::from(s)].par = value,
            DmaReg::M0ar(_) => self.dma[c].streams[usize::from(s)].m0ar = value,
            DmaReg::Fcr(_) => self.dma[c].streams[usize::from(s)].fcr = value,
            _ => {}
        }
    }

    pub(super) fn enable_checks(&mut self, ctl: u8, s: u8, req: Request) {
        let c = usize::from(ctl - 1);
        let st = self.dma[c].streams[usize::from(s)];
        let flags = self.dma[c].flags(s);
        if !flags.is_empty() {
            self.violate(format!(
                "X6: DMA{ctl} stream {s} enabled with its flags still set ({:#04x})",
                flags.bits()
            ));
        }
        if st.ndtr == 0 {
            self.violate(format!("X6: DMA{ctl} stream {s} enabled with NDTR = 0"));
        }
        let chsel = (st.cr & DMA_CR_CHSEL_MASK) >> DMA_CR_CHSEL_SHIFT;
        if chsel != req.channel() {
            self.violate(format!(
                "X7: DMA{ctl} stream {s} on channel {chsel}: {} is channel {}",
                req.name(),
                req.channel()
            ));
        }
        let dir = st.cr & DMA_CR_DIR_MASK;
        let want_dir = if req.p2m() {
            DMA_CR_DIR_P2M
        } else {
            DMA_CR_DIR_M2P
        };
        let psize = (st.cr & DMA_CR_PSIZE_MASK) >> DMA_CR_PSIZE_SHIFT;
        let msize = (st.cr & DMA_CR_MSIZE_MASK) >> DMA_CR_MSIZE_SHIFT;
        let (want_par, sizes): (u32, &[u32]) = match req {
            Request::SpiRx | Request::SpiTx => (SPI2_DR, &[0]),
            Request::TimCh2 => (GPIOB_IDR, &[1, 2]),
            Request::TimCh3 => (GPIOB_BSRR, &[2]),
        };
        if dir != want_dir {
            self.violate(format!(
                "X8: DMA{ctl} stream {s} ({}) in the wrong direction",
                req.name()
            ));
        }
        if st.par != want_par {
            self.violate(format!(
                "X8: DMA{ctl} stream {s} ({}) PAR {:#010x}, not {want_par:#010x}",
                req.name(),
                st.par
            ));
        }
        if !sizes.contains(&psize) {
            self.violate(format!(
                "X8: DMA{ctl} stream {s} ({}) PSIZE {psize}",
                req.name()
            ));
        }
        if st.fcr & DMA_FCR_DMDIS == 0 && msize != psize {
            self.violate(format!(
                "X8: DMA{ctl} stream {s}: direct mode with MSIZE {msize} ≠ PSIZE {psize}"
            ));
        }
        if st.cr & DMA_CR_MINC == 0 || st.cr & (DMA_CR_PINC | DMA_CR_CIRC | DMA_CR_PFCTRL) != 0 {
            self.violate(format!(
                "X8: DMA{ctl} stream {s}: CR {:#010x} is not memory-incremented, one-shot, DMA-flow-controlled",
                st.cr
            ));
        }
        if req == Request::SpiTx && self.spi.cr2 & SPI_CR2_TXDMAEN != 0 {
            self.violate("X4: SPI2_TX stream enabled after TXDMAEN");
            if self.spi.tx_buf.is_none() {
                // The request was already active: FEIF, as in direct mode.
                self.dma[c].raise(s, Flags::FEIF);
            }
        }
    }

    pub(super) fn dma_read(&mut self, ctl: u8, reg: DmaReg) -> u32 {
        let c = usize::from(ctl - 1);
        let d = &self.dma[c];
        let st = |s: u8| &d.streams[usize::from(s % 8)];
        match reg {
            DmaReg::Lisr => d.isr[0],
            DmaReg::Hisr => d.isr[1],
            DmaReg::Lifcr | DmaReg::Hifcr => 0,
            DmaReg::Cr(s) => st(s).cr,
            DmaReg::Ndtr(s) => st(s).ndtr,
            DmaReg::Par(s) => st(s).par,
            DmaReg::M0ar(s) => st(s).m0ar,
            DmaReg::Fcr(s) => st(s).fcr,
        }
    }

    pub(super) fn dma_write(&mut self, ctl: u8, reg: DmaReg, value: u32) {
        let c = usize::from(ctl - 1);
        match reg {
            DmaReg::Lisr | DmaReg::Hisr => self.violate(format!("DMA{ctl} {reg:?} is read-only")),
            DmaReg::Lifcr | DmaReg::Hifcr => {
                let hi = usize::from(reg == DmaReg::Hifcr);
                let own: u32 = (0..4u8)
                    .filter(|&k| Request::of(ctl, k + 4 * hi as u8).is_some())
                    .map(|k| Flags::ALL.at(k))
                    .sum();
                if value & !own != 0 {
                    self.violate(format!(
                        "X7: DMA{ctl} {reg:?} {value:#010x} clears another stream's flags"
                    ));
                }
                self.dma[c].isr[hi] &= !value;
            }
            _ => self.stream_write(ctl, reg, value),
        }
    }
}
