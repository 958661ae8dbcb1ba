//! RM0090 §28, §17, §10 and §8: SPI2 as the I/O extension's master, TIM1 as
//! its bit engine, DMA1 streams 3/4 and DMA2 streams 2/6, GPIOB's four port
//! pins as levels, and a chain of 74HC165s and 74HC595s on those pins
//! ([`ShiftRegs`], this model's own bit-level one, wired as
//! `stepbridge_sim::shift` documents), as `drivers_core::ioext_spi` sees
//! them. Time runs in cycles of 168 MHz — the CPU's and TIM1's clock; SPI2's
//! 42 MHz kernel clock is 4 of them — so every edge is exact; a register
//! access takes [`ACCESS`] cycles, a DMA request is served [`DMA_LATENCY`]
//! cycles after it rises.
//!
//! # Rules (RM0090 rev 19 section numbers)
//!
//! | # | rule | section |
//! |---|---|---|
//! | X1 | SPI2 shifts a frame only with SPE = 1, MSTR = 1 and SSM = SSI = 1 (software NSS held high, else MODF); the port needs 8-bit frames (DFF = 0), MSB first (LSBFIRST = 0), full duplex (BIDIMODE = RXONLY = 0) | §28.3.3 "Configuring the SPI in master mode", §28.5.1 |
//! | X2 | SPI2's CPHA, CPOL, MSTR, BR, LSBFIRST, SSI, SSM, RXONLY, DFF and BIDIMODE change only while SPE = 0 ("should not be changed when communication is ongoing"; the model takes it as "while enabled") | §28.5.1 |
//! | X3 | SCK = f_PCLK1 / 2^(BR+1). A frame starts when DR's byte moves to the shift register (TXE sets); CPHA = 0: MOSI takes the MSB at the start and the next bit at each trailing edge, MISO is sampled at the leading edges; CPHA = 1: MOSI changes at the leading edges, MISO is sampled at the trailing edges. The frame ends one period after its start edge: RXNE with the byte (OVR instead if RXNE is still set; a DR read followed by an SR read clears OVR); the next frame follows at once if DR holds one; BSY from the first load to the end of the last frame | §28.3.5, §28.3.7, §28.4.8, §28.5.3 (the edge positions inside a frame: UNCONFIRMED, from the timing diagrams as known) |
//! | X4 | With TXDMAEN a TXE raises SPI2_TX's DMA request, with RXDMAEN an RXNE raises SPI2_RX's. Start order: RXDMAEN, then the streams, then TXDMAEN; a TX stream enabled while its request is already active sets its FEIF (UNCONFIRMED: the FIFO error RM0090 describes for direct mode memory-to-peripheral), and TXDMAEN before the TX stream is enabled is recorded | §28.3.9 "SPI communication using DMA" |
//! | X5 | SPE cleared while BSY cuts a frame (the SPI disable procedure waits for BSY = 0 first); CS may rise only once BSY is clear | §28.3.8 "Disabling the SPI" |
//! | X6 | A stream's PAR, M0AR, NDTR, FCR and configuration bits are written only while EN = 0; its flags are cleared (LIFCR/HIFCR, write 1) before EN is set; NDTR ≠ 0 at EN | §10.3.17 "Stream configuration procedure", §10.5.5–§10.5.10 |
//! | X7 | Request mapping: DMA1 stream 3 channel 0 = SPI2_RX, stream 4 channel 0 = SPI2_TX; DMA2 stream 2 channel 6 = TIM1_CH2, stream 6 channel 6 = TIM1_CH3; a stream on another channel never sees the request. Streams other than these four are not the port's (DMA2 0/3 are the chain's) | §10.3.3, Tables 42 and 43 |
//! | X8 | Directions, addresses, sizes: SPI2_RX/TX peripheral-to-memory / memory-to-peripheral at SPI2_DR in bytes; the samples peripheral-to-memory from GPIOB_IDR (half-words); the MOSI table memory-to-peripheral to GPIOB_BSRR in words (BSRR's reset half is its upper 16 bits); memory increment, no peripheral increment, not circular, direct mode with MSIZE = PSIZE ("in direct mode MSIZE is forced to PSIZE"); DMA1's peripheral port does not reach AHB1, so a DMA1 stream at GPIO is a bus error (TEIF, EN cleared); so is an address outside the port's buffers and registers | §10.3.6, §10.3.11, §10.5.5, §2.1 (bus matrix) |
//! | X9 | Each item counts NDTR down; HTIF at half, TCIF and EN = 0 at 0; TEIF disables the stream; TCIE/TEIE/DMEIE/HTIE (SxCR) and FEIE (SxFCR) gate the stream's interrupt line (`DMA1_STREAM3`, `DMA2_STREAM2`) | §10.3.6, §10.3.18, §10.5.1–§10.5.5 |
//! | X10 | TIM1 counts at f / (PSC + 1) from CNT while CEN = 1; PSC and RCR are preloaded (in effect at UG or an update event); CNT overflows after ARR; at an overflow the update event comes when the repetition counter is 0 (then reloaded from RCR; otherwise it counts down), so RCR = n − 1 makes n periods; UG resets CNT and loads the preloads; one-pulse mode clears CEN at the update event | §17.3.1–§17.3.3 "Repetition counter", §17.3.15 "One-pulse mode" |
//! | X11 | TIM1 CH1: OC1REF per OC1M (frozen: kept; forced inactive: low; PWM mode 2: low while CNT < CCR1, else high); CH1N drives the pin (AF1) with OC1REF xor CC1NP when MOE = 1, CC1NE = 1 and CC1E = 0 (no dead time), and not at all otherwise; CNT = CCR2 / CCR3 raise TIM1_CH2 / TIM1_CH3 with CC2DE / CC3DE, a request the stream must be ready for (enabled, and served before the next one); PSC, ARR, RCR, CCRx, CCMRx and CCER are not written while CEN = 1 | §17.3.6, §17.3.10 "PWM mode", §17.3.11 "Complementary outputs", §17.4.3–§17.4.18 |
//! | X12 | GPIOB: MODER, PUPDR and AFRH fields of every pin but PB13–PB15 stay as they are (PB11 stays CS, a push-pull output), and are written only inside the driver's critical section (other drivers' pins share the registers); BSRR writes touch only CS (PB11) and MOSI (PB15); a set bit wins over its reset bit; IDR reads every pin's level in input and alternate-function mode | §8.3.1, §8.3.7, §8.4.1–§8.4.10 |
//! | X13 | The wire (Copley's note, `bridge_logic::ioext::wire`): CS and SCK never change at the same instant; SPI2 or TIM1 never clock SCK while CS is high (SCK only moves to a new CPOL there); CS rises with SCK at the level it had when CS fell (a transfer ends at CPOL) | not RM0090 |
//!
//! The tests compare each CS window with the plan (`bits` leading and
//! trailing edges, the first edge at least the plan's half period after CS
//! fell, CS at least that after the last edge, no period shorter than the
//! plan's) and the bits with what the logic expects.
//!
//! # Modelling choices (UNCONFIRMED)
//!
//! * A DMA request is served [`DMA_LATENCY`] cycles after it rises (no
//!   arbitration between streams; RM0090 gives no number).
//! * A pin that nothing drives (input, or an alternate function whose
//!   peripheral is off) follows its pull-up/down, or keeps its level
//!   without one; CS has its external pull-up. SPI2's MOSI keeps its last
//!   bit between frames.
//! * The timer starts counting at the CEN write; NVIC pending bits are not
//!   modelled (an interrupt line is a level).
//! * A stream never falls behind by itself (no FIFO overrun or underrun):
//!   FEIF, TEIF and DMEIF come from the tests ([`IoModel::fail_next`]; an
//!   injected FEIF still moves its item, RM0090 §10.3.18 "no data loss"),
//!   and FEIF from a transmit stream enabled while its request is active
//!   (X4). A stuck stream is [`IoModel::stall`].
//! * The chips: one '165 and one '595 a chip, no propagation delays; the
//!   tests use 32 of each so every one of 256 bits reaches one.

