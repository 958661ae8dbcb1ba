//! The Copley registers as values: the I/O options, the configuration word,
//! and the bit order of the transmit and receive data.
//!
//! * **Configuration** bits exactly as the Copley note defines them
//!   ([`mod@cfg`]). Undocumented bits are masked on write and read 0
//!   ([`Config::from_register`] says whether any were set, so the caller can
//!   count them). Bit 11 (status) is not part of a [`Config`]: it is state of
//!   the extension, read-only, and a write of it is ignored. Bit 28 clear
//!   (SLI mode) is refused with [`IoError::Unsupported`].
//! * **Bit count**: bits 0–7 hold n − 1, so every register value means
//!   1..=256 bits; 0 and 257+ cannot be written through the register, and
//!   the typed constructor [`Config::new`] refuses them with
//!   [`IoError::IllegalValue`].
//! * **Wire order** ([`WireBits`]): the data is a string of up to 256 bits
//!   sent and received MSB first, word 0 first. Wire bit `i` (the i-th bit
//!   clocked, 0 = first) is bit `15 − i % 16` of word `i / 16`. A transfer
//!   of n bits sends wire bits `0..n` and stores the n received bits at the
//!   same positions; bits from n on are not sent and read as 0 in the
//!   receive data. So 8 bits `0xA5` are written as word 0 = `0xA500`, and a
//!   1-bit transfer sends bit 15 of word 0.

use super::IoError;

/// Most bits one transfer moves (8-bit field holding n − 1).
pub const MAX_BITS: u16 = 256;
/// Words of transmit / receive data (16 × 16 = 256 bits).
pub const WORDS: usize = 16;

/// Configuration register bits (Copley I/O extension note).
pub mod cfg {
    /// Bits 0–7: number of bits to transfer − 1.
    pub const BITS: u32 = 0xFF;
    /// Bit 9: restart the transfer automatically every control tick.
    pub const AUTO_RESTART: u32 = 1 << 9;
    /// Bit 10: leave CS low after the transfer.
    pub const CS_HOLD: u32 = 1 << 10;
    /// Bit 11: a transfer ended and updated the receive data (read-only;
    /// cleared when the receive data is read).
    pub const STATUS: u32 = 1 << 11;
    /// Bit 12: clock polarity (1 = clock high between transfers).
    pub const CPOL: u32 = 1 << 12;
    /// Bit 13: data phase (1 = sample on the trailing clock edge).
    pub const CPHA: u32 = 1 << 13;
    /// Bits 16–23: clock period N, in 100 ns units: (N·100 + 20) ns.
    pub const PERIOD: u32 = 0xFF << PERIOD_SHIFT;
    pub const PERIOD_SHIFT: u32 = 16;
    /// Bit 28: SPI mode (clear = SLI mode, refused).
    pub const SPI_MODE: u32 = 1 << 28;
    /// Bits a write stores.
    pub const WRITABLE: u32 = BITS | AUTO_RESTART | CS_HOLD | CPOL | CPHA | PERIOD | SPI_MODE;
    /// Every documented bit (the writable ones and the status bit).
    pub const DOCUMENTED: u32 = WRITABLE | STATUS;
}

/// I/O options register bits (Copley parameter 0x15A, the two bits the note
/// documents for modules).
pub mod options {
    /// Bit 0: the I/O extension is enabled.
    pub const ENABLE: u32 = 1 << 0;
    /// Bit 1: SLI-mode LED style. SLI mode is not implemented, so this bit
    /// is masked like an undocumented one (reads 0).
    pub const SLI_BICOLOR: u32 = 1 << 1;
    /// Bits a write stores.
    pub const WRITABLE: u32 = ENABLE;
}

/// Clock polarity and data phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SpiMode {
    /// Clock level between transfers (true = high).
    pub cpol: bool,
    /// false: sample on the leading edge, change on the trailing edge;
    /// true: change on the leading edge, sample on the trailing edge.
    pub cpha: bool,
}

impl SpiMode {
    pub const MODE0: SpiMode = SpiMode {
        cpol: false,
        cpha: false,
    };
    pub const MODE1: SpiMode = SpiMode {
        cpol: false,
        cpha: true,
    };
    pub const MODE2: SpiMode = SpiMode {
        cpol: true,
        cpha: false,
    };
    pub const MODE3: SpiMode = SpiMode {
        cpol: true,
        cpha: true,
    };
    pub const ALL: [SpiMode; 4] = [Self::MODE0, Self::MODE1, Self::MODE2, Self::MODE3];
}

