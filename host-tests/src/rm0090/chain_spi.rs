//! RM0090 §28, §10 and §20: SPI1 as the chain's master, DMA2 streams 0
//! (SPI1_RX) and 3 (SPI1_TX), TIM7 and the CS line, as
//! `drivers_core::chain_spi` sees them, with the simulated powerSTEP01
//! chain (`stepbridge_sim::SimChain`) behind MOSI/MISO. Time runs in
//! picoseconds; register accesses take [`ACCESS_PS`] each.
//!
//! # Rules (RM0090 rev 19 section numbers)
//!
//! | # | rule | section |
//! |---|---|---|
//! | S1 | A byte shifts only with SPE = 1, MSTR = 1 and SSM = SSI = 1 (software NSS held high, else MODF); the chain needs mode 3 (CPOL = CPHA = 1), MSB first (LSBFIRST = 0), 8-bit frames (DFF = 0) | §28.3.3 "Configuring the SPI in master mode", §28.5.1; powerSTEP01 datasheet |
//! | S2 | SCK = f_PCLK2 / 2^(BR+1), at most 5 MHz for the powerSTEP01 | §28.5.1 (BR); powerSTEP01 datasheet |
//! | S3 | A DR write moves to the shift register when it is empty (TXE sets again); a DR write while TXE = 0 overwrites the waiting byte | §28.3.5, §28.5.3 (TXE) |
//! | S4 | After each byte RXNE sets with the received byte; a byte completed while RXNE = 1 is lost and sets OVR, which a read of DR followed by a read of SR clears | §28.3.5, §28.4.8 "Overrun error" |
//! | S5 | BSY stays set until the last bit has left the shift register; TXE only says DR is empty. CS may rise only once BSY is clear | §28.3.8 "Disabling the SPI", §28.5.3 (BSY) |
//! | S6 | With TXDMAEN a TXE raises a DMA request, with RXDMAEN an RXNE does | §28.3.9 "SPI communication using DMA" |
//! | S7 | A stream's PAR, M0AR, NDTR, FCR and configuration bits may be written only while EN = 0; its flags from the previous transfer must be cleared (LIFCR, write 1) before EN is set | §10.3.17 "Stream configuration procedure", §10.5.5 |
//! | S8 | SPI1_RX is DMA2 stream 0 or 2 channel 3, SPI1_TX stream 3 or 5 channel 3; PAR = SPI1_DR; RX peripheral-to-memory, TX memory-to-peripheral | §10.3.3, Table 43 |
//! | S9 | NDTR counts the items down; at 0 TCIF sets and EN clears; TCIE/TEIE/DMEIE/FEIE gate the stream's interrupt | §10.3.6, §10.3.11, §10.5.1 |
//! | S10 | TIM7 counts at f_TIM / (PSC + 1) from CNT; the overflow after ARR sets UIF (not the UG event with URS = 1); one-pulse mode clears CEN there; UIF is rc_w0; UIE gates the interrupt | §20.3, §20.4.1–§20.4.8 |
//! | S11 | powerSTEP01: CS high at least t_disCS = 800 ns between windows, CS low at least t_setCS = 350 ns before the first SCK edge, no SCK edge while CS is high | powerSTEP01 datasheet (not RM0090) |
//!
//! # Modelling choices (UNCONFIRMED)
//!
//! * DMA requests are served at once (no bus latency); a stream disabled
//!   by the CPU stops at once (the chip finishes its current beat).
//! * The transmit stream's FIFO-error flag at enable (direct mode) is not
//!   modelled; the driver ignores it anyway.
//! * MISO: byte k of a window is what the simulated chain would return for
//!   the bytes clocked so far (a copy of the chain as CS fell is clocked
//!   again); when CS rises the real chain takes the whole window, and the
//!   model checks it returns exactly what MISO carried.
//! * An interrupt line is level-sensitive here: NVIC pending bits are not
//!   modelled ([`ChainHandle::unpend_interrupts`] only counts).
//!
//! [`SharedChain`] shares the one driver the way the firmware's
//! critical-section cell does: the bridge's chain bus is a handle that asks
//! it for each blocking window, the tests (the control tick and the
//! interrupts) reach the same driver.

use std::cell::RefCell;
use std::rc::Rc;