use drivers_core::dma::bits::*;
use drivers_core::dma::{DmaReg, Flags};
use drivers_core::ioext_spi::bits::*;
use drivers_core::ioext_spi::{GpioReg, IoExtBuffers, IoExtHw, IoReg, Pins, Target, TimReg, MAX};
use drivers_core::spi::bits::*;
use drivers_core::spi::SpiReg;

use super::spi::SpiPort;

mod dma;
mod gpio;
mod spi;
mod tim;

/// The CPU's and TIM1's clock; every time in the model is in its cycles.
pub const CLOCK_HZ: u64 = 168_000_000;
/// SPI2's kernel clock (APB1), 4 model cycles a tick.
pub const PCLK1_HZ: u64 = 42_000_000;
const SPI_TICK: u64 = CLOCK_HZ / PCLK1_HZ;
/// One register access.
pub const ACCESS: u64 = 4;
/// From a DMA request to its item moved.
pub const DMA_LATENCY: u64 = 6;
/// The board's pins (`pins.rs`): CS PB11, SCK PB13, MISO PB14, MOSI PB15.
pub const PINS: Pins = Pins {
    cs: 11,
    sck: 13,
    miso: 14,
    mosi: 15,
};
/// Bus addresses the model gives the buffers, and the registers' (RM0090
/// §2.3: SPI2 at 0x4000_3800, GPIOB at 0x4002_0400).
pub const TX_BYTES: u32 = 0x2000_0000;
pub const RX_BYTES: u32 = 0x2000_0100;
pub const MOSI_TABLE: u32 = 0x2000_1000;
pub const SAMPLES: u32 = 0x2000_2000;
pub const SPI2_DR: u32 = 0x4000_380C;
pub const GPIOB_IDR: u32 = 0x4002_0410;
pub const GPIOB_BSRR: u32 = 0x4002_0418;