/// The writable part of the configuration register (status excluded).
///
/// Invariant: only [`cfg::WRITABLE`] bits are set and [`cfg::SPI_MODE`] is
/// one of them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config(u32);

impl Config {
    /// Factory configuration: SPI mode, 8 bits, mode 0, N = 10 (1 020 ns
    /// requested, 1 523.8 ns produced), no auto-restart, no CS hold.
    pub const FACTORY: Config = Config(cfg::SPI_MODE | (10 << cfg::PERIOD_SHIFT) | 7);

    /// A configuration from a register write. Undocumented bits are dropped
    /// (the flag says whether any were set); the status bit is ignored.
    /// SLI mode (bit 28 clear) is [`IoError::Unsupported`].
    pub const fn from_register(value: u32) -> Result<(Config, bool), IoError> {
        if value & cfg::SPI_MODE == 0 {
            return Err(IoError::Unsupported);
        }
        Ok((Config(value & cfg::WRITABLE), value & !cfg::DOCUMENTED != 0))
    }

    /// A configuration from its fields; `bits` must be 1..=256.
    pub const fn new(bits: u16, mode: SpiMode, period_n: u8) -> Result<Config, IoError> {
        if bits == 0 || bits > MAX_BITS {
            return Err(IoError::IllegalValue);
        }
        // 1..=256 − 1 fits the 8-bit field.
        let field = bits.saturating_sub(1) as u32;
        let mut v = cfg::SPI_MODE | field | ((period_n as u32) << cfg::PERIOD_SHIFT);
        if mode.cpol {
            v |= cfg::CPOL;
        }
        if mode.cpha {
            v |= cfg::CPHA;
        }
        Ok(Config(v))
    }

    /// The register value with the given status bit.
    pub const fn register(self, status: bool) -> u32 {
        if status {
            self.0 | cfg::STATUS
        } else {
            self.0
        }
    }

    /// Bits per transfer, 1..=256.
    pub const fn bits(self) -> u16 {
        // 0..=255 + 1: never wraps.
        ((self.0 & cfg::BITS) as u16).wrapping_add(1)
    }

    /// Words of data the bit count needs (1..=16).
    pub const fn words(self) -> usize {
        words_for(self.bits())
    }

    pub const fn auto_restart(self) -> bool {
        self.0 & cfg::AUTO_RESTART != 0
    }

    pub const fn cs_hold(self) -> bool {
        self.0 & cfg::CS_HOLD != 0
    }

    pub const fn mode(self) -> SpiMode {
        SpiMode {
            cpol: self.0 & cfg::CPOL != 0,
            cpha: self.0 & cfg::CPHA != 0,
        }
    }

    /// The clock period field N ((N·100 + 20) ns requested).
    pub const fn period_n(self) -> u8 {
        ((self.0 & cfg::PERIOD) >> cfg::PERIOD_SHIFT) as u8
    }

    /// The same configuration with bit 9 set or cleared.
    pub const fn with_auto_restart(self, on: bool) -> Config {
        Config(set(self.0, cfg::AUTO_RESTART, on))
    }

    /// The same configuration with bit 10 set or cleared.
    pub const fn with_cs_hold(self, on: bool) -> Config {
        Config(set(self.0, cfg::CS_HOLD, on))
    }
}

const fn set(v: u32, bit: u32, on: bool) -> u32 {
    if on {
        v | bit
    } else {
        v & !bit
    }
}

/// Words needed for `bits` bits: ⌈bits / 16⌉, at most [`WORDS`].
pub const fn words_for(bits: u16) -> usize {
    let w = (bits as usize).div_ceil(16);
    if w > WORDS {
        WORDS
    } else {
        w
    }
}

/// Up to 256 bits in wire order (see the module doc): wire bit `i` is bit
/// `15 − i % 16` of word `i / 16`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WireBits([u16; WORDS]);

impl WireBits {
    pub const ZERO: WireBits = WireBits([0; WORDS]);

    pub const fn from_words(words: [u16; WORDS]) -> WireBits {
        WireBits(words)
    }

    /// Bits `0..bits` set to `level(i)`, the rest 0.
    pub fn from_fn(bits: u16, level: impl Fn(usize) -> bool) -> WireBits {
        let mut w = WireBits::ZERO;
        for i in 0..usize::from(bits) {
            w.set(i, level(i));
        }
        w
    }

    pub const fn words(&self) -> &[u16; WORDS] {
        &self.0
    }

    pub fn words_mut(&mut self) -> &mut [u16; WORDS] {
        &mut self.0
    }

    /// Wire bit `i` (false from 256 on).
    pub fn get(&self, i: usize) -> bool {
        self.0
            .get(i / 16)
            .is_some_and(|w| w & (0x8000 >> (i % 16)) != 0)
    }

