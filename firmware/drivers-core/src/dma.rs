//! DMA1/DMA2 streams as both DMA drivers use them (RM0090 §10): the stream
//! registers, one stream's five event flags wherever they sit in
//! LISR/HISR/LIFCR/HIFCR, the one rule for which flags are errors, and the
//! stream set-up both drivers follow (registers only while EN = 0, flags
//! cleared before EN).
//!
//! The chain driver (`chain_spi`: DMA2 streams 0 and 3) and the I/O
//! extension's (`ioext_spi`: DMA1 streams 3 and 4, DMA2 streams 2 and 6)
//! name their controller's registers through their own register enum; the
//! functions here take the enum's constructor (`ChainReg::Dma`,
//! `IoReg::Dma1`, …) so the same code reads and clears the flags of both.
//!
//! # Flags (RM0090 §10.5.1–§10.5.4)
//!
//! Streams 0–3 report in DMA_LISR (cleared through DMA_LIFCR), streams 4–7
//! in DMA_HISR (DMA_HIFCR), at bit offsets 0, 6, 16 and 22 of the
//! stream's number modulo 4: FEIF (+0), DMEIF (+2), TEIF (+3), HTIF (+4),
//! TCIF (+5). The clear registers are write-1-to-clear: a write touches only
//! the bits written as 1, so drivers sharing a controller (the chain and
//! the I/O extension share DMA2) each write their own streams' bits.
//!
//! # The FIFO-error rule
//!
//! TEIF (a bus error: the stream disabled itself) and DMEIF always end a
//! transfer. FEIF (in direct mode: the stream fell behind its request,
//! RM0090 §10.3.18) counts as an error unless the stream moves data *to* a
//! peripheral that waits for it ([`Role::TransmitWaited`]: an SPI master
//! clocks only the bytes it has, so a late byte is a longer gap, never a
//! lost or a wrong one; this FEIF also rises when such a stream is enabled
//! with its request already active). A receive stream's FEIF
//! ([`Role::Receive`]) means the peripheral produced faster than the stream
//! moved: whether the peripheral then lost an item depends on the
//! peripheral, so it counts. A transmit stream paced by a free-running
//! request ([`Role::TransmitTimed`], a timer compare) has no peripheral
//! waiting: its late item is a wrong level on the wire, so it counts too.
//! [`Role::errors`] is the rule; every stream of both drivers has its role.

use crate::Regs;

/// One DMA controller's registers (RM0090 §10.5): the interrupt status and
/// flag clear registers, and stream `n`'s configuration, item count,
/// peripheral and memory addresses and FIFO control.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DmaReg {
    Lisr,
    Hisr,
    Lifcr,
    Hifcr,
    Cr(u8),
    Ndtr(u8),
    Par(u8),
    M0ar(u8),
    Fcr(u8),
}

/// DMA_SxCR and DMA_SxFCR bits (RM0090 §10.5.5, §10.5.10).
pub mod bits {
    pub const DMA_CR_EN: u32 = 1 << 0;
    pub const DMA_CR_DMEIE: u32 = 1 << 1;
    pub const DMA_CR_TEIE: u32 = 1 << 2;
    pub const DMA_CR_HTIE: u32 = 1 << 3;
    pub const DMA_CR_TCIE: u32 = 1 << 4;
    pub const DMA_CR_PFCTRL: u32 = 1 << 5;
    pub const DMA_CR_DIR_SHIFT: u32 = 6;
    pub const DMA_CR_DIR_MASK: u32 = 0b11 << DMA_CR_DIR_SHIFT;
    /// DIR = 00: peripheral to memory.
    pub const DMA_CR_DIR_P2M: u32 = 0;
    pub const DMA_CR_DIR_M2P: u32 = 0b01 << DMA_CR_DIR_SHIFT;
    pub const DMA_CR_CIRC: u32 = 1 << 8;
    pub const DMA_CR_PINC: u32 = 1 << 9;
    pub const DMA_CR_MINC: u32 = 1 << 10;
    pub const DMA_CR_PSIZE_SHIFT: u32 = 11;
    pub const DMA_CR_PSIZE_MASK: u32 = 0b11 << DMA_CR_PSIZE_SHIFT;
    pub const DMA_CR_MSIZE_SHIFT: u32 = 13;
    pub const DMA_CR_MSIZE_MASK: u32 = 0b11 << DMA_CR_MSIZE_SHIFT;
    pub const DMA_CR_PL_SHIFT: u32 = 16;
    pub const DMA_CR_PL_HIGH: u32 = 0b10 << DMA_CR_PL_SHIFT;
    pub const DMA_CR_PL_VERY_HIGH: u32 = 0b11 << DMA_CR_PL_SHIFT;
    pub const DMA_CR_CHSEL_SHIFT: u32 = 25;
    pub const DMA_CR_CHSEL_MASK: u32 = 0b111 << DMA_CR_CHSEL_SHIFT;
    /// SxFCR reset value: direct mode (DMDIS = 0), FIFO threshold 1/2.
    pub const DMA_FCR_RESET: u32 = 0x21;
    pub const DMA_FCR_DMDIS: u32 = 1 << 2;
    pub const DMA_FCR_FEIE: u32 = 1 << 7;
}