/// Cycles for `ns` (rounded up).
pub fn cycles_of_ns(ns: u64) -> u64 {
    (ns * CLOCK_HZ).div_ceil(1_000_000_000)
}

// ------------------------------------------------------------ the chips --

/// `n165` 74HC165s and `n595` 74HC595s on SCK, MOSI, MISO and CS, wired as
/// `stepbridge_sim::shift` documents (CS → RCLK of every '595; CS →
/// inverter → SH/LD of every '165; '165 #0's QH is MISO, '595 #0's SER is
/// MOSI). Written here from the datasheets, not shared with the logic's
/// simulator: SH/LD low (CS high) loads the '165s from their inputs, as
/// long as it lasts; a rising SCK edge shifts the '165s towards QH while
/// CS is low and the '595s always; a rising CS edge latches the '595s'
/// outputs. Every part sees the levels before an edge.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ShiftRegs {
    n165: usize,
    n595: usize,
    /// Bit x = input A + x.
    inputs: Vec<u8>,
    /// Bit x = stage A + x; QH = bit 7.
    sr165: Vec<u8>,
    /// Bit x = stage QA + x.
    sr595: Vec<u8>,
    out595: Vec<u8>,
    cs: bool,
}

impl ShiftRegs {
    pub fn new(n165: usize, n595: usize) -> ShiftRegs {
        ShiftRegs {
            n165,
            n595,
            inputs: vec![0; n165],
            sr165: vec![0; n165],
            sr595: vec![0; n595],
            out595: vec![0; n595],
            cs: true,
        }
    }

    /// The input receive bit `i` reads: input H − i % 8 of '165 #i / 8.
    pub fn set_rx_bit(&mut self, i: usize, level: bool) {
        if let Some(b) = self.inputs.get_mut(i / 8) {
            let m = 0x80 >> (i % 8);
            if level {
                *b |= m;
            } else {
                *b &= !m;
            }
        }
        if self.cs {
            self.sr165.clone_from(&self.inputs);
        }
    }

    /// Latched output stage `s` (= 8·chip + pin, QA = pin 0).
    pub fn stage(&self, s: usize) -> bool {
        self.out595
            .get(s / 8)
            .is_some_and(|b| b & (1 << (s % 8)) != 0)
    }

    /// The output that shows transmit bit `i` after an `n`-bit transfer:
    /// stage n − 1 − i.
    pub fn tx_bit_output(&self, n: usize, i: usize) -> bool {
        n.checked_sub(1 + i).is_some_and(|s| self.stage(s))
    }

    pub fn stages(&self) -> usize {
        8 * self.n595
    }