use bridge_logic::powerstep::chain::{ChainBus, Frames, MAX_DEVICES, MAX_WINDOWS};
use drivers_core::chain_spi::bits::*;
use drivers_core::chain_spi::{
    ChainBuffers, ChainHw, ChainMemory, ChainReg, ChainSpi, ChainSpiError, CS_DESELECT_NS,
    CS_SETUP_NS, DMEIF0, FEIF0, HTIF0, RX_STREAM, SPI1_CHANNEL, STREAM_FLAGS, TCIF0, TCIF3, TEIF0,
    TX_STREAM,
};
use drivers_core::dma::DmaReg;
use drivers_core::spi::SpiReg;

use super::spi::SpiPort;
use stepbridge_sim::SimChain;

/// APB2 (SPI1) and TIM7's clock on the board, and the CPU clock.
pub const PCLK2_HZ: u64 = 84_000_000;
pub const TIMCLK_HZ: u64 = 84_000_000;
pub const SYSCLK_HZ: u64 = 168_000_000;
/// One register access (two APB2 cycles, rounded).
pub const ACCESS_PS: u64 = 24_000;
/// The powerSTEP01's SCK limit.
pub const SCK_LIMIT_HZ: u64 = 5_000_000;
/// Bus addresses the model gives the rows and SPI1_DR.
pub const TX_ROWS: u32 = 0x2000_0000;
pub const RX_ROWS: u32 = 0x2000_1000;
pub const SPI1_DR: u32 = 0x4001_300C;

/// One DMA stream's registers.
#[derive(Clone, Copy, Debug, Default)]
struct Stream {
    cr: u32,
    ndtr: u32,
    par: u32,
    m0ar: u32,
    fcr: u32,
    /// Items moved since EN.
    moved: u32,
}

/// A window as the chain saw it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Window {
    pub tx: Vec<u8>,
    pub rx: Vec<u8>,
    /// CS high before it (ns; None for the first).
    pub gap_ns: Option<u64>,
    /// CS low to the first SCK edge (ns).
    pub setup_ns: u64,
}

/// SPI1, DMA2 streams 0/3, TIM7, CS and the chain (see the module docs).
pub struct ChainModel {
    now: u64,
    spi: SpiPort,
    /// The byte on the wire: what MISO brings, when it ends (ps).
    shift: Option<(u8, u64)>,
    streams: [Stream; 2],
    lisr: u32,
    tim_cr1: u32,
    tim_dier: u32,
    tim_sr: u32,
    tim_cnt: u32,
    tim_psc: u32,
    tim_psc_live: u32,
    tim_arr: u32,
    /// When TIM7 overflows (ps), while it counts.
    tim_overflow: Option<u64>,
    cs_high: bool,
    cs_changed: u64,
    last_rise: Option<u64>,
    /// The chain as CS fell, and the window so far.
    snapshot: Option<SimChain>,
    window_tx: Vec<u8>,
    window_rx: Vec<u8>,
    window_gap: Option<u64>,
    window_setup: u64,
    pub chain: SimChain,
    pub mem: ChainBuffers,
    pub windows: Vec<Window>,
    pub unpends: u32,
    /// Error flags to raise on the named stream's next transfer.
    fail_stream: Option<(u8, u32)>,
    /// SPI1 stops shifting (a dead clock): for timeout tests.
    pub frozen: bool,
    violations: Vec<String>,
}

impl std::fmt::Debug for ChainModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ChainModel")
            .field("now_ns", &(self.now / 1000))
            .field("spi_cr1", &format_args!("{:#06x}", self.spi.cr1))
            .field("spi_cr2", &format_args!("{:#06x}", self.spi.cr2))
            .field("lisr", &format_args!("{:#010x}", self.lisr))
            .field("cs_high", &self.cs_high)
            .field("violations", &self.violations)
            .finish()
    }
}

fn idx(stream: u8) -> Option<usize> {
    match stream {
        RX_STREAM => Some(0),
        TX_STREAM => Some(1),
        _ => None,
    }
}

