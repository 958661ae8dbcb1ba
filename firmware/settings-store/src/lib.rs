//! Settings store: one opaque settings image (≤ [`MAX_IMAGE`] bytes) kept in
//! two erase units of NOR flash, for "Write settings to EEPROM".
//!
//! # Guarantees
//!
//! 1. **Old or new, never a mix, never nothing.** If power is cut at any
//!    moment of [`Store::save`] (during any program or erase, or between
//!    them), the next [`Store::load`] returns exactly the image of the last
//!    save that returned `Ok` or exactly the image being saved — never a
//!    mix of the two, never another older image, and never an error once a
//!    save has returned `Ok`. After the cut the store keeps working: the
//!    next save and load behave as if nothing had happened.
//! 2. **Versioned and checked.** Every record carries [`FORMAT_VERSION`], a
//!    header CRC and a CRC-32 (ISO-HDLC) over header and payload. `load`
//!    returns only records of this format version whose CRCs and commit word
//!    are intact; anything else is skipped.
//! 3. **Wear-levelled.** Records are appended to the active sector; a sector
//!    is erased only when the store moves to it because the active one is
//!    full, so the two sectors are erased alternately, once per
//!    `ERASE_SIZE / record size` saves (84 saves of a full image per
//!    erase with the STM32F405's 128 KiB sectors). `load` never writes.
//! 4. **Unreadable is reported.** `load` says [`StoreError::Empty`] when both
//!    sectors are completely erased (factory-fresh) and
//!    [`StoreError::Corrupt`] when they hold something but no loadable
//!    record. The caller then boots with defaults; a later `save` works on
//!    any flash content and `load` returns that image from then on (unless
//!    the flash holds forged records, see the assumptions).
//! 5. **Untrusted content.** No flash content makes the store panic, loop
//!    forever or read outside its two sectors: every length, offset and CRC
//!    read from flash is checked (the module denies unchecked indexing and
//!    overflowing arithmetic). No allocation, `no_std`.
//! 6. **Writes only when asked.** `new` and `load` never program or erase;
//!    only `save` does, and an erase stalls an STM32F405 for 2 s typical,
//!    4 s worst case, so the caller saves only on the explicit command.
//!
//! # Assumptions
//!
//! * NOR semantics: erase sets a whole erase unit to `0xFF`, a program can
//!   only clear bits. The store programs every word at most once between two
//!   erases of its sector (as [`NorFlash::write`] demands; tests check it).
//! * Geometry (checked at compile time): `WRITE_SIZE` and `READ_SIZE` divide
//!   4, `ERASE_SIZE` is a multiple of 4 and holds at least one full record
//!   ([`MAX_RECORD`] bytes). The store uses the first two erase units,
//!   flash offsets `0 .. 2·ERASE_SIZE`; a smaller flash is
//!   [`StoreError::Flash`].
//! * A cut during a program leaves the words of that program in any state
//!   between old and new (any subset of their 1→0 transitions) and no other
//!   word changed; a cut during an erase leaves that erase unit in any
//!   state. After power returns, cells read the same every time (marginally
//!   programmed cells are not modelled: should one flip later, the record
//!   holding it fails its CRC and `load` falls back to the previous record —
//!   still never a mix).
//! * Garbage is recognised with high probability, not certainty: to pass as
//!   a record it needs the magic, a matching header CRC-32, a matching
//!   record CRC-32 and the commit word.
//! * Sequence numbers are `u32` and wrap; records are ordered by serial
//!   number arithmetic (RFC 1982), which is exact while all records in the
//!   two sectors are within 2³¹ saves of each other — always true for
//!   records this store wrote, as two sectors hold far fewer records than
//!   that. Intact records with sequence numbers all over the circle can only
//!   be forged: then which one `load` returns is arbitrary (it is still one
//!   intact record, and nothing panics).
//!
//! # Record format (all integers little-endian)
//!
//! | offset      | bytes | field                                            |
//! |-------------|-------|--------------------------------------------------|
//! | 0           | 4     | magic `"SBST"`                                   |
//! | 4           | 2     | format version ([`FORMAT_VERSION`])              |
//! | 6           | 2     | payload length `n`                               |
//! | 8           | 4     | sequence number (+1 per save)                    |
//! | 12          | 4     | header CRC: CRC-32 of bytes 0..12                |
//! | 16          | n     | payload (the settings image)                     |
//! | 16+n        | p     | zero padding to a multiple of 4                  |
//! | 16+n+p      | 4     | record CRC: CRC-32 of bytes 0..16+n+p            |
//! | 20+n+p      | 4     | commit word `"DONE"`                             |
//!
//! A record takes [`record_size`]`(n)` = 24 + n + p bytes, at most
//! [`MAX_RECORD`] = 1560; records follow each other without gaps from the
//! start of a sector. The header CRC makes the length trustworthy, so a
//! scan can step over a record whose payload is bad. A record is *intact*
//! when both CRCs and the commit word match; it is *loadable* when it is
//! intact, of [`FORMAT_VERSION`] and at most [`MAX_IMAGE`] long. Records of
//! another version are never loaded, but their sequence numbers count, so
//! the next save is newer than anything in flash.
//!
//! A save programs, in this order: (1) the header, (2) the payload's whole
//! words, (3) the last payload bytes with padding and the record CRC, (4)
//! the commit word. Before (1), if the record does not fit in the free
//! space of the active sector, the store erases the *other* sector (E) and
//! writes the record at its start.
//!
//! # Reading a sector; where the next record goes
//!
//! A scan walks a sector from offset 0. A framed record (magic, valid
//! header CRC, fits in the sector) is stepped over by its length, intact or
//! not. Anything else that is not erased is garbage: the scan steps one word
//! and looks for a header again, so a damaged header does not hide the
//! records after it. The scan ends where the rest of the sector is erased.
//!
//! The next record is appended at that point if the sector held no
//! garbage; a sector with garbage is *closed*: nothing more is programmed
//! into it, the next save moves to the other sector. The store thus never
//! programs over anything a torn program might have touched: a torn record
//! with an intact header is stepped over, one with a torn header closes the
//! sector.
//!
//! The active sector is the one holding the newest loadable record (if
//! none, the newest intact record; if none, the first save erases sector
//! 0). The other sector therefore never holds the newest loadable record,
//! which is why erasing it (E) is safe.
//!
//! # Crash points
//!
//! | cut during                     | flash afterwards                         | next `load` |
//! |--------------------------------|------------------------------------------|-------------|
//! | E (erase other sector)         | other sector: any mix of old records, `0xFF` and noise; active sector untouched | old |
//! | after E, before (1)            | other sector erased                      | old |
//! | (1) header                     | no bit cleared: still erased, the next record goes there; part of it: garbage, sector closed; all of it: framed record, stepped over | old |
//! | (2), (3) payload, CRC          | framed record, CRC or commit missing     | old |
//! | (4) commit word                | commit incomplete → not intact; complete → intact | old or new |
//! | after (4)                      | record intact (even if `save` reported the cut) | new |
//!
//! "Old" is always there: it sits in the active sector, which no operation
//! of the save touches except by programming erased words after it, or in
//! the sector that stays untouched while the other is erased. A first save
//! on a store with no loadable record may leave `Empty` or `Corrupt` when
//! cut — there is no old image to keep.
//!
//! # Cost
//!
//! `load` (and the first `save` after `new` or after an error) reads both
//! sectors in full and computes the CRC of every record: on the STM32F405
//! about 256 KiB of memory-mapped reads. A save reads back the record it
//! wrote (and, after an erase, the erased sector) to verify it.