    /// MISO: '165 #0's QH (ground without a '165).
    pub fn miso(&self) -> bool {
        self.sr165.first().is_some_and(|b| b & 0x80 != 0)
    }

    fn cs_edge(&mut self, high: bool) {
        self.cs = high;
        if high {
            self.out595.clone_from(&self.sr595);
            self.sr165.clone_from(&self.inputs);
        }
    }

    fn sck_rise(&mut self, mosi: bool) {
        if !self.cs {
            for k in 0..self.n165 {
                let ser = self.sr165.get(k + 1).is_some_and(|b| b & 0x80 != 0);
                self.sr165[k] = (self.sr165[k] << 1) | u8::from(ser);
            }
        }
        let mut ser = mosi;
        for k in 0..self.n595 {
            let qh = self.sr595[k] & 0x80 != 0;
            self.sr595[k] = (self.sr595[k] << 1) | u8::from(ser);
            ser = qh;
        }
    }
}

// ------------------------------------------------------------- the wire --

/// One CS-low window as the chips saw it (times in cycles).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CsWindow {
    pub fell: u64,
    pub rose: Option<u64>,
    /// SCK's level when CS fell.
    pub idle: bool,
    /// When the engine started inside this window (TIM1's CEN, SPI2's
    /// first frame), if it did after CS fell.
    pub engine_start: Option<u64>,
    /// Every SCK edge inside the window (alternately leading and
    /// trailing, from the idle level).
    pub edges: Vec<u64>,
}

// ------------------------------------------------------------ the model --

#[derive(Clone, Copy, Debug, Default)]
struct Stream {
    cr: u32,
    ndtr: u32,
    par: u32,
    m0ar: u32,
    fcr: u32,
    /// Items moved since EN, and NDTR at EN.
    moved: u32,
    start: u32,
    /// A request waits to be served at this time.
    pending: Option<u64>,
    fail_next: Option<Flags>,
    stalled: bool,
}

#[derive(Clone, Debug)]
struct Dma {
    streams: [Stream; 8],
    /// LISR and HISR.
    isr: [u32; 2],
}

impl Dma {
    fn new() -> Dma {
        Dma {
            streams: [Stream {
                fcr: DMA_FCR_RESET,
                ..Stream::default()
            }; 8],
            isr: [0; 2],
        }
    }

    fn flags(&self, s: u8) -> Flags {
        Flags::of(self.isr[usize::from(s / 4)], s)
    }

    fn raise(&mut self, s: u8, f: Flags) {
        self.isr[usize::from(s / 4)] |= f.at(s);
    }

    fn line(&self, s: u8) -> bool {
        let st = &self.streams[usize::from(s)];
        let f = self.flags(s);
        (st.cr & DMA_CR_TCIE != 0 && f.intersects(Flags::TCIF))
            || (st.cr & DMA_CR_TEIE != 0 && f.intersects(Flags::TEIF))
            || (st.cr & DMA_CR_DMEIE != 0 && f.intersects(Flags::DMEIF))
            || (st.cr & DMA_CR_HTIE != 0 && f.intersects(Flags::HTIF))
            || (st.fcr & DMA_FCR_FEIE != 0 && f.intersects(Flags::FEIF))
    }
}

/// Which request a stream of the port serves (X7, X8).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Request {
    SpiRx,
    SpiTx,
    TimCh2,
    TimCh3,
}

impl Request {
    /// (controller, stream, channel, peripheral-to-memory, PAR, PSIZE codes allowed)
    fn of(ctl: u8, stream: u8) -> Option<Request> {
        match (ctl, stream) {
            (1, 3) => Some(Request::SpiRx),
            (1, 4) => Some(Request::SpiTx),
            (2, 2) => Some(Request::TimCh2),
            (2, 6) => Some(Request::TimCh3),
            _ => None,
        }
    }

    fn channel(self) -> u32 {
        match self {
            Request::SpiRx | Request::SpiTx => 0,
            Request::TimCh2 | Request::TimCh3 => 6,
        }
    }

    fn p2m(self) -> bool {
        matches!(self, Request::SpiRx | Request::TimCh2)
    }

    fn name(self) -> &'static str {
        match self {
            Request::SpiRx => "SPI2_RX",
            Request::SpiTx => "SPI2_TX",
            Request::TimCh2 => "TIM1_CH2",
            Request::TimCh3 => "TIM1_CH3",
        }
    }
}