impl ChainModel {
    /// Reset state, CS high, `chain` behind the bus.
    pub fn new(chain: SimChain) -> ChainModel {
        ChainModel {
            now: 0,
            spi: SpiPort::default(),
            shift: None,
            streams: [Stream {
                fcr: DMA_FCR_RESET,
                ..Stream::default()
            }; 2],
            lisr: 0,
            tim_cr1: 0,
            tim_dier: 0,
            tim_sr: 0,
            tim_cnt: 0,
            tim_psc: 0,
            tim_psc_live: 0,
            tim_arr: 0xFFFF,
            tim_overflow: None,
            cs_high: true,
            cs_changed: 0,
            last_rise: None,
            snapshot: None,
            window_tx: Vec::new(),
            window_rx: Vec::new(),
            window_gap: None,
            window_setup: 0,
            chain,
            mem: ChainBuffers::new(),
            windows: Vec::new(),
            unpends: 0,
            fail_stream: None,
            frozen: false,
            violations: Vec::new(),
        }
    }

    pub fn now_ns(&self) -> u64 {
        self.now / 1000
    }

    pub fn violations(&self) -> &[String] {
        &self.violations
    }

    pub fn spi_cr1(&self) -> u32 {
        self.spi.cr1
    }

    pub fn spi_cr2(&self) -> u32 {
        self.spi.cr2
    }

    pub fn lisr(&self) -> u32 {
        self.lisr
    }

    pub fn stream_cr(&self, stream: u8) -> u32 {
        idx(stream).map_or(0, |i| self.streams[i].cr)
    }

    pub fn stream_par(&self, stream: u8) -> u32 {
        idx(stream).map_or(0, |i| self.streams[i].par)
    }

    pub fn cs_high(&self) -> bool {
        self.cs_high
    }

    pub fn ovr(&self) -> bool {
        self.spi.ovr
    }

    /// Raise `flags` (LISR bits) on `stream`'s next item and stop it.
    pub fn fail_stream_next(&mut self, stream: u8, flags: u32) {
        self.fail_stream = Some((stream, flags));
    }

    /// SCK in Hz as configured.
    pub fn sck_hz(&self) -> u64 {
        PCLK2_HZ >> (((self.spi.cr1 & SPI_CR1_BR_MASK) >> SPI_CR1_BR_SHIFT) + 1)
    }

    fn byte_ps(&self) -> u64 {
        8 * 1_000_000_000_000 / self.sck_hz().max(1)
    }

    fn violate(&mut self, what: impl Into<String>) {
        let what = what.into();
        self.violations
            .push(format!("{} (at {} ns)", what, self.now / 1000));
    }

    /// TIM7's interrupt line (S10).
    pub fn tim_irq(&self) -> bool {
        self.tim_dier & TIM_DIER_UIE != 0 && self.tim_sr & TIM_SR_UIF != 0
    }

    /// DMA2_STREAM0's interrupt line (S9).
    pub fn dma_irq(&self) -> bool {
        let cr = self.streams[0].cr;
        let fcr = self.streams[0].fcr;
        (cr & DMA_CR_TCIE != 0 && self.lisr & TCIF0 != 0)
            || (cr & DMA_CR_TEIE != 0 && self.lisr & TEIF0 != 0)
            || (cr & DMA_CR_DMEIE != 0 && self.lisr & DMEIF0 != 0)
            || (cr & DMA_CR_HTIE != 0 && self.lisr & HTIF0 != 0)
            || (fcr & DMA_FCR_FEIE != 0 && self.lisr & FEIF0 != 0)
    }