use bits::*;

/// One stream's event flags, at stream 0's bit positions (FEIF bit 0,
/// DMEIF 2, TEIF 3, HTIF 4, TCIF 5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Flags(u32);

impl Flags {
    /// `bits` (stream 0's positions) as flags; other bits are dropped.
    pub const fn from_bits(bits: u32) -> Flags {
        Flags(bits & Self::ALL.0)
    }

    pub const NONE: Flags = Flags(0);
    pub const FEIF: Flags = Flags(1 << 0);
    pub const DMEIF: Flags = Flags(1 << 2);
    pub const TEIF: Flags = Flags(1 << 3);
    pub const HTIF: Flags = Flags(1 << 4);
    pub const TCIF: Flags = Flags(1 << 5);
    pub const ALL: Flags = Flags(0x3D);

    pub const fn bits(self) -> u32 {
        self.0
    }

    pub const fn union(self, other: Flags) -> Flags {
        Flags(self.0 | other.0)
    }

    /// Some flag of `other` is set here.
    pub const fn intersects(self, other: Flags) -> bool {
        self.0 & other.0 != 0
    }

    pub const fn contains(self, other: Flags) -> bool {
        self.0 & other.0 == other.0
    }

    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// These flags as `stream`'s bits of its status or clear register.
    pub const fn at(self, stream: u8) -> u32 {
        self.0 << offset(stream)
    }

    /// `stream`'s flags in `value`, a read of its status register.
    pub const fn of(value: u32, stream: u8) -> Flags {
        Flags((value >> offset(stream)) & Self::ALL.0)
    }
}

/// Where stream `stream`'s flags start in LISR/HISR (RM0090 §10.5.1).
pub const fn offset(stream: u8) -> u32 {
    match stream % 4 {
        0 => 0,
        1 => 6,
        2 => 16,
        _ => 22,
    }
}

/// The status register holding `stream`'s flags.
pub const fn status_register(stream: u8) -> DmaReg {
    if stream < 4 {
        DmaReg::Lisr
    } else {
        DmaReg::Hisr
    }
}

/// The register that clears `stream`'s flags.
pub const fn clear_register(stream: u8) -> DmaReg {
    if stream < 4 {
        DmaReg::Lifcr
    } else {
        DmaReg::Hifcr
    }
}

/// What a stream does for its peripheral: decides which of its flags are
/// errors (module docs, "The FIFO-error rule").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Peripheral to memory (SPI receive data, GPIO samples).
    Receive,
    /// Memory to a peripheral that waits for the data (SPI transmit).
    TransmitWaited,
    /// Memory to a peripheral, paced by a free-running request (a timer
    /// compare writing GPIO BSRR).
    TransmitTimed,
}

impl Role {
    /// The flags that end a transfer on a stream of this role.
    pub const fn errors(self) -> Flags {
        let always = Flags::TEIF.union(Flags::DMEIF);
        match self {
            Role::TransmitWaited => always,
            Role::Receive | Role::TransmitTimed => always.union(Flags::FEIF),
        }
    }

    /// DIR for this role.
    pub const fn dir(self) -> u32 {
        match self {
            Role::Receive => DMA_CR_DIR_P2M,
            Role::TransmitWaited | Role::TransmitTimed => DMA_CR_DIR_M2P,
        }
    }
}

/// Item size on both ports (direct mode: MSIZE = PSIZE).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Size {
    Byte,
    HalfWord,
    Word,
}

impl Size {
    const fn code(self) -> u32 {
        match self {
            Size::Byte => 0,
            Size::HalfWord => 1,
            Size::Word => 2,
        }
    }
}

/// One stream of a driver: where it is and how it is configured.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stream {
    /// Stream number, 0..=7.
    pub number: u8,
    /// Request channel (RM0090 tables 42/43), 0..=7.
    pub channel: u8,
    pub role: Role,
    pub size: Size,
    /// DMA_CR_PL_HIGH or DMA_CR_PL_VERY_HIGH.
    pub priority: u32,
    /// Interrupt enables (TCIE, TEIE, DMEIE); 0 for a stream whose errors
    /// are read at its partner's interrupt.
    pub interrupts: u32,
}

impl Stream {
    /// SxCR without EN: channel, direction, memory increment, sizes,
    /// priority, interrupts; circular, peripheral increment and double
    /// buffer off, the DMA as flow controller.
    pub const fn cr(&self) -> u32 {
        let size = self.size.code();
        (((self.channel as u32) << DMA_CR_CHSEL_SHIFT) & DMA_CR_CHSEL_MASK)
            | self.role.dir()
            | DMA_CR_MINC
            | (size << DMA_CR_PSIZE_SHIFT)
            | (size << DMA_CR_MSIZE_SHIFT)
            | self.priority
            | self.interrupts
    }
}