/// A frame on SPI2's wire.
#[derive(Clone, Copy, Debug)]
struct Frame {
    out: u8,
    got: u8,
    /// Half periods done, 0..16, and when the next one ends.
    step: u8,
    next: u64,
    half: u64,
}

/// SPI2, TIM1, DMA1/DMA2, GPIOB and the chips (module docs).
pub struct IoModel {
    now: u64,
    // SPI2
    spi: SpiPort,
    frame: Option<Frame>,
    spi_sck: bool,
    spi_mosi: bool,
    // DMA
    dma: [Dma; 2],
    // TIM1
    tim_cr1: u32,
    tim_dier: u32,
    tim_sr: u32,
    tim_ccmr1: u32,
    tim_ccmr2: u32,
    tim_ccer: u32,
    tim_bdtr: u32,
    tim_psc: u32,
    tim_psc_live: u32,
    tim_arr: u32,
    tim_rcr: u32,
    tim_rep: u32,
    tim_ccr: [u32; 3],
    tim_cnt: u32,
    /// While counting: when CNT took its value.
    tim_at: u64,
    oc1ref: bool,
    // GPIOB
    moder: u32,
    pupdr: u32,
    afrh: u32,
    odr: u32,
    masked: u32,
    // pins and chips
    cs: bool,
    sck: bool,
    mosi: bool,
    pub chips: ShiftRegs,
    pub mem: IoExtBuffers,
    windows: Vec<CsWindow>,
    stray_edges: u32,
    violations: Vec<String>,
}

impl std::fmt::Debug for IoModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("IoModel")
            .field("now", &self.now)
            .field("spi_cr1", &format_args!("{:#06x}", self.spi.cr1))
            .field("spi_cr2", &format_args!("{:#06x}", self.spi.cr2))
            .field("tim_cr1", &format_args!("{:#06x}", self.tim_cr1))
            .field("cs", &self.cs)
            .field("sck", &self.sck)
            .field("violations", &self.violations)
            .finish()
    }
}

const OUR_PINS: [u8; 3] = [13, 14, 15];

fn field(reg: u32, pin: u8, width: u32) -> u32 {
    (reg >> (u32::from(pin) * width)) & ((1 << width) - 1)
}

impl IoModel {
    /// Reset state as `pins::configure` leaves GPIOB (CS an output, high;
    /// SCK and MOSI floating inputs; MISO an input with a pull-up), the
    /// chips behind the pins.
    pub fn new(chips: ShiftRegs) -> IoModel {
        let mut m = IoModel {
            now: 0,
            spi: SpiPort::default(),
            frame: None,
            spi_sck: false,
            spi_mosi: false,
            dma: [Dma::new(), Dma::new()],
            tim_cr1: 0,
            tim_dier: 0,
            tim_sr: 0,
            tim_ccmr1: 0,
            tim_ccmr2: 0,
            tim_ccer: 0,
            tim_bdtr: 0,
            tim_psc: 0,
            tim_psc_live: 0,
            tim_arr: 0xFFFF,
            tim_rcr: 0,
            tim_rep: 0,
            tim_ccr: [0; 3],
            tim_cnt: 0,
            tim_at: 0,
            oc1ref: false,
            moder: GPIO_MODE_OUTPUT << 22,
            pupdr: GPIO_PULL_UP << 28,
            afrh: 0,
            odr: 1 << 11,
            masked: 0,
            cs: true,
            sck: false,
            mosi: false,
            chips,
            mem: IoExtBuffers::new(),
            windows: Vec::new(),
            stray_edges: 0,
            violations: Vec::new(),
        };
        m.update_pins();
        m
    }

    pub fn now(&self) -> u64 {
        self.now
    }

    pub fn now_ns(&self) -> u64 {
        self.now * 1_000_000_000 / CLOCK_HZ
    }

    pub fn violations(&self) -> &[String] {
        &self.violations
    }

    pub fn windows(&self) -> &[CsWindow] {
        &self.windows
    }

    /// SCK edges while CS was high (a CPOL change between transfers makes
    /// one).
    pub fn stray_edges(&self) -> u32 {
        self.stray_edges
    }