    /// When the next event is due (ps).
    pub fn next_event(&self) -> Option<u64> {
        let shift = self.shift.map(|(_, end)| end).filter(|_| !self.frozen);
        match (shift, self.tim_overflow) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Let time run to `t` (ps), with every event on the way.
    pub fn advance_to(&mut self, t: u64) {
        while let Some(next) = self.next_event().filter(|&n| n <= t) {
            self.now = self.now.max(next);
            if self.tim_overflow == Some(next) {
                self.tim_overflow = None;
                self.tim_sr |= TIM_SR_UIF;
                self.tim_cnt = 0;
                if self.tim_cr1 & TIM_CR1_OPM != 0 {
                    self.tim_cr1 &= !TIM_CR1_CEN;
                }
            }
            if self.shift.map(|(_, end)| end) == Some(next) && !self.frozen {
                self.shift_done();
            }
            self.dma_service();
        }
        self.now = self.now.max(t);
    }

    fn tick_access(&mut self) {
        let t = self.now + ACCESS_PS;
        self.advance_to(t);
    }

    // --------------------------------------------------------- SPI --

    fn dr_write(&mut self, byte: u8) {
        if self.spi.cr1 & SPI_CR1_SPE == 0 {
            self.violate("S1: DR written with SPE = 0");
            return;
        }
        if self.spi.tx_buf.is_some() {
            self.violate("S3: DR written while TXE = 0: a byte lost");
        }
        self.spi.tx_buf = Some(byte);
        if self.shift.is_none() {
            self.start_shift();
        }
    }

    /// S1, S2, S11: the next byte goes on the wire.
    fn start_shift(&mut self) {
        let Some(byte) = self.spi.tx_buf.take() else {
            return;
        };
        let cr1 = self.spi.cr1;
        if cr1 & (SPI_CR1_SSM | SPI_CR1_SSI) != (SPI_CR1_SSM | SPI_CR1_SSI)
            && cr1 & SPI_CR1_MSTR != 0
        {
            self.spi.modf = true;
        }
        let mode = SPI_CR1_CPOL | SPI_CR1_CPHA | SPI_CR1_MSTR;
        if cr1 & mode != mode || cr1 & (SPI_CR1_LSBFIRST | SPI_CR1_DFF) != 0 {
            self.violate(format!(
                "S1: byte clocked with CR1 = {cr1:#06x}: not master mode 3, MSB first, 8 bit"
            ));
        }
        if self.sck_hz() > SCK_LIMIT_HZ {
            self.violate(format!(
                "S2: SCK {} Hz above the powerSTEP01's 5 MHz",
                self.sck_hz()
            ));
        }
        if self.cs_high {
            self.violate(format!("S11: SCK while CS is high ({byte:#04x} to nobody)"));
        }
        if self.window_tx.is_empty() && !self.cs_high {
            let setup = (self.now - self.cs_changed) / 1000;
            self.window_setup = setup;
            if setup < u64::from(CS_SETUP_NS) {
                self.violate(format!(
                    "S11: first SCK edge {setup} ns after CS fell (t_setCS 350 ns)"
                ));
            }
        }
        // MISO: what the chain returns for the bytes clocked so far.
        self.window_tx.push(byte);
        let miso = match self.snapshot.as_ref() {
            Some(s) => {
                let mut c = s.clone();
                let mut rx = vec![0u8; self.window_tx.len()];
                c.transfer(&self.window_tx, &mut rx);
                rx.last().copied().unwrap_or(0xFF)
            }
            None => 0xFF,
        };
        self.window_rx.push(miso);
        self.shift = Some((miso, self.now + self.byte_ps()));
    }

    /// S4: a byte is in.
    fn shift_done(&mut self) {
        let Some((miso, _)) = self.shift.take() else {
            return;
        };
        if self.spi.rxne {
            self.spi.ovr = true;
        } else {
            self.spi.rx_buf = miso;
            self.spi.rxne = true;
        }
        if self.spi.tx_buf.is_some() {
            self.start_shift();
        }
    }

    // --------------------------------------------------------- DMA --

    /// S6, S9: serve the streams' requests.
    fn dma_service(&mut self) {
        for _ in 0..4 * MAX_DEVICES {
            let mut moved = false;
            // Receive: RXNE with RXDMAEN.
            let rx = self.streams[0];
            if rx.cr & DMA_CR_EN != 0
                && self.spi.cr2 & SPI_CR2_RXDMAEN != 0
                && self.spi.rxne
                && rx.ndtr > 0
            {
                if self.dma_fails(RX_STREAM) {
                    continue;
                }
                let byte = self.spi.rx_buf;
                self.spi.rxne = false;
                let addr = rx.m0ar.wrapping_add(rx.moved);
                self.mem_write(addr, byte);
                self.item_done(0, TCIF0);
                moved = true;
            }
            // Transmit: TXE with TXDMAEN.
            let tx = self.streams[1];
            if tx.cr & DMA_CR_EN != 0
                && self.spi.cr2 & SPI_CR2_TXDMAEN != 0
                && self.spi.tx_buf.is_none()
                && tx.ndtr > 0
            {
                if self.dma_fails(TX_STREAM) {
                    continue;
                }
                let addr = tx.m0ar.wrapping_add(tx.moved);
                let byte = self.mem_read(addr);
                self.item_done(1, TCIF3);
                self.dr_write(byte);
                moved = true;
            }
            if !moved {
                return;
            }
        }
    }

    fn dma_fails(&mut self, stream: u8) -> bool {
        match self.fail_stream {
            Some((s, flags)) if s == stream => {
                self.fail_stream = None;
                self.lisr |= flags;
                if let Some(i) = idx(stream) {
                    self.streams[i].cr &= !DMA_CR_EN;
                }
                true
            }
            _ => false,
        }
    }

    fn item_done(&mut self, i: usize, tcif: u32) {
        let s = &mut self.streams[i];
        s.moved += 1;
        s.ndtr -= 1;
        if s.ndtr == 0 {
            s.cr &= !DMA_CR_EN;
            self.lisr |= tcif;
        }
    }

    fn row(addr: u32, base: u32) -> Option<(usize, usize)> {
        let off = addr.checked_sub(base)? as usize;
        let (w, k) = (off / MAX_DEVICES, off % MAX_DEVICES);
        (w < MAX_WINDOWS).then_some((w, k))
    }

    fn mem_write(&mut self, addr: u32, byte: u8) {
        match Self::row(addr, RX_ROWS) {
            Some((w, k)) => self.mem.rx[w][k] = byte,
            None => self.violate(format!("DMA write to {addr:#010x}, not a receive row")),
        }
    }

    fn mem_read(&mut self, addr: u32) -> u8 {
        match Self::row(addr, TX_ROWS) {
            Some((w, k)) => self.mem.tx[w][k],
            None => {
                self.violate(format!("DMA read of {addr:#010x}, not a transmit row"));
                0
            }
        }
    }

    /// S7, S8: a write to a stream register.
    fn stream_write(&mut self, reg: DmaReg, stream: u8, value: u32) {
        let Some(i) = idx(stream) else {
            self.violate(format!("{reg:?}: stream {stream} is not the chain's"));
            return;
        };
        let s = self.streams[i];
        let enabled = s.cr & DMA_CR_EN != 0;
        match reg {
            DmaReg::Cr(_) => {
                if enabled && (value ^ s.cr) & !DMA_CR_EN != 0 {
                    self.violate(format!("S7: stream {stream} CR reconfigured while EN = 1"));
                }
                if !enabled && value & DMA_CR_EN != 0 {
                    self.enable_checks(stream, i, value);
                    self.streams[i].moved = 0;
                }
                self.streams[i].cr = value;
            }
            _ if enabled => {
                self.violate(format!(
                    "S7: {reg:?} written while stream {stream} is enabled"
                ));
            }
            DmaReg::Ndtr(_) => self.streams[i].ndtr = value & 0xFFFF,
            DmaReg::Par(_) => self.streams[i].par = value,
            DmaReg::M0ar(_) => self.streams[i].m0ar = value,
            DmaReg::Fcr(_) => self.streams[i].fcr = value,
            _ => {}
        }
    }

    fn enable_checks(&mut self, stream: u8, i: usize, cr: u32) {
        let own = if stream == RX_STREAM {
            STREAM_FLAGS & 0x3F
        } else {
            STREAM_FLAGS & (0x3F << 22)
        };
        if self.lisr & own != 0 {
            self.violate(format!(
                "S7: stream {stream} enabled with its flags still set ({:#010x})",
                self.lisr & own
            ));
        }
        let s = self.streams[i];
        if (cr & DMA_CR_CHSEL_MASK) >> DMA_CR_CHSEL_SHIFT != SPI1_CHANNEL {
            self.violate(format!(
                "S8: stream {stream} on channel {}",
                (cr & DMA_CR_CHSEL_MASK) >> DMA_CR_CHSEL_SHIFT
            ));
        }
        if s.par != SPI1_DR {
            self.violate(format!(
                "S8: stream {stream} PAR {:#010x}, not SPI1_DR",
                s.par
            ));
        }
        let dir = cr & DMA_CR_DIR_MASK;
        let want = if stream == RX_STREAM {
            0
        } else {
            DMA_CR_DIR_M2P
        };
        if dir != want {
            self.violate(format!("S8: stream {stream} in the wrong direction"));
        }
        if s.ndtr == 0 {
            self.violate(format!("S9: stream {stream} enabled with NDTR = 0"));
        }
    }

    // --------------------------------------------------------- TIM7 --

    fn tim_schedule(&mut self) {
        if self.tim_cr1 & TIM_CR1_CEN == 0 {
            self.tim_overflow = None;
            return;
        }
        let ticks = u64::from(self.tim_arr.saturating_sub(self.tim_cnt)) + 1;
        let period = (u64::from(self.tim_psc_live) + 1) * 1_000_000_000_000 / TIMCLK_HZ;
        self.tim_overflow = Some(self.now + ticks * period);
    }

    // ----------------------------------------------------------- CS --

    fn set_cs(&mut self, high: bool) {
        if high == self.cs_high {
            return;
        }
        if high {
            // S5: the last byte must be off the wire.
            if self.shift.is_some() || self.spi.tx_buf.is_some() {
                self.violate("S5: CS raised while SPI1 is busy: the window's last byte is cut");
            }
            if self.snapshot.take().is_some() && !self.window_tx.is_empty() {
                let mut rx = vec![0u8; self.window_tx.len()];
                self.chain.transfer(&self.window_tx, &mut rx);
                if rx != self.window_rx {
                    self.violate("model: MISO during the window differs from the chain's window");
                }
                self.windows.push(Window {
                    tx: std::mem::take(&mut self.window_tx),
                    rx: std::mem::take(&mut self.window_rx),
                    gap_ns: self.window_gap,
                    setup_ns: self.window_setup,
                });
            }
            self.last_rise = Some(self.now);
        } else {
            self.window_gap = self.last_rise.map(|r| (self.now - r) / 1000);
            if let Some(gap) = self.window_gap {
                if gap < u64::from(CS_DESELECT_NS) {
                    self.violate(format!(
                        "S11: CS high only {gap} ns between windows (t_disCS 800 ns)"
                    ));
                }
            }
            self.snapshot = Some(self.chain.clone());
            self.window_tx.clear();
            self.window_rx.clear();
        }
        self.cs_high = high;
        self.cs_changed = self.now;
    }
}

/// A shared handle on the model: the driver holds one, the tests another.
pub type ChainHandle = super::Handle<ChainModel>;

impl ChainHandle {
    pub fn new(chain: SimChain) -> ChainHandle {
        super::Handle::of(ChainModel::new(chain))
    }
}

impl super::RegisterFile<ChainReg> for ChainModel {
    fn tick_access(&mut self) {
        ChainModel::tick_access(self);
    }