/// Set up a disabled stream (RM0090 §10.3.17): peripheral address, direct
/// mode, configuration with EN = 0.
#[inline]
pub fn configure<R: Copy>(
    hw: &mut impl Regs<R>,
    dma: impl Fn(DmaReg) -> R + Copy,
    s: &Stream,
    par: u32,
) {
    hw.write(dma(DmaReg::Par(s.number)), par);
    hw.write(dma(DmaReg::Fcr(s.number)), DMA_FCR_RESET);
    hw.write(dma(DmaReg::Cr(s.number)), s.cr());
}

/// Point a disabled stream at `m0ar` for `items` items.
#[inline]
pub fn load<R: Copy>(
    hw: &mut impl Regs<R>,
    dma: impl Fn(DmaReg) -> R + Copy,
    stream: u8,
    m0ar: u32,
    items: u32,
) {
    hw.write(dma(DmaReg::M0ar(stream)), m0ar);
    hw.write(dma(DmaReg::Ndtr(stream)), items);
}

/// Set EN (its flags must have been cleared).
#[inline]
pub fn enable<R: Copy>(hw: &mut impl Regs<R>, dma: impl Fn(DmaReg) -> R + Copy, stream: u8) {
    hw.modify(dma(DmaReg::Cr(stream)), |cr| cr | DMA_CR_EN);
}

/// Clear EN (the stream finishes its current item first).
#[inline]
pub fn disable<R: Copy>(hw: &mut impl Regs<R>, dma: impl Fn(DmaReg) -> R + Copy, stream: u8) {
    hw.modify(dma(DmaReg::Cr(stream)), |cr| cr & !DMA_CR_EN);
}

/// Wait (at most `polls` rounds) until streams `a` and `b` read EN = 0: a
/// stream disabled by software finishes its current item, and its
/// registers are writable only after that (RM0090 §10.3.17).
#[inline]
pub fn wait_disabled<R: Copy>(
    hw: &mut impl Regs<R>,
    dma: impl Fn(DmaReg) -> R + Copy,
    a: u8,
    b: u8,
    polls: u32,
) -> bool {
    (0..polls).any(|_| {
        hw.read(dma(DmaReg::Cr(a))) & DMA_CR_EN == 0 && hw.read(dma(DmaReg::Cr(b))) & DMA_CR_EN == 0
    })
}

/// `stream`'s flags (one status-register read).
#[inline]
pub fn read<R: Copy>(hw: &mut impl Regs<R>, dma: impl Fn(DmaReg) -> R + Copy, stream: u8) -> Flags {
    Flags::of(hw.read(dma(status_register(stream))), stream)
}

/// The flags of two streams; one read when they share a status register.
#[inline]
pub fn read_pair<R: Copy>(
    hw: &mut impl Regs<R>,
    dma: impl Fn(DmaReg) -> R + Copy,
    a: u8,
    b: u8,
) -> (Flags, Flags) {
    let va = hw.read(dma(status_register(a)));
    let vb = if status_register(a) == status_register(b) {
        va
    } else {
        hw.read(dma(status_register(b)))
    };
    (Flags::of(va, a), Flags::of(vb, b))
}

/// The LIFCR and HIFCR words that clear `flags` of each `(stream,
/// flags)`. A `const fn`: for fixed streams call it in a `const` block, so
/// the words are constants (`opt-level = "s"` does not unroll the loop).
// Evaluated at build time for the drivers' fixed stream lists: an index
// or an overflow there fails the build, not the firmware.
#[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
pub const fn clear_words(streams: &[(u8, Flags)]) -> [u32; 2] {
    let mut words = [0u32; 2];
    let mut i = 0;
    while i < streams.len() {
        let (s, f) = streams[i];
        words[(s / 4) as usize % 2] |= f.at(s);
        i += 1;
    }
    words
}

/// Write the clear words (LIFCR, HIFCR): one write each that has a bit to
/// clear (write 1 to clear: nothing else changes).
#[inline]
pub fn clear_with<R: Copy>(
    hw: &mut impl Regs<R>,
    dma: impl Fn(DmaReg) -> R + Copy,
    words: [u32; 2],
) {
    if words[0] != 0 {
        hw.write(dma(DmaReg::Lifcr), words[0]);
    }
    if words[1] != 0 {
        hw.write(dma(DmaReg::Hifcr), words[1]);
    }
}

/// Clear `flags` of each `(stream, flags)` ([`clear_words`],
/// [`clear_with`]).
#[inline]
pub fn clear<R: Copy>(
    hw: &mut impl Regs<R>,
    dma: impl Fn(DmaReg) -> R + Copy,
    streams: &[(u8, Flags)],
) {
    clear_with(hw, dma, clear_words(streams));
}