#![cfg_attr(not(test), no_std)]
// Tests are not bus input: they may index, unwrap and panic.
#![cfg_attr(test, allow(clippy::indexing_slicing, clippy::arithmetic_side_effects))]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

use crc::{Crc, CRC_32_ISO_HDLC};
use embedded_storage::nor_flash::NorFlash;

/// Largest settings image the store accepts.
pub const MAX_IMAGE: usize = 1536;
/// Record format version written by this store, the only one it loads.
pub const FORMAT_VERSION: u16 = 1;
/// Bytes of a record around its payload: 16 header, 4 CRC, 4 commit word.
pub const RECORD_OVERHEAD: usize = HEADER_LEN + 2 * WORD;
/// Bytes of the largest record (a [`MAX_IMAGE`] payload).
pub const MAX_RECORD: usize = record_size(MAX_IMAGE);

const MAGIC: [u8; 4] = *b"SBST";
const COMMIT: [u8; 4] = *b"DONE";
const HEADER_LEN: usize = 16;
const WORD: usize = 4;
const ERASED_WORD: [u8; WORD] = [0xFF; WORD];
/// Sectors the store uses.
const SECTORS: usize = 2;
/// Read buffer for CRCs and erased checks.
const CHUNK: usize = 64;

static CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// Bytes a record with an `n`-byte payload takes in flash (24 + `n`
/// rounded up to a multiple of 4).
pub const fn record_size(n: usize) -> usize {
    padded(n).saturating_add(RECORD_OVERHEAD)
}