    fn read_reg(&mut self, reg: ChainReg) -> u32 {
        match reg {
            ChainReg::Spi(r) => {
                let busy = self.shift.is_some() || self.spi.tx_buf.is_some();
                self.spi.read(r, busy)
            }
            ChainReg::Dma(DmaReg::Lisr) => self.lisr,
            // Streams 4–7 are not the chain's: their HISR reads 0 here.
            ChainReg::Dma(DmaReg::Hisr | DmaReg::Lifcr | DmaReg::Hifcr) => 0,
            ChainReg::Dma(DmaReg::Cr(s)) => idx(s).map_or(0, |i| self.streams[i].cr),
            ChainReg::Dma(DmaReg::Ndtr(s)) => idx(s).map_or(0, |i| self.streams[i].ndtr),
            ChainReg::Dma(DmaReg::Par(s)) => idx(s).map_or(0, |i| self.streams[i].par),
            ChainReg::Dma(DmaReg::M0ar(s)) => idx(s).map_or(0, |i| self.streams[i].m0ar),
            ChainReg::Dma(DmaReg::Fcr(s)) => idx(s).map_or(0, |i| self.streams[i].fcr),
            ChainReg::TimCr1 => self.tim_cr1,
            ChainReg::TimDier => self.tim_dier,
            ChainReg::TimSr => self.tim_sr,
            ChainReg::TimEgr => 0,
            ChainReg::TimCnt => self.tim_cnt,
            ChainReg::TimPsc => self.tim_psc,
            ChainReg::TimArr => self.tim_arr,
        }
    }