    /// Set wire bit `i` (no effect from 256 on).
    pub fn set(&mut self, i: usize, level: bool) {
        if let Some(w) = self.0.get_mut(i / 16) {
            let m = 0x8000 >> (i % 16);
            if level {
                *w |= m;
            } else {
                *w &= !m;
            }
        }
    }

    /// The first `bits` bits; every later bit cleared.
    pub fn truncated(mut self, bits: u16) -> WireBits {
        let bits = usize::from(bits);
        for (k, w) in self.0.iter_mut().enumerate() {
            let first = k.saturating_mul(16);
            let keep = bits.saturating_sub(first);
            if keep == 0 {
                *w = 0;
            } else if keep < 16 {
                // Keep the top `keep` bits (1..=15).
                *w &= !(0xFFFF_u16 >> keep);
            }
        }
        self
    }

    /// Byte `j` in wire order (the high byte of word `j / 2` when `j` is
    /// even, its low byte when odd): what an 8-bit MSB-first SPI frame
    /// carries. 0 from byte 32 on.
    pub fn byte(&self, j: usize) -> u8 {
        let w = self.0.get(j / 2).copied().unwrap_or(0);
        let [hi, lo] = w.to_be_bytes();
        if j % 2 == 0 {
            hi
        } else {
            lo
        }
    }

    /// Bits from 8-bit MSB-first frames in wire order (at most 32 bytes are
    /// used; missing ones read 0).
    pub fn from_bytes(bytes: &[u8]) -> WireBits {
        let mut out = WireBits::ZERO;
        for (w, pair) in out.0.iter_mut().zip(bytes.chunks(2)) {
            let hi = pair.first().copied().unwrap_or(0);
            let lo = pair.get(1).copied().unwrap_or(0);
            *w = u16::from_be_bytes([hi, lo]);
        }
        out
    }

    /// Bits from GPIO port samples (one 16-bit IDR value per bit, in wire
    /// order): wire bit `k` is bit `pin` of `samples[k]` (at most 256
    /// samples are used; `pin` is taken modulo 16).
    pub fn from_port_samples(samples: &[u16], pin: u8) -> WireBits {
        let mask = 1u16 << (pin % 16);
        let mut out = WireBits::ZERO;
        for (w, chunk) in out.0.iter_mut().zip(samples.chunks(16)) {
            let mut acc = 0u16;
            for s in chunk {
                acc = acc.wrapping_shl(1) | u16::from(s & mask != 0);
            }
            // A short last chunk: its bits belong at the top.
            let len = u32::try_from(chunk.len()).unwrap_or(16);
            *w = acc.wrapping_shl(16u32.saturating_sub(len));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    #![allow(
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects,
        clippy::unwrap_used
    )]
    #![allow(clippy::panic)]
    use super::*;

    #[test]
    fn wire_bit_zero_is_the_msb_of_word_zero() {
        let mut b = WireBits::ZERO;
        b.set(0, true);
        assert_eq!(b.words()[0], 0x8000);
        b.set(15, true);
        b.set(16, true);
        assert_eq!(b.words()[..2], [0x8001, 0x8000]);
        assert!(b.get(0) && b.get(15) && b.get(16) && !b.get(1));
    }

    #[test]
    fn bits_past_256_are_ignored_and_read_false() {
        let mut b = WireBits::ZERO;
        b.set(256, true);
        b.set(usize::MAX, true);
        assert_eq!(b, WireBits::ZERO);
        assert!(!b.get(256) && !b.get(usize::MAX));
    }

    #[test]
    fn truncation_keeps_exactly_the_first_n_bits() {
        let all = WireBits::from_words([0xFFFF; WORDS]);
        for n in [1u16, 7, 8, 9, 15, 16, 17, 31, 32, 33, 255, 256] {
            let t = all.truncated(n);
            for i in 0..300 {
                assert_eq!(t.get(i), i < usize::from(n), "n = {n}, bit {i}");
            }
        }
        assert_eq!(all.truncated(0), WireBits::ZERO);
    }

    #[test]
    fn bytes_are_the_words_big_endian_in_order() {
        let b = WireBits::from_words({
            let mut w = [0; WORDS];
            w[0] = 0xA55A;
            w[1] = 0x0102;
            w
        });
        assert_eq!(
            [b.byte(0), b.byte(1), b.byte(2), b.byte(3)],
            [0xA5, 0x5A, 0x01, 0x02]
        );
        assert_eq!(b.byte(32), 0);
        assert_eq!(WireBits::from_bytes(&[0xA5, 0x5A, 0x01, 0x02]), b);
        // An odd byte count fills the high byte of the last word.
        assert_eq!(WireBits::from_bytes(&[0xA5]).words()[0], 0xA500);
        // Bytes past 32 are ignored.
        assert_eq!(
            WireBits::from_bytes(&[0xFF; 40]),
            WireBits::from_words([0xFFFF; WORDS])
        );
    }