    pub fn cs_high(&self) -> bool {
        self.cs
    }

    pub fn sck(&self) -> bool {
        self.sck
    }

    pub fn spi_cr1(&self) -> u32 {
        self.spi.cr1
    }

    pub fn spi_cr2(&self) -> u32 {
        self.spi.cr2
    }

    pub fn tim_cr1(&self) -> u32 {
        self.tim_cr1
    }

    pub fn tim_dier(&self) -> u32 {
        self.tim_dier
    }

    pub fn moder(&self) -> u32 {
        self.moder
    }

    /// Stream `stream`'s CR on DMA`ctl` (1 or 2).
    pub fn stream_cr(&self, ctl: u8, stream: u8) -> u32 {
        self.dma[usize::from(ctl - 1)].streams[usize::from(stream)].cr
    }

    /// Stream `stream`'s PAR on DMA`ctl`.
    pub fn stream_par(&self, ctl: u8, stream: u8) -> u32 {
        self.dma[usize::from(ctl - 1)].streams[usize::from(stream)].par
    }

    /// Stream `stream`'s flags on DMA`ctl`.
    pub fn stream_flags(&self, ctl: u8, stream: u8) -> Flags {
        self.dma[usize::from(ctl - 1)].flags(stream)
    }

    /// Raise `flags` on the next item of the stream instead of moving it
    /// (TEIF also disables it); FEIF moves the item all the same (RM0090
    /// §10.3.18: no data lost).
    pub fn fail_next(&mut self, ctl: u8, stream: u8, flags: Flags) {
        self.dma[usize::from(ctl - 1)].streams[usize::from(stream)].fail_next = Some(flags);
    }

    /// Set `flags` on the stream (a flag left over from the last transfer).
    pub fn raise(&mut self, ctl: u8, stream: u8, flags: Flags) {
        self.dma[usize::from(ctl - 1)].raise(stream, flags);
    }

    /// The stream's requests are never served (a stuck DMA): for the
    /// timeout tests.
    pub fn stall(&mut self, ctl: u8, stream: u8, stalled: bool) {
        self.dma[usize::from(ctl - 1)].streams[usize::from(stream)].stalled = stalled;
    }

    /// `DMA1_STREAM3`'s line (the SPI engine's end).
    pub fn irq_spi(&self) -> bool {
        self.dma[0].line(3)
    }

    /// `DMA2_STREAM2`'s line (the bit engine's end).
    pub fn irq_timer(&self) -> bool {
        self.dma[1].line(2)
    }

    /// Some other stream's interrupt line (none is enabled by the port).
    pub fn irq_other(&self) -> bool {
        self.dma[0].line(4) || self.dma[1].line(6)
    }

    fn violate(&mut self, what: impl Into<String>) {
        let what = what.into();
        self.violations
            .push(format!("{what} (at {} ns)", self.now_ns()));
    }

    // ------------------------------------------------------------ time --

    fn tim_tick(&self) -> u64 {
        u64::from(self.tim_psc_live) + 1
    }

    fn tim_running(&self) -> bool {
        self.tim_cr1 & TIM_CR1_CEN != 0
    }

    /// The next CNT value that is an event (a compare or the overflow, as
    /// ARR + 1), and when CNT reaches it.
    fn tim_next(&self) -> Option<(u32, u64)> {
        if !self.tim_running() {
            return None;
        }
        // A CNT above ARR (never written by the driver) counts on to the
        // overflow all the same.
        let mut v = (self.tim_arr + 1).max(self.tim_cnt + 1);
        for &c in &self.tim_ccr {
            if c > self.tim_cnt && c <= self.tim_arr {
                v = v.min(c);
            }
        }
        Some((
            v,
            self.tim_at + u64::from(v - self.tim_cnt) * self.tim_tick(),
        ))
    }

    fn dma_next(&self) -> Option<u64> {
        self.dma
            .iter()
            .flat_map(|d| d.streams.iter().filter_map(|s| s.pending))
            .min()
    }