    fn write_reg(&mut self, reg: ChainReg, value: u32) {
        match reg {
            ChainReg::Spi(SpiReg::Cr1) => self.spi.cr1 = value & 0xFFFF,
            ChainReg::Spi(SpiReg::Cr2) => self.spi.cr2 = value & 0xFF,
            ChainReg::Spi(SpiReg::Sr) => {}
            ChainReg::Spi(SpiReg::Dr) => self.dr_write(value as u8),
            ChainReg::Dma(DmaReg::Lisr | DmaReg::Hisr) => self.violate("LISR/HISR are read-only"),
            ChainReg::Dma(DmaReg::Lifcr) => {
                if value & !STREAM_FLAGS != 0 {
                    self.violate(format!(
                        "LIFCR {value:#010x} clears flags of streams not the chain's"
                    ));
                }
                self.lisr &= !value;
            }
            ChainReg::Dma(DmaReg::Hifcr) => {
                self.violate("HIFCR written: streams 4–7 are not the chain's");
            }
            ChainReg::Dma(
                r @ (DmaReg::Cr(s)
                | DmaReg::Ndtr(s)
                | DmaReg::Par(s)
                | DmaReg::M0ar(s)
                | DmaReg::Fcr(s)),
            ) => self.stream_write(r, s, value),
            ChainReg::TimCr1 => {
                self.tim_cr1 = value & 0x8F;
                self.tim_schedule();
            }
            ChainReg::TimDier => self.tim_dier = value,
            ChainReg::TimSr => self.tim_sr &= value,
            ChainReg::TimEgr => {
                if value & TIM_EGR_UG != 0 {
                    self.tim_psc_live = self.tim_psc;
                    self.tim_cnt = 0;
                    if self.tim_cr1 & TIM_CR1_URS == 0 {
                        self.tim_sr |= TIM_SR_UIF;
                    }
                    self.tim_schedule();
                }
            }
            ChainReg::TimCnt => {
                self.tim_cnt = value & 0xFFFF;
                self.tim_schedule();
            }
            ChainReg::TimPsc => self.tim_psc = value & 0xFFFF,
            ChainReg::TimArr => {
                self.tim_arr = value & 0xFFFF;
                self.tim_schedule();
            }
        }
        self.dma_service();
    }
}

impl ChainHw for ChainHandle {
    fn cs(&mut self, high: bool) {
        let mut m = self.0.borrow_mut();
        m.tick_access();
        m.set_cs(high);
    }

