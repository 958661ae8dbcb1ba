//! A simulated NOR flash with power-cut injection (feature `sim`), `no_std`,
//! no allocation: the flash the settings store ([`crate`]) is tested
//! on, and the one a QEMU image can use.
//!
//! # What it models
//!
//! * `SECTORS` erase units of `SECTOR_SIZE` bytes, contiguous from offset 0.
//!   [`NorFlash`] with `ERASE_SIZE = SECTOR_SIZE`, `WRITE_SIZE = 4`,
//!   `READ_SIZE = 1`; misaligned or out-of-range arguments are errors.
//! * NOR semantics: erase sets every byte of a sector to `0xFF`; a program
//!   can only clear bits (the stored word becomes `old & new`), so programming
//!   a 1 over a 0 keeps the 0. Programming a word that is no longer erased is
//!   allowed (as on the STM32F4) but counted in
//!   [`FlashCounters::overwrites`]: `NorFlash` users must not do it, and tests
//!   assert they do not.
//! * Operation counting: every program (`write`) and every erase call is one
//!   *operation*, numbered from 0 in the order they are started
//!   ([`SimFlash::ops`] is the number the next one gets). Reads are counted
//!   separately and are not operations.
//! * Power cuts: [`SimFlash::cut_power_at`]`(k, seed)` makes operation `k`
//!   torn, after which the flash is unpowered: every read, program and erase
//!   fails with [`SimFlashError::PowerOff`] until [`SimFlash::restore_power`].
//!   The torn operation itself also returns `PowerOff`. What it leaves behind
//!   is drawn from a deterministic PRNG seeded with `seed`:
//!   * a torn **program** of `n` words programs a prefix of `0..=n` words
//!     completely (all `n` is possible: the data got there but the CPU never
//!     saw the result), then, half of the time, the next word partially: an
//!     arbitrary subset of its 1→0 transitions. Words after that, and every
//!     other word of the flash, are untouched.
//!   * a torn **erase** picks one of four outcomes for the sector: untouched,
//!     completely erased, or word by word (twice as likely) one of: erased,
//!     unchanged, random bits set (`old | r`), or an arbitrary value `r`.
//!     Sectors before it in a multi-sector erase are erased; later ones are
//!     untouched.
//!
//! Not modelled: marginally programmed cells that read differently later,
//! read disturb, wear-out, and timing.

// A test double (feature `sim`), not the store: it reads no untrusted input,
// and its indexing and arithmetic are on its own bounded state.
#![allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used
)]
#![allow(clippy::expect_used, clippy::panic)]

use core::fmt;

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// Program granularity of the simulated flash (one 32-bit word).
pub const WORD: usize = 4;

/// Errors of the simulated flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SimFlashError {
    /// The flash is unpowered: the operation was torn, or power was cut by
    /// an earlier one and not restored yet.
    PowerOff,
    /// Offset or length not a multiple of the read/write/erase unit.
    NotAligned,
    /// Outside the flash, or an erase range with `from > to`.
    OutOfBounds,
}

impl NorFlashError for SimFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SimFlashError::PowerOff => NorFlashErrorKind::Other,
            SimFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            SimFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
        }
    }
}

/// What the flash has been asked to do since it was created.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlashCounters {
    /// Successful `read` calls.
    pub reads: u64,
    /// Program (`write`) operations started, torn ones included.
    pub programs: u64,
    /// Erase operations started, torn ones included.
    pub erases: u64,
    /// Words programmed while not erased (with a value that clears a bit).
    pub overwrites: u64,
}

/// Small deterministic PRNG (SplitMix64) for tearing patterns and tests.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    pub fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    /// Uniform in `0..n` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        match u64::try_from(n) {
            Ok(0) | Err(_) => 0,
            // The result is < n, so it fits in usize.
            Ok(n) => usize::try_from(self.next_u64() % n).unwrap_or(0),
        }
    }

    /// Uniform in `lo..=hi` (`lo` when `hi < lo`).
    pub fn range(&mut self, lo: usize, hi: usize) -> usize {
        let span = hi.saturating_sub(lo).saturating_add(1);
        lo.saturating_add(self.below(span))
    }

    pub fn coin(&mut self) -> bool {
        self.next_u64() & 1 == 1
    }

    pub fn fill(&mut self, bytes: &mut [u8]) {
        for b in bytes {
            *b = self.next_u64() as u8;
        }
    }
}