    #[test]
    fn port_samples_give_one_bit_each_from_the_pin() {
        let samples = [1 << 14, 0, 0xFFFF, !(1 << 14)];
        let b = WireBits::from_port_samples(&samples, 14);
        assert_eq!(b.words()[0], 0b1010 << 12);
        // 300 samples: only 256 are used.
        let b = WireBits::from_port_samples(&[1 << 3; 300], 3);
        assert_eq!(b, WireBits::from_words([0xFFFF; WORDS]));
    }

    #[test]
    fn every_configuration_field_has_its_copley_bit() {
        let (c, reserved) = Config::from_register(
            cfg::SPI_MODE
                | 30
                | cfg::AUTO_RESTART
                | cfg::CS_HOLD
                | cfg::CPOL
                | cfg::CPHA
                | (200 << 16),
        )
        .unwrap();
        assert!(!reserved);
        assert_eq!(c.bits(), 31);
        assert!(c.auto_restart() && c.cs_hold());
        assert_eq!(c.mode(), SpiMode::MODE3);
        assert_eq!(c.period_n(), 200);
        let only = |bit: u32| Config::from_register(cfg::SPI_MODE | bit).unwrap().0;
        assert!(only(cfg::AUTO_RESTART).auto_restart() && !only(0).auto_restart());
        assert!(only(cfg::CS_HOLD).cs_hold() && !only(0).cs_hold());
        assert_eq!(only(cfg::CPOL).mode(), SpiMode::MODE2);
        assert_eq!(only(cfg::CPHA).mode(), SpiMode::MODE1);
        assert_eq!(only(0).mode(), SpiMode::MODE0);
        assert_eq!(only(0).bits(), 1);
        assert_eq!(only(255).bits(), 256);
        assert_eq!(only(255 << 16).period_n(), 255);
    }

    #[test]
    fn undocumented_bits_are_masked_and_reported() {
        for bit in [8, 14, 15, 24, 25, 26, 27, 29, 30, 31] {
            let (c, reserved) = Config::from_register(cfg::SPI_MODE | 1 << bit | 7).unwrap();
            assert!(reserved, "bit {bit}");
            assert_eq!(c.register(false), cfg::SPI_MODE | 7, "bit {bit}");
        }
    }

    #[test]
    fn the_status_bit_is_not_stored_by_a_write() {
        let (c, reserved) = Config::from_register(cfg::SPI_MODE | cfg::STATUS).unwrap();
        assert!(!reserved);
        assert_eq!(c.register(false), cfg::SPI_MODE);
        assert_eq!(c.register(true), cfg::SPI_MODE | cfg::STATUS);
    }

    #[test]
    fn sli_mode_is_refused() {
        assert_eq!(Config::from_register(0), Err(IoError::Unsupported));
        assert_eq!(
            Config::from_register(cfg::WRITABLE & !cfg::SPI_MODE),
            Err(IoError::Unsupported)
        );
    }

    #[test]
    fn bit_counts_0_and_above_256_are_illegal_values() {
        assert_eq!(
            Config::new(0, SpiMode::MODE0, 0),
            Err(IoError::IllegalValue)
        );
        assert_eq!(
            Config::new(257, SpiMode::MODE0, 0),
            Err(IoError::IllegalValue)
        );
        assert_eq!(
            Config::new(u16::MAX, SpiMode::MODE0, 0),
            Err(IoError::IllegalValue)
        );
        for n in [1u16, 7, 8, 9, 31, 32, 33, 255, 256] {
            let c = Config::new(n, SpiMode::MODE1, 5).unwrap();
            assert_eq!((c.bits(), c.mode(), c.period_n()), (n, SpiMode::MODE1, 5));
            assert_eq!(c.words(), usize::from(n).div_ceil(16));
        }
    }

    #[test]
    fn factory_config_is_8_bits_mode_0_n_10_in_spi_mode() {
        let c = Config::FACTORY;
        assert_eq!((c.bits(), c.mode(), c.period_n()), (8, SpiMode::MODE0, 10));
        assert!(!c.auto_restart() && !c.cs_hold());
        assert_eq!(Config::from_register(c.register(false)), Ok((c, false)));
    }
}