/// `n` rounded up to a multiple of [`WORD`] (saturating).
const fn padded(n: usize) -> usize {
    n.saturating_add(WORD - 1) & !(WORD - 1)
}

/// Why a load or save did not happen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// Both sectors are completely erased: nothing was ever saved
    /// (factory-fresh).
    Empty,
    /// The sectors hold data but no loadable record: garbage, torn or
    /// damaged records, or only records of another format version.
    Corrupt,
    /// `save`: the image is longer than [`MAX_IMAGE`]. `load`: `out` is
    /// shorter than the stored image (nothing is copied).
    TooLarge,
    /// The flash driver reported an error, the flash is smaller than two
    /// erase units, or a record or erase read back differently from what was
    /// written.
    Flash,
}

/// What the store has done since [`Store::new`], and where it stands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StoreStats {
    /// Saves that returned `Ok`.
    pub saves: u32,
    /// Sector erases that returned `Ok`.
    pub erases: u32,
    /// The sector the next record goes to or after (0 or 1); `None` before
    /// the first `load`/`save`, after an error, or when no record exists.
    pub sector: Option<u8>,
    /// Bytes of that sector in use (the whole sector when it is closed).
    pub used: u32,
}

/// The settings store on a NOR flash. See the [module docs](self).
#[derive(Clone, Debug)]
pub struct Store<F: NorFlash> {
    flash: F,
    /// Where things stand, known after a scan; `None` until then and after
    /// any error (the next operation scans again).
    mount: Option<Mount>,
    saves: u32,
    erases: u32,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Mount {
    head: Head,
    /// Sequence number of the next record.
    next_seq: u32,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Head {
    /// No intact record anywhere: the next save erases sector 0.
    Blank,
    /// Records go to `sector`, at `free`; `None` when the sector is closed
    /// (the next save moves to the other sector).
    Active { sector: usize, free: Option<usize> },
}

/// `a + b` for offsets that are bounded by the sector size; overflow would
/// mean a bug, reported as a flash error rather than a panic.
fn add(a: usize, b: usize) -> Result<usize, StoreError> {
    a.checked_add(b).ok_or(StoreError::Flash)
}

fn sub(a: usize, b: usize) -> Result<usize, StoreError> {
    a.checked_sub(b).ok_or(StoreError::Flash)
}

fn flash_err<E>(_: E) -> StoreError {
    StoreError::Flash
}

impl<F: NorFlash> Store<F> {
    /// Size of one sector (one erase unit).
    const SECTOR: usize = F::ERASE_SIZE;

    const GEOMETRY_OK: () = assert!(
        F::ERASE_SIZE >= MAX_RECORD
            && F::ERASE_SIZE % WORD == 0
            && F::ERASE_SIZE <= (u32::MAX / 2) as usize
            && F::WRITE_SIZE > 0
            && WORD % F::WRITE_SIZE == 0
            && F::READ_SIZE > 0
            && WORD % F::READ_SIZE == 0,
        "persist::Store needs WRITE_SIZE and READ_SIZE dividing 4 and \
         MAX_RECORD <= ERASE_SIZE <= 2 GiB, a multiple of 4"
    );

    /// A store on `flash`. Touches no flash: call [`Store::load`] at boot.
    pub fn new(flash: F) -> Self {
        let () = Self::GEOMETRY_OK;
        Store {
            flash,
            mount: None,
            saves: 0,
            erases: 0,
        }
    }

    pub fn flash(&self) -> &F {
        &self.flash
    }

    /// The flash, for whatever the caller needs; the store scans again
    /// before its next save, in case the content was changed.
    pub fn flash_mut(&mut self) -> &mut F {
        self.mount = None;
        &mut self.flash
    }

    pub fn into_inner(self) -> F {
        self.flash
    }

    pub fn stats(&self) -> StoreStats {
        let (sector, used) = match self.mount.map(|m| m.head) {
            Some(Head::Active { sector, free }) => {
                (u8::try_from(sector).ok(), free.unwrap_or(Self::SECTOR))
            }
            _ => (None, 0),
        };
        StoreStats {
            saves: self.saves,
            erases: self.erases,
            sector,
            used: u32::try_from(used).unwrap_or(u32::MAX),
        }
    }

    /// Copies the newest loadable image into `out` and returns its length.
    /// Scans both sectors (no writes) and remembers where the next save
    /// goes, also when it returns `Empty` or `Corrupt`.
    pub fn load(&mut self, out: &mut [u8]) -> Result<usize, StoreError> {
        self.mount = None;
        let (mount, newest, blank) = self.scan_all()?;
        self.mount = Some(mount);
        let Some(found) = newest else {
            return Err(if blank {
                StoreError::Empty
            } else {
                StoreError::Corrupt
            });
        };
        let dst = out
            .get_mut(..found.header.payload_len())
            .ok_or(StoreError::TooLarge)?;
        if let Err(e) = self.read_payload(found, dst) {
            self.mount = None;
            return Err(e);
        }
        Ok(found.header.payload_len())
    }

    /// Stores `image` as the newest record: appended to the active sector,
    /// or, when it does not fit there, at the start of the other sector
    /// after erasing it. Returns `Ok` only once the record reads back
    /// intact.
    pub fn save(&mut self, image: &[u8]) -> Result<(), StoreError> {
        let len = u16::try_from(image.len())
            .ok()
            .filter(|_| image.len() <= MAX_IMAGE)
            .ok_or(StoreError::TooLarge)?;
        let mount = match self.mount.take() {
            Some(m) => m,
            None => self.scan_all()?.0,
        };
        // From here on `self.mount` stays `None` until the record is verified,
        // so that any error makes the next operation scan again.
        let size = record_size(image.len());
        let (sector, offset, erase) = match mount.head {
            Head::Active {
                sector,
                free: Some(free),
            } if free
                .checked_add(size)
                .is_some_and(|end| end <= Self::SECTOR) =>
            {
                (sector, free, false)
            }
            Head::Active { sector, .. } => (sub(1, sector)?, 0, true),
            Head::Blank => (0, 0, true),
        };
        if erase {
            self.erase_sector(sector)?;
        }
        let header = Header {
            version: FORMAT_VERSION,
            len,
            seq: mount.next_seq,
        };
        self.write_record(sector, offset, header, image)?;
        match self.frame_at(sector, offset)? {
            Some((h, true)) if h == header => {}
            _ => return Err(StoreError::Flash),
        }
        self.mount = Some(Mount {
            head: Head::Active {
                sector,
                free: Some(add(offset, size)?),
            },
            next_seq: header.seq.wrapping_add(1),
        });
        self.saves = self.saves.saturating_add(1);
        Ok(())
    }
}

mod format;
mod scan;
/// The simulated NOR flash with power cuts (tests; feature `sim` for
/// host-tests and the QEMU image).
#[cfg(any(test, feature = "sim"))]
pub mod sim;
#[cfg(test)]
mod tests;
mod write;

use format::Header;
use scan::Found;