/// `SECTORS` NOR sectors of `SECTOR_SIZE` bytes (a multiple of [`WORD`]).
#[derive(Clone)]
pub struct SimFlash<const SECTOR_SIZE: usize, const SECTORS: usize> {
    sectors: [[u8; SECTOR_SIZE]; SECTORS],
    sector_erases: [u32; SECTORS],
    counters: FlashCounters,
    /// Index of the next program/erase operation.
    ops: u64,
    /// Operation to tear, if any.
    cut_at: Option<u64>,
    powered: bool,
    rng: SplitMix64,
}

impl<const SECTOR_SIZE: usize, const SECTORS: usize> fmt::Debug for SimFlash<SECTOR_SIZE, SECTORS> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SimFlash")
            .field("sector_size", &SECTOR_SIZE)
            .field("sectors", &SECTORS)
            .field("sector_erases", &self.sector_erases)
            .field("counters", &self.counters)
            .field("ops", &self.ops)
            .field("cut_at", &self.cut_at)
            .field("powered", &self.powered)
            .finish_non_exhaustive()
    }
}

impl<const SECTOR_SIZE: usize, const SECTORS: usize> Default for SimFlash<SECTOR_SIZE, SECTORS> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const SECTOR_SIZE: usize, const SECTORS: usize> SimFlash<SECTOR_SIZE, SECTORS> {
    const SECTOR_IS_WORDS: () = assert!(
        SECTOR_SIZE > 0 && SECTOR_SIZE % WORD == 0,
        "SimFlash: SECTOR_SIZE must be a non-zero multiple of 4"
    );

    /// A fully erased, powered flash.
    pub fn new() -> Self {
        let () = Self::SECTOR_IS_WORDS;
        SimFlash {
            sectors: [[0xFF; SECTOR_SIZE]; SECTORS],
            sector_erases: [0; SECTORS],
            counters: FlashCounters::default(),
            ops: 0,
            cut_at: None,
            powered: true,
            rng: SplitMix64::new(0),
        }
    }

    /// The raw contents, sector by sector (no counting, works unpowered).
    pub fn sectors(&self) -> &[[u8; SECTOR_SIZE]; SECTORS] {
        &self.sectors
    }

    /// Tamper with the raw contents, bypassing NOR semantics and counters
    /// (tests use it to corrupt records or fill the flash with garbage).
    pub fn sectors_mut(&mut self) -> &mut [[u8; SECTOR_SIZE]; SECTORS] {
        &mut self.sectors
    }

    /// Completed and torn erases per sector.
    pub fn sector_erases(&self) -> &[u32; SECTORS] {
        &self.sector_erases
    }

    pub fn counters(&self) -> FlashCounters {
        self.counters
    }

    /// Number of program/erase operations started so far: the index the
    /// next one will get.
    pub fn ops(&self) -> u64 {
        self.ops
    }

    /// Tear operation number `op` (see [`SimFlash::ops`]) with a pattern
    /// drawn from `seed`, and cut power there. Replaces an earlier request.
    pub fn cut_power_at(&mut self, op: u64, seed: u64) {
        self.cut_at = Some(op);
        self.rng = SplitMix64::new(seed);
    }

    /// Power comes back: operations work again, no cut is pending.
    pub fn restore_power(&mut self) {
        self.powered = true;
        self.cut_at = None;
    }

    pub fn is_powered(&self) -> bool {
        self.powered
    }

    /// Starts an operation: `Ok(true)` when this one is to be torn (power is
    /// then off).
    fn begin_op(&mut self) -> Result<bool, SimFlashError> {
        if !self.powered {
            return Err(SimFlashError::PowerOff);
        }
        let index = self.ops;
        self.ops = self.ops.saturating_add(1);
        let torn = self.cut_at == Some(index);
        if torn {
            self.powered = false;
            self.cut_at = None;
        }
        Ok(torn)
    }

    fn capacity_bytes() -> usize {
        SECTOR_SIZE.saturating_mul(SECTORS)
    }

    /// `(sector, offset in sector)` of the flash offset `at`, if in range.
    fn locate(at: usize) -> Option<(usize, usize)> {
        let sector = at.checked_div(SECTOR_SIZE)?;
        let offset = at.checked_rem(SECTOR_SIZE)?;
        (sector < SECTORS).then_some((sector, offset))
    }

    fn byte_mut(&mut self, at: usize) -> Option<&mut u8> {
        let (s, o) = Self::locate(at)?;
        self.sectors.get_mut(s)?.get_mut(o)
    }