    /// When the next event is due.
    pub fn next_event(&self) -> Option<u64> {
        [
            self.frame.map(|f| f.next),
            self.tim_next().map(|(_, t)| t),
            self.dma_next(),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Let time run to `t`, with every event on the way.
    pub fn advance_to(&mut self, t: u64) {
        while let Some(next) = self.next_event().filter(|&n| n <= t) {
            self.now = self.now.max(next);
            if self.frame.is_some_and(|f| f.next <= self.now) {
                self.spi_step();
            }
            if let Some((v, at)) = self.tim_next() {
                if at <= self.now {
                    self.tim_event(v);
                }
            }
            self.dma_service();
        }
        self.now = self.now.max(t);
    }
}

/// A shared handle on the model: the driver holds one, the tests another.
pub type IoHandle = super::Handle<IoModel>;

impl IoHandle {
    pub fn new(chips: ShiftRegs) -> IoHandle {
        super::Handle::of(IoModel::new(chips))
    }
}

impl super::RegisterFile<IoReg> for IoModel {
    fn tick_access(&mut self) {
        IoModel::tick_access(self);
    }

    fn read_reg(&mut self, reg: IoReg) -> u32 {
        match reg {
            IoReg::Spi(r) => {
                let busy = self.busy();
                self.spi.read(r, busy)
            }
            IoReg::Dma1(r) => self.dma_read(1, r),
            IoReg::Dma2(r) => self.dma_read(2, r),
            IoReg::Tim(r) => self.tim_read(r),
            IoReg::Gpio(r) => match r {
                GpioReg::Moder => self.moder,
                GpioReg::Pupdr => self.pupdr,
                GpioReg::Afrh => self.afrh,
                GpioReg::Idr => self.idr(),
                GpioReg::Bsrr => 0,
            },
        }
    }

    fn write_reg(&mut self, reg: IoReg, value: u32) {
        match reg {
            IoReg::Spi(r) => match r {
                SpiReg::Cr1 => self.spi_cr1_write(value),
                SpiReg::Cr2 => {
                    let value = value & 0xFF;
                    if value & SPI_CR2_TXDMAEN != 0 && self.spi.cr2 & SPI_CR2_TXDMAEN == 0 {
                        let tx = self.dma[0].streams[4].cr;
                        if tx & DMA_CR_EN == 0 {
                            self.violate("X4: TXDMAEN set with the SPI2_TX stream disabled");
                        }
                        let rx = self.dma[0].streams[3].cr;
                        if rx & DMA_CR_EN == 0 || self.spi.cr2 & SPI_CR2_RXDMAEN == 0 {
                            self.violate("X4: TXDMAEN set before RXDMAEN and the SPI2_RX stream");
                        }
                    }
                    self.spi.cr2 = value;
                    self.spi_requests();
                }
                SpiReg::Sr => {}
                SpiReg::Dr => self.dr_write(value as u8),
            },
            IoReg::Dma1(r) => self.dma_write(1, r, value),
            IoReg::Dma2(r) => self.dma_write(2, r, value),
            IoReg::Tim(r) => self.tim_write(r, value),
            IoReg::Gpio(r) => self.gpio_write(r, value),
        }
        self.update_pins();
    }
}

impl IoExtHw for IoHandle {
    const PINS: Pins = PINS;

    fn delay_cycles(&mut self, cycles: u32) {
        let mut m = self.0.borrow_mut();
        let t = m.now + u64::from(cycles);
        m.advance_to(t);
    }

    fn masked<R>(&mut self, f: impl FnOnce(&mut Self) -> R) -> R {
        self.0.borrow_mut().masked += 1;
        let r = f(self);
        self.0.borrow_mut().masked -= 1;
        r
    }

    fn buffers<R>(&mut self, f: impl FnOnce(&mut IoExtBuffers) -> R) -> R {
        f(&mut self.0.borrow_mut().mem)
    }

    fn address(&self, target: Target) -> u32 {
        match target {
            Target::TxBytes => TX_BYTES,
            Target::RxBytes => RX_BYTES,
            Target::MosiTable => MOSI_TABLE,
            Target::Samples => SAMPLES,
            Target::SpiDr => SPI2_DR,
            Target::GpioBsrr => GPIOB_BSRR,
            Target::GpioIdr => GPIOB_IDR,
        }
    }
}

// Keep MAX in use (the buffers' size is the driver's).
const _: () = assert!(MAX == 256);