    fn delay_cycles(&mut self, cycles: u32) {
        let mut m = self.0.borrow_mut();
        let t = m.now + u64::from(cycles) * 1_000_000_000_000 / SYSCLK_HZ;
        m.advance_to(t);
    }

    fn unpend_interrupts(&mut self) {
        self.0.borrow_mut().unpends += 1;
    }
}

impl ChainMemory for ChainHandle {
    fn write_tx_rows(&mut self, frames: &Frames, windows: usize) {
        let mut m = self.0.borrow_mut();
        for (dst, src) in m.mem.tx.iter_mut().zip(frames).take(windows) {
            *dst = *src;
        }
    }

    fn read_rx_rows(&self, out: &mut Frames, windows: usize) {
        let m = self.0.borrow();
        for (dst, src) in out.iter_mut().zip(&m.mem.rx).take(windows) {
            *dst = *src;
        }
    }

    fn row_address(&self, rx: bool, w: usize) -> Option<u32> {
        let base = if rx { RX_ROWS } else { TX_ROWS };
        (w < MAX_WINDOWS).then(|| base + (w * MAX_DEVICES) as u32)
    }

    fn dr_address(&self) -> u32 {
        SPI1_DR
    }
}

/// The chain's one driver, shared as the firmware shares it (its
/// critical-section cell): the bridge's [`ChainBus`] is a clone that asks
/// the driver for each blocking window; the tests — the control tick and
/// the two interrupts — reach the same driver with [`SharedChain::with`].
#[derive(Clone, Debug)]
pub struct SharedChain(Rc<RefCell<ChainSpi<ChainHandle>>>);

impl SharedChain {
    pub fn new(driver: ChainSpi<ChainHandle>) -> SharedChain {
        SharedChain(Rc::new(RefCell::new(driver)))
    }

    /// Run `f` on the driver.
    pub fn with<R>(&self, f: impl FnOnce(&mut ChainSpi<ChainHandle>) -> R) -> R {
        f(&mut self.0.borrow_mut())
    }
}

impl ChainBus for SharedChain {
    type Error = ChainSpiError;

    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ChainSpiError> {
        self.with(|d| d.window(tx, rx))
    }
}