    fn word(&self, at: usize) -> [u8; WORD] {
        let mut w = [0xFF; WORD];
        for (i, b) in w.iter_mut().enumerate() {
            if let Some((s, o)) = at.checked_add(i).and_then(Self::locate) {
                if let Some(v) = self.sectors.get(s).and_then(|sec| sec.get(o)) {
                    *b = *v;
                }
            }
        }
        w
    }

    fn set_word(&mut self, at: usize, w: [u8; WORD]) {
        for (i, v) in w.into_iter().enumerate() {
            if let Some(b) = at.checked_add(i).and_then(|a| self.byte_mut(a)) {
                *b = v;
            }
        }
    }

    /// NOR program of one word: `old & new`, counting overwrites.
    fn program_word(&mut self, at: usize, new: [u8; WORD]) {
        let old = self.word(at);
        if old != [0xFF; WORD] && new != [0xFF; WORD] {
            self.counters.overwrites = self.counters.overwrites.saturating_add(1);
        }
        let mut out = old;
        for (o, n) in out.iter_mut().zip(new) {
            *o &= n;
        }
        self.set_word(at, out);
    }

    /// Torn program of one word: an arbitrary subset of its 1→0 transitions.
    fn program_word_partially(&mut self, at: usize, new: [u8; WORD]) {
        let old = self.word(at);
        let old32 = u32::from_le_bytes(old);
        let new32 = u32::from_le_bytes(new);
        let cleared = old32 & !new32 & self.rng.next_u32();
        self.program_word(at, (old32 & !cleared).to_le_bytes());
    }

    fn check_range(offset: u32, len: usize, align: usize) -> Result<usize, SimFlashError> {
        let start = usize::try_from(offset).map_err(|_| SimFlashError::OutOfBounds)?;
        let end = start.checked_add(len).ok_or(SimFlashError::OutOfBounds)?;
        if end > Self::capacity_bytes() {
            return Err(SimFlashError::OutOfBounds);
        }
        if start % align != 0 || len % align != 0 {
            return Err(SimFlashError::NotAligned);
        }
        Ok(start)
    }

    fn erase_sector(&mut self, s: usize, torn: bool) {
        if let Some(n) = self.sector_erases.get_mut(s) {
            *n = n.saturating_add(1);
        }
        let mode = if torn { self.rng.below(4) } else { 1 };
        let Some(sector) = self.sectors.get_mut(s) else {
            return;
        };
        match mode {
            0 => {}
            1 => sector.fill(0xFF),
            _ => {
                for word in sector.chunks_exact_mut(WORD) {
                    let r = self.rng.next_u32();
                    let old = word
                        .first_chunk::<WORD>()
                        .map_or(0, |w| u32::from_le_bytes(*w));
                    let new = match self.rng.below(4) {
                        0 => u32::MAX,
                        1 => old,
                        2 => old | r,
                        _ => r,
                    };
                    word.copy_from_slice(&new.to_le_bytes());
                }
            }
        }
    }
}

impl<const SECTOR_SIZE: usize, const SECTORS: usize> ErrorType for SimFlash<SECTOR_SIZE, SECTORS> {
    type Error = SimFlashError;
}

impl<const SECTOR_SIZE: usize, const SECTORS: usize> ReadNorFlash
    for SimFlash<SECTOR_SIZE, SECTORS>
{
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        if !self.powered {
            return Err(SimFlashError::PowerOff);
        }
        let mut at = Self::check_range(offset, bytes.len(), Self::READ_SIZE)?;
        let mut rest = bytes;
        while !rest.is_empty() {
            let (s, o) = Self::locate(at).ok_or(SimFlashError::OutOfBounds)?;
            let src = self
                .sectors
                .get(s)
                .and_then(|sec| sec.get(o..))
                .ok_or(SimFlashError::OutOfBounds)?;
            let n = src.len().min(rest.len());
            let (dst, tail) = rest.split_at_mut(n);
            dst.copy_from_slice(src.get(..n).ok_or(SimFlashError::OutOfBounds)?);
            rest = tail;
            at = at.saturating_add(n);
        }
        self.counters.reads = self.counters.reads.saturating_add(1);
        Ok(())
    }

    fn capacity(&self) -> usize {
        Self::capacity_bytes()
    }
}

impl<const SECTOR_SIZE: usize, const SECTORS: usize> NorFlash for SimFlash<SECTOR_SIZE, SECTORS> {
    const WRITE_SIZE: usize = WORD;
    const ERASE_SIZE: usize = SECTOR_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        if !self.powered {
            return Err(SimFlashError::PowerOff);
        }
        let len = to.checked_sub(from).ok_or(SimFlashError::OutOfBounds)?;
        let len = usize::try_from(len).map_err(|_| SimFlashError::OutOfBounds)?;
        let start = Self::check_range(from, len, SECTOR_SIZE)?;
        let first = start / SECTOR_SIZE;
        let count = len / SECTOR_SIZE;
        let torn = self.begin_op()?;
        self.counters.erases = self.counters.erases.saturating_add(1);
        // A torn multi-sector erase tears one of its sectors; earlier ones
        // are done, later ones untouched.
        let torn_at = if torn { self.rng.below(count) } else { count };
        for i in 0..count {
            let s = first.saturating_add(i);
            match i.cmp(&torn_at) {
                core::cmp::Ordering::Less => self.erase_sector(s, false),
                core::cmp::Ordering::Equal => self.erase_sector(s, true),
                core::cmp::Ordering::Greater => break,
            }
        }
        if torn {
            Err(SimFlashError::PowerOff)
        } else {
            Ok(())
        }
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        if !self.powered {
            return Err(SimFlashError::PowerOff);
        }
        let start = Self::check_range(offset, bytes.len(), WORD)?;
        let torn = self.begin_op()?;
        self.counters.programs = self.counters.programs.saturating_add(1);
        let words = bytes.len() / WORD;
        let done = if torn {
            self.rng.below(words.saturating_add(1))
        } else {
            words
        };
        for (i, chunk) in bytes.chunks_exact(WORD).enumerate() {
            let Some(new) = chunk.first_chunk::<WORD>().copied() else {
                break;
            };
            let at = start.saturating_add(i.saturating_mul(WORD));
            if i < done {
                self.program_word(at, new);
            } else {
                if self.rng.coin() {
                    self.program_word_partially(at, new);
                }
                break;
            }
        }
        if torn {
            Err(SimFlashError::PowerOff)
        } else {
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Flash = SimFlash<64, 2>;

    fn read_all(f: &mut Flash) -> Vec<u8> {
        let mut v = vec![0; 128];
        f.read(0, &mut v).unwrap();
        v
    }

    #[test]
    fn new_flash_is_erased() {
        let mut f = Flash::new();
        assert!(read_all(&mut f).iter().all(|&b| b == 0xFF));
        assert_eq!(f.capacity(), 128);
    }

    #[test]
    fn program_can_only_clear_bits() {
        let mut f = Flash::new();
        f.write(8, &[0x0F, 0xF0, 0x00, 0xFF]).unwrap();
        f.write(8, &[0xFF, 0x3C, 0xFF, 0xAA]).unwrap();
        let mut w = [0; 4];
        f.read(8, &mut w).unwrap();
        assert_eq!(w, [0x0F, 0x30, 0x00, 0xAA]);
    }

    #[test]
    fn programming_a_written_word_counts_as_overwrite() {
        let mut f = Flash::new();
        f.write(0, &[0; 8]).unwrap();
        assert_eq!(f.counters().overwrites, 0);
        f.write(4, &[0xFF; 4]).unwrap(); // all-ones: no-op, not counted
        assert_eq!(f.counters().overwrites, 0);
        f.write(4, &[0; 4]).unwrap();
        assert_eq!(f.counters().overwrites, 1);
    }

    #[test]
    fn erase_sets_one_sector_to_ff() {
        let mut f = Flash::new();
        f.write(0, &[0; 128]).unwrap();
        f.erase(64, 128).unwrap();
        let all = read_all(&mut f);
        assert!(all[..64].iter().all(|&b| b == 0));
        assert!(all[64..].iter().all(|&b| b == 0xFF));
        assert_eq!(f.sector_erases(), &[0, 1]);
    }

    #[test]
    fn misaligned_and_out_of_range_requests_are_rejected() {
        let mut f = Flash::new();
        assert_eq!(f.write(2, &[0; 4]), Err(SimFlashError::NotAligned));
        assert_eq!(f.write(0, &[0; 3]), Err(SimFlashError::NotAligned));
        assert_eq!(f.write(128, &[0; 4]), Err(SimFlashError::OutOfBounds));
        assert_eq!(f.erase(0, 32), Err(SimFlashError::NotAligned));
        assert_eq!(f.erase(64, 0), Err(SimFlashError::OutOfBounds));
        assert_eq!(f.erase(0, 192), Err(SimFlashError::OutOfBounds));
        let mut b = [0; 2];
        assert_eq!(f.read(127, &mut b), Err(SimFlashError::OutOfBounds));
        assert_eq!(f.read(u32::MAX, &mut b), Err(SimFlashError::OutOfBounds));
        assert_eq!(f.ops(), 0, "rejected requests are not operations");
    }

    #[test]
    fn operations_are_numbered_and_reads_are_not_operations() {
        let mut f = Flash::new();
        let mut b = [0; 4];
        f.read(0, &mut b).unwrap();
        f.write(0, &[0; 4]).unwrap();
        f.erase(0, 64).unwrap();
        assert_eq!(f.ops(), 2);
        let c = f.counters();
        assert_eq!((c.reads, c.programs, c.erases), (1, 1, 1));
    }

    #[test]
    fn cut_tears_operation_k_and_fails_everything_until_power_returns() {
        let mut f = Flash::new();
        f.cut_power_at(1, 7);
        f.write(0, &[0; 4]).unwrap(); // op 0
        assert_eq!(f.write(4, &[0; 4]), Err(SimFlashError::PowerOff)); // op 1, torn
        assert!(!f.is_powered());
        let mut b = [0; 4];
        assert_eq!(f.read(0, &mut b), Err(SimFlashError::PowerOff));
        assert_eq!(f.write(8, &[0; 4]), Err(SimFlashError::PowerOff));
        assert_eq!(f.erase(0, 64), Err(SimFlashError::PowerOff));
        assert_eq!(f.ops(), 2, "failed operations while unpowered do not count");
        f.restore_power();
        f.write(8, &[0; 4]).unwrap();
        assert_eq!(f.read(8, &mut b), Ok(()));
        assert_eq!(b, [0; 4]);
    }

    #[test]
    fn torn_program_leaves_a_prefix_and_at_most_one_partial_word() {
        let new: Vec<u8> = (0..64).map(|i| (i * 37 % 251) as u8 & 0x7E).collect();
        let mut prefixes = std::collections::BTreeSet::new();
        for seed in 0..200 {
            let mut f = Flash::new();
            f.cut_power_at(0, seed);
            assert_eq!(f.write(64, &new), Err(SimFlashError::PowerOff));
            f.restore_power();
            let all = read_all(&mut f);
            assert!(
                all[..64].iter().all(|&b| b == 0xFF),
                "other sector untouched"
            );
            let got = &all[64..];
            let words: Vec<_> = got.chunks(4).zip(new.chunks(4)).collect();
            let full = words.iter().take_while(|(g, n)| g == n).count();
            prefixes.insert(full);
            let rest = &words[full.min(words.len())..];
            if let Some(((g, n), after)) = rest.split_first() {
                // The first unfinished word has only bits of old & new's 1→0
                // transitions cleared, everything after it is still erased.
                for (gb, nb) in g.iter().zip(n.iter()) {
                    assert_eq!(gb & nb, *nb, "only bits the program clears may be cleared");
                }
                assert!(after.iter().all(|(g, _)| g.iter().all(|&b| b == 0xFF)));
            }
        }
        assert!(
            prefixes.contains(&0) && prefixes.contains(&16),
            "{prefixes:?}"
        );
    }

    #[test]
    fn torn_erase_touches_only_its_sector() {
        let mut patterns = 0;
        for seed in 0..100 {
            let mut f = Flash::new();
            f.write(0, &[0x5A; 128]).unwrap();
            f.cut_power_at(1, seed);
            assert_eq!(f.erase(64, 128), Err(SimFlashError::PowerOff));
            f.restore_power();
            let all = read_all(&mut f);
            assert!(all[..64].iter().all(|&b| b == 0x5A));
            let torn = &all[64..];
            if torn.iter().any(|&b| b != 0x5A) && torn.iter().any(|&b| b != 0xFF) {
                patterns += 1;
            }
        }
        assert!(patterns > 10, "mixed outcomes are drawn: {patterns}");
    }

    #[test]
    fn same_seed_tears_the_same_way() {
        let run = |seed| {
            let mut f = Flash::new();
            f.write(0, &[0x11; 64]).unwrap();
            f.cut_power_at(1, seed);
            let _ = f.erase(0, 64);
            f.restore_power();
            f.cut_power_at(2, seed ^ 1);
            let _ = f.write(64, &[0; 64]);
            f.restore_power();
            read_all(&mut f)
        };
        assert_eq!(run(42), run(42));
        assert_ne!(run(42), run(43));
    }
}
