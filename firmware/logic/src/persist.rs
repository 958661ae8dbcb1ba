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
//!    `ERASE_SIZE / record size` saves (≥ 125 saves of a full image per
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
//! [`MAX_RECORD`] = 1048; records follow each other without gaps from the
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

#![deny(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::unreachable,
    clippy::todo,
    clippy::unimplemented
)]

use crc::{Crc, CRC_32_ISO_HDLC};
use embedded_storage::nor_flash::NorFlash;

/// Largest settings image the store accepts.
pub const MAX_IMAGE: usize = 1024;
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

/// The decoded, CRC-checked header of a framed record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Header {
    version: u16,
    len: u16,
    seq: u32,
}

impl Header {
    fn encode(&self) -> [u8; HEADER_LEN] {
        let [m0, m1, m2, m3] = MAGIC;
        let [v0, v1] = self.version.to_le_bytes();
        let [l0, l1] = self.len.to_le_bytes();
        let [s0, s1, s2, s3] = self.seq.to_le_bytes();
        let head = [m0, m1, m2, m3, v0, v1, l0, l1, s0, s1, s2, s3];
        let [c0, c1, c2, c3] = CRC32.checksum(&head).to_le_bytes();
        [
            m0, m1, m2, m3, v0, v1, l0, l1, s0, s1, s2, s3, c0, c1, c2, c3,
        ]
    }

    /// The header in `h`, if its magic and header CRC match.
    fn decode(h: &[u8; HEADER_LEN]) -> Option<Header> {
        let [m0, m1, m2, m3, v0, v1, l0, l1, s0, s1, s2, s3, c0, c1, c2, c3] = *h;
        let head = [m0, m1, m2, m3, v0, v1, l0, l1, s0, s1, s2, s3];
        let ok = [m0, m1, m2, m3] == MAGIC
            && CRC32.checksum(&head) == u32::from_le_bytes([c0, c1, c2, c3]);
        ok.then_some(Header {
            version: u16::from_le_bytes([v0, v1]),
            len: u16::from_le_bytes([l0, l1]),
            seq: u32::from_le_bytes([s0, s1, s2, s3]),
        })
    }

    fn payload_len(&self) -> usize {
        usize::from(self.len)
    }

    fn loadable(&self) -> bool {
        self.version == FORMAT_VERSION && self.payload_len() <= MAX_IMAGE
    }
}

/// An intact record found by a scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Found {
    sector: usize,
    offset: usize,
    header: Header,
}

/// What one sector holds.
#[derive(Clone, Copy, Debug)]
struct SectorScan {
    newest_loadable: Option<Found>,
    newest_intact: Option<Found>,
    /// Start of the erased rest of the sector.
    tail: usize,
    /// Something that is neither a framed record nor erased was seen.
    garbage: bool,
}

impl SectorScan {
    fn blank(&self) -> bool {
        self.tail == 0 && !self.garbage
    }
}

/// `a` is newer than `b` in serial-number order.
fn newer(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

/// The newer of `best` and `candidate`; a tie goes to `candidate` (found
/// later).
fn pick(best: Option<Found>, candidate: Option<Found>) -> Option<Found> {
    match (best, candidate) {
        (Some(b), Some(c)) if newer(b.header.seq, c.header.seq) => Some(b),
        (b, None) => b,
        (_, c) => c,
    }
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

    // ----------------------------------------------------------- flash access

    /// Flash offset of `offset` in `sector`.
    fn address(sector: usize, offset: usize) -> Result<u32, StoreError> {
        let at = sector
            .checked_mul(Self::SECTOR)
            .and_then(|base| base.checked_add(offset))
            .ok_or(StoreError::Flash)?;
        u32::try_from(at).map_err(flash_err)
    }

    fn read(&mut self, sector: usize, offset: usize, buf: &mut [u8]) -> Result<(), StoreError> {
        if sector >= SECTORS || add(offset, buf.len())? > Self::SECTOR {
            return Err(StoreError::Flash);
        }
        let at = Self::address(sector, offset)?;
        self.flash.read(at, buf).map_err(flash_err)
    }

    fn write(&mut self, sector: usize, offset: usize, bytes: &[u8]) -> Result<(), StoreError> {
        if sector >= SECTORS || add(offset, bytes.len())? > Self::SECTOR {
            return Err(StoreError::Flash);
        }
        let at = Self::address(sector, offset)?;
        self.flash.write(at, bytes).map_err(flash_err)
    }

    fn erase_sector(&mut self, sector: usize) -> Result<(), StoreError> {
        let from = Self::address(sector, 0)?;
        let to = Self::address(sector, Self::SECTOR)?;
        self.flash.erase(from, to).map_err(flash_err)?;
        self.erases = self.erases.saturating_add(1);
        if self.first_not_erased(sector, 0)?.is_some() {
            return Err(StoreError::Flash);
        }
        Ok(())
    }

    /// Offset of the first byte at or after `from` in `sector` that is not
    /// `0xFF`, if any.
    fn first_not_erased(
        &mut self,
        sector: usize,
        from: usize,
    ) -> Result<Option<usize>, StoreError> {
        let mut buf = [0u8; CHUNK];
        let mut at = from;
        while at < Self::SECTOR {
            let n = CHUNK.min(sub(Self::SECTOR, at)?);
            let chunk = buf.get_mut(..n).ok_or(StoreError::Flash)?;
            self.read(sector, at, chunk)?;
            if let Some(i) = chunk.iter().position(|&b| b != 0xFF) {
                return Ok(Some(add(at, i)?));
            }
            at = add(at, n)?;
        }
        Ok(None)
    }

    // --------------------------------------------------------------- records

    /// Programs a record in the order the module docs give.
    fn write_record(
        &mut self,
        sector: usize,
        offset: usize,
        header: Header,
        image: &[u8],
    ) -> Result<(), StoreError> {
        let head = header.encode();
        let whole = image.len() & !(WORD - 1);
        let (words, rest) = image.split_at_checked(whole).ok_or(StoreError::Flash)?;
        // Last bytes, zero padding, record CRC: at most 3 + 1 + 4 bytes.
        let mut last = [0u8; 2 * WORD];
        let rest_padded = padded(rest.len());
        let mut crc = CRC32.digest();
        crc.update(&head);
        crc.update(image);
        crc.update(
            [0u8; WORD]
                .get(..sub(rest_padded, rest.len())?)
                .ok_or(StoreError::Flash)?,
        );
        last.get_mut(..rest.len())
            .ok_or(StoreError::Flash)?
            .copy_from_slice(rest);
        last.get_mut(rest_padded..add(rest_padded, WORD)?)
            .ok_or(StoreError::Flash)?
            .copy_from_slice(&crc.finalize().to_le_bytes());
        let last = last
            .get(..add(rest_padded, WORD)?)
            .ok_or(StoreError::Flash)?;

        let payload_at = add(offset, HEADER_LEN)?;
        let last_at = add(payload_at, whole)?;
        let commit_at = add(last_at, last.len())?;
        self.write(sector, offset, &head)?; // (1)
        if !words.is_empty() {
            self.write(sector, payload_at, words)?; // (2)
        }
        self.write(sector, last_at, last)?; // (3)
        self.write(sector, commit_at, &COMMIT) // (4)
    }

    /// The framed record at `offset`: its header and whether it is intact.
    /// `None` when there is no framed record there (erased or garbage).
    fn frame_at(
        &mut self,
        sector: usize,
        offset: usize,
    ) -> Result<Option<(Header, bool)>, StoreError> {
        let mut h = [0u8; HEADER_LEN];
        self.read(sector, offset, &mut h)?;
        let Some(header) = Header::decode(&h) else {
            return Ok(None);
        };
        let fits = offset
            .checked_add(record_size(header.payload_len()))
            .is_some_and(|end| end <= Self::SECTOR);
        if !fits {
            return Ok(None);
        }
        let intact = self.intact(sector, offset, &h, header)?;
        Ok(Some((header, intact)))
    }

    /// Record CRC and commit word of the framed record at `offset`.
    fn intact(
        &mut self,
        sector: usize,
        offset: usize,
        h: &[u8; HEADER_LEN],
        header: Header,
    ) -> Result<bool, StoreError> {
        let mut crc = CRC32.digest();
        crc.update(h);
        let mut buf = [0u8; CHUNK];
        let mut at = add(offset, HEADER_LEN)?;
        let end = add(at, padded(header.payload_len()))?;
        while at < end {
            let n = CHUNK.min(sub(end, at)?);
            let chunk = buf.get_mut(..n).ok_or(StoreError::Flash)?;
            self.read(sector, at, chunk)?;
            crc.update(chunk);
            at = add(at, n)?;
        }
        let mut tail = [0u8; 2 * WORD];
        self.read(sector, end, &mut tail)?;
        let [c0, c1, c2, c3, k0, k1, k2, k3] = tail;
        Ok(u32::from_le_bytes([c0, c1, c2, c3]) == crc.finalize() && [k0, k1, k2, k3] == COMMIT)
    }

    /// Copies the payload of `found` into `dst` (exactly its length) and
    /// checks the record CRC again over what was copied.
    fn read_payload(&mut self, found: Found, dst: &mut [u8]) -> Result<(), StoreError> {
        let Found {
            sector,
            offset,
            header,
        } = found;
        let len = header.payload_len();
        let whole = len & !(WORD - 1);
        let payload_at = add(offset, HEADER_LEN)?;
        let (words, rest) = dst.split_at_mut_checked(whole).ok_or(StoreError::Flash)?;
        self.read(sector, payload_at, words)?;
        let mut last = [0u8; 2 * WORD];
        let rest_padded = padded(rest.len());
        let last = last
            .get_mut(..add(rest_padded, WORD)?)
            .ok_or(StoreError::Flash)?;
        self.read(sector, add(payload_at, whole)?, last)?;
        let (tail, stored) = last
            .split_at_checked(rest_padded)
            .ok_or(StoreError::Flash)?;
        let (got, pad) = tail.split_at_checked(rest.len()).ok_or(StoreError::Flash)?;
        rest.copy_from_slice(got);
        let mut crc = CRC32.digest();
        crc.update(&header.encode());
        crc.update(dst);
        crc.update(pad);
        let stored: [u8; WORD] = stored.try_into().map_err(flash_err)?;
        if crc.finalize() == u32::from_le_bytes(stored) {
            Ok(())
        } else {
            Err(StoreError::Flash)
        }
    }

    // ------------------------------------------------------------------ scan

    fn scan_sector(&mut self, sector: usize) -> Result<SectorScan, StoreError> {
        let mut scan = SectorScan {
            newest_loadable: None,
            newest_intact: None,
            tail: Self::SECTOR,
            garbage: false,
        };
        let mut pos = 0usize;
        while pos < Self::SECTOR {
            let framed = if add(pos, HEADER_LEN)? <= Self::SECTOR {
                self.frame_at(sector, pos)?
            } else {
                None
            };
            if let Some((header, intact)) = framed {
                if intact {
                    let found = Some(Found {
                        sector,
                        offset: pos,
                        header,
                    });
                    scan.newest_intact = pick(scan.newest_intact, found);
                    if header.loadable() {
                        scan.newest_loadable = pick(scan.newest_loadable, found);
                    }
                }
                pos = add(pos, record_size(header.payload_len()))?;
                continue;
            }
            let mut word = [0u8; WORD];
            self.read(sector, pos, &mut word)?;
            if word != ERASED_WORD {
                // Garbage: look for a header one word further.
                scan.garbage = true;
                pos = add(pos, WORD)?;
                continue;
            }
            match self.first_not_erased(sector, pos)? {
                None => {
                    scan.tail = pos;
                    break;
                }
                // Erased up to `at`; no header can start in an erased word.
                Some(at) => pos = at & !(WORD - 1),
            }
        }
        Ok(scan)
    }

    /// Scans both sectors: the mount state, the newest loadable record, and
    /// whether the flash is completely erased.
    fn scan_all(&mut self) -> Result<(Mount, Option<Found>, bool), StoreError> {
        let needed = Self::SECTOR.checked_mul(SECTORS).ok_or(StoreError::Flash)?;
        if self.flash.capacity() < needed {
            return Err(StoreError::Flash);
        }
        let scans = [self.scan_sector(0)?, self.scan_sector(1)?];
        let [a, b] = scans;
        let loadable = pick(a.newest_loadable, b.newest_loadable);
        let intact = pick(a.newest_intact, b.newest_intact);
        let head = match loadable.or(intact) {
            Some(found) => {
                let s = scans.get(found.sector).ok_or(StoreError::Flash)?;
                Head::Active {
                    sector: found.sector,
                    free: (!s.garbage).then_some(s.tail),
                }
            }
            None => Head::Blank,
        };
        let next_seq = intact.map_or(1, |f| f.header.seq.wrapping_add(1));
        let mount = Mount { head, next_seq };
        Ok((mount, loadable, a.blank() && b.blank()))
    }
}

#[cfg(test)]
#[allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic
)]
mod tests {
    use embedded_storage::nor_flash::{ErrorType, ReadNorFlash};

    use super::*;
    use crate::sim::flash::{SimFlash, SimFlashError, SplitMix64};

    /// Small sectors (3 full records each) so that moves happen often.
    const S: usize = 4096;
    type Flash = SimFlash<S, 2>;

    fn fresh() -> Store<Flash> {
        Store::new(Flash::new())
    }

    fn load<F: NorFlash>(store: &mut Store<F>) -> Result<Vec<u8>, StoreError> {
        let mut out = [0u8; MAX_IMAGE];
        let n = store.load(&mut out)?;
        Ok(out[..n].to_vec())
    }

    /// A fresh store mounted on `flash` (what a reboot does).
    fn reboot<F: NorFlash>(store: Store<F>) -> Store<F> {
        Store::new(store.into_inner())
    }

    fn image(rng: &mut SplitMix64, len: usize) -> Vec<u8> {
        let mut v = vec![0; len];
        rng.fill(&mut v);
        v
    }

    fn random_image(rng: &mut SplitMix64) -> Vec<u8> {
        let len = rng.range(1, MAX_IMAGE);
        image(rng, len)
    }

    /// The bytes of a record as the store writes it.
    fn raw_record(version: u16, seq: u32, payload: &[u8]) -> Vec<u8> {
        let header = Header {
            version,
            len: payload.len() as u16,
            seq,
        };
        let mut r = header.encode().to_vec();
        r.extend_from_slice(payload);
        r.resize(HEADER_LEN + padded(payload.len()), 0);
        let crc = CRC32.checksum(&r);
        r.extend_from_slice(&crc.to_le_bytes());
        r.extend_from_slice(&COMMIT);
        assert_eq!(r.len(), record_size(payload.len()));
        r
    }

    fn put<const N: usize>(flash: &mut SimFlash<N, 2>, sector: usize, offset: usize, bytes: &[u8]) {
        flash.sectors_mut()[sector][offset..offset + bytes.len()].copy_from_slice(bytes);
    }

    // ------------------------------------------------------------ basics

    #[test]
    fn save_then_load_returns_the_image() {
        let mut store = fresh();
        store.save(b"axis settings").unwrap();
        assert_eq!(load(&mut store).unwrap(), b"axis settings");
        assert_eq!(load(&mut reboot(store)).unwrap(), b"axis settings");
    }

    #[test]
    fn empty_and_full_size_images_round_trip() {
        let mut rng = SplitMix64::new(1);
        for len in [0, 1, 2, 3, 4, 5, MAX_IMAGE - 1, MAX_IMAGE] {
            let img = image(&mut rng, len);
            let mut store = fresh();
            store.save(&img).unwrap();
            assert_eq!(load(&mut reboot(store)).unwrap(), img, "len {len}");
        }
    }

    #[test]
    fn newest_save_wins_also_after_a_reboot() {
        let mut store = fresh();
        for v in [&b"one"[..], b"two", b"three"] {
            store.save(v).unwrap();
            assert_eq!(load(&mut store).unwrap(), v);
        }
        assert_eq!(load(&mut reboot(store)).unwrap(), b"three");
    }

    #[test]
    fn erased_flash_loads_as_empty() {
        assert_eq!(load(&mut fresh()), Err(StoreError::Empty));
    }

    #[test]
    fn random_garbage_loads_as_corrupt() {
        let mut flash = Flash::new();
        let mut rng = SplitMix64::new(2);
        for sector in flash.sectors_mut() {
            rng.fill(sector);
        }
        assert_eq!(load(&mut Store::new(flash)), Err(StoreError::Corrupt));
    }

    #[test]
    fn zeroed_flash_loads_as_corrupt() {
        let mut flash = Flash::new();
        flash.sectors_mut()[1].fill(0);
        assert_eq!(load(&mut Store::new(flash)), Err(StoreError::Corrupt));
    }

    #[test]
    fn one_stray_byte_makes_the_flash_corrupt_not_empty() {
        let mut flash = Flash::new();
        flash.sectors_mut()[1][S - 1] = 0xFE;
        assert_eq!(load(&mut Store::new(flash)), Err(StoreError::Corrupt));
    }

    #[test]
    fn image_over_max_is_too_large_and_touches_nothing() {
        let mut store = fresh();
        assert_eq!(store.save(&[0; MAX_IMAGE + 1]), Err(StoreError::TooLarge));
        assert_eq!(store.flash().ops(), 0);
        assert_eq!(store.flash().counters().reads, 0);
    }

    #[test]
    fn output_shorter_than_the_image_is_too_large() {
        let mut store = fresh();
        store.save(&[7; 100]).unwrap();
        let mut out = [0; 99];
        assert_eq!(store.load(&mut out), Err(StoreError::TooLarge));
        assert_eq!(out, [0; 99], "nothing copied");
        let mut out = [0; 100];
        assert_eq!(store.load(&mut out), Ok(100));
    }

    #[test]
    fn new_and_load_never_program_or_erase() {
        let mut store = fresh();
        for i in 0..20u8 {
            store.save(&[i; 700]).unwrap();
        }
        let flash = store.into_inner();
        let ops = flash.ops();
        let mut store = Store::new(flash);
        assert_eq!(store.flash().counters().reads, flash_reads_before(&store));
        load(&mut store).unwrap();
        assert_eq!(store.flash().ops(), ops);

        fn flash_reads_before(s: &Store<Flash>) -> u64 {
            s.flash().counters().reads
        }
    }

    #[test]
    fn save_without_load_scans_first_and_appends() {
        let mut store = fresh();
        store.save(b"first").unwrap();
        let mut store = reboot(store);
        store.save(b"second").unwrap();
        assert_eq!(store.stats().erases, 0, "appended, no erase");
        assert_eq!(load(&mut store).unwrap(), b"second");
    }

    // ---------------------------------------------------------- integrity

    #[test]
    fn record_with_bad_crc_is_skipped() {
        let mut store = fresh();
        for v in [&b"aaaa"[..], b"bbbb", b"cccc"] {
            store.save(v).unwrap();
        }
        let r = record_size(4);
        let mut flash = store.into_inner();
        // Newest record damaged: the one before it is the newest loadable.
        flash.sectors_mut()[0][2 * r + HEADER_LEN] ^= 0x01;
        assert_eq!(load(&mut Store::new(flash.clone())).unwrap(), b"bbbb");
        // A damaged record in the middle does not hide the newest.
        flash.sectors_mut()[0][2 * r + HEADER_LEN] ^= 0x01;
        flash.sectors_mut()[0][r + HEADER_LEN + 4] ^= 0x80; // its CRC
        assert_eq!(load(&mut Store::new(flash)).unwrap(), b"cccc");
    }

    #[test]
    fn record_without_commit_word_is_skipped() {
        let mut flash = Flash::new();
        let a = raw_record(FORMAT_VERSION, 1, b"old");
        let mut b = raw_record(FORMAT_VERSION, 2, b"new");
        let n = b.len();
        b[n - 4..].fill(0xFF);
        put(&mut flash, 0, 0, &a);
        put(&mut flash, 0, a.len(), &b);
        assert_eq!(load(&mut Store::new(flash)).unwrap(), b"old");
    }

    #[test]
    fn damaged_header_does_not_hide_later_records() {
        let mut store = fresh();
        for v in [&b"aaaa"[..], b"bbbb", b"cccc"] {
            store.save(v).unwrap();
        }
        let r = record_size(4);
        let mut flash = store.into_inner();
        flash.sectors_mut()[0][r + 6] ^= 0x04; // length field of "bbbb"
        assert_eq!(load(&mut Store::new(flash)).unwrap(), b"cccc");
    }

    #[test]
    fn record_of_unknown_version_is_not_loaded() {
        let mut flash = Flash::new();
        let old = raw_record(FORMAT_VERSION, 1, b"v1 settings");
        let newer = raw_record(FORMAT_VERSION + 1, 2, b"v2 settings");
        put(&mut flash, 0, 0, &old);
        put(&mut flash, 0, old.len(), &newer);
        assert_eq!(load(&mut Store::new(flash)).unwrap(), b"v1 settings");
    }

    #[test]
    fn only_unknown_versions_load_as_corrupt() {
        let mut flash = Flash::new();
        put(&mut flash, 1, 0, &raw_record(0, 5, b"v0"));
        put(&mut flash, 1, 64, &raw_record(2, 6, b"v2"));
        assert_eq!(load(&mut Store::new(flash)), Err(StoreError::Corrupt));
    }

    #[test]
    fn save_after_unknown_version_is_newer_than_it() {
        let mut flash = Flash::new();
        put(
            &mut flash,
            1,
            0,
            &raw_record(FORMAT_VERSION + 1, 1000, b"v2"),
        );
        let mut store = Store::new(flash);
        store.save(b"v1 again").unwrap();
        let mount = store.mount.unwrap();
        assert_eq!(mount.next_seq, 1002, "saved with sequence 1001");
        assert_eq!(
            mount.head,
            Head::Active {
                sector: 1,
                free: Some(record_size(2) + record_size(8))
            },
            "appended after the v2 record, in its sector"
        );
        assert_eq!(load(&mut reboot(store)).unwrap(), b"v1 again");
    }

    #[test]
    fn sequence_numbers_wrap_and_the_newest_still_wins() {
        let mut flash = Flash::new();
        put(
            &mut flash,
            0,
            0,
            &raw_record(FORMAT_VERSION, u32::MAX - 20, &[9; 1000]),
        );
        put(
            &mut flash,
            1,
            0,
            &raw_record(FORMAT_VERSION, u32::MAX - 2, &[0; 1000]),
        );
        let mut store = Store::new(flash);
        assert_eq!(load(&mut store).unwrap(), [0; 1000]);
        for i in 1..=12u8 {
            store.save(&[i; 1000]).unwrap();
            assert_eq!(load(&mut store).unwrap(), [i; 1000]);
            store = reboot(store);
        }
        // 3 appends after u32::MAX - 2, then moves at sequences 1, 5 and 9.
        assert_eq!(store.flash().sector_erases(), &[2, 1]);
    }

    // --------------------------------------------------- where records go

    #[test]
    fn records_are_appended_until_the_sector_is_full_then_the_other_sector_is_used() {
        let r = record_size(1000); // 1024: four per 4 KiB sector
        let mut store = fresh();
        store.save(&[1; 1000]).unwrap();
        assert_eq!(
            store.flash().sector_erases(),
            &[1, 0],
            "first save erases sector 0"
        );
        for i in 2..=4u8 {
            store.save(&[i; 1000]).unwrap();
        }
        assert_eq!(
            store.flash().sector_erases(),
            &[1, 0],
            "appends erase nothing"
        );
        assert_eq!(store.stats().used as usize, 4 * r);
        store.save(&[5; 1000]).unwrap();
        assert_eq!(store.flash().sector_erases(), &[1, 1], "moved to sector 1");
        assert_eq!(store.stats().sector, Some(1));
        for i in 6..=8u8 {
            store.save(&[i; 1000]).unwrap();
        }
        assert_eq!(
            store.flash().sector_erases(),
            &[1, 1],
            "sector 0 kept until needed"
        );
        store.save(&[9; 1000]).unwrap();
        assert_eq!(
            store.flash().sector_erases(),
            &[2, 1],
            "moved back to sector 0"
        );
        assert_eq!(load(&mut reboot(store)).unwrap(), [9; 1000]);
    }

    #[test]
    fn garbage_after_the_last_record_closes_the_sector() {
        let mut store = fresh();
        store.save(b"kept").unwrap();
        let mut flash = store.into_inner();
        flash.sectors_mut()[0][S / 2] = 0x00;
        let mut store = Store::new(flash);
        assert_eq!(load(&mut store).unwrap(), b"kept");
        assert_eq!(store.stats().used as usize, S, "closed: counts as full");
        store.save(b"moved").unwrap();
        assert_eq!(store.flash().sector_erases(), &[1, 1]);
        assert_eq!(store.stats().sector, Some(1));
        assert_eq!(store.flash().counters().overwrites, 0);
        assert_eq!(load(&mut reboot(store)).unwrap(), b"moved");
    }

    #[test]
    fn torn_record_with_intact_header_is_stepped_over() {
        let mut store = fresh();
        store.save(b"old").unwrap();
        let before = store.flash().ops();
        // Ops of the next save: header, payload words, tail+CRC, commit.
        store.flash_mut().cut_power_at(before + 1, 3);
        assert_eq!(store.save(&[5; 200]), Err(StoreError::Flash));
        let mut flash = store.into_inner();
        flash.restore_power();
        let mut store = Store::new(flash);
        assert_eq!(load(&mut store).unwrap(), b"old");
        assert_eq!(
            store.stats().used as usize,
            record_size(3) + record_size(200),
            "the next record goes after the torn one"
        );
        store.save(b"new").unwrap();
        assert_eq!(store.flash().sector_erases(), &[1, 0], "no move");
        assert_eq!(load(&mut reboot(store)).unwrap(), b"new");
    }

    #[test]
    fn stats_report_saves_erases_sector_and_usage() {
        let mut store = fresh();
        assert_eq!(store.stats(), StoreStats::default());
        store.save(&[0; 10]).unwrap();
        store.save(&[0; 20]).unwrap();
        assert_eq!(
            store.stats(),
            StoreStats {
                saves: 2,
                erases: 1,
                sector: Some(0),
                used: (record_size(10) + record_size(20)) as u32,
            }
        );
    }

    #[test]
    fn flash_mut_makes_the_store_scan_again() {
        let mut store = fresh();
        store.save(b"a").unwrap();
        store.flash_mut().sectors_mut()[0][40] = 0; // garbage after the record
        store.save(b"b").unwrap();
        assert_eq!(store.flash().counters().overwrites, 0);
        assert_eq!(store.stats().sector, Some(1), "saw the garbage and moved");
        assert_eq!(load(&mut store).unwrap(), b"b");
    }

    // ---------------------------------------------------- flash trouble

    #[test]
    fn flash_smaller_than_two_sectors_is_a_flash_error() {
        let mut store = Store::new(SimFlash::<S, 1>::new());
        assert_eq!(load(&mut store), Err(StoreError::Flash));
        assert_eq!(store.save(b"x"), Err(StoreError::Flash));
    }

    #[test]
    fn flash_errors_are_reported_and_the_store_recovers() {
        let mut store = fresh();
        store.save(b"before").unwrap();
        let ops = store.flash().ops();
        store.flash_mut().cut_power_at(ops, 0);
        assert_eq!(store.save(b"during"), Err(StoreError::Flash));
        assert_eq!(
            load(&mut store),
            Err(StoreError::Flash),
            "reads fail unpowered"
        );
        assert_eq!(store.stats().sector, None);
        store.flash_mut().restore_power();
        let got = load(&mut store).unwrap();
        assert!(got == b"before" || got == b"during");
        store.save(b"after").unwrap();
        assert_eq!(load(&mut store).unwrap(), b"after");
    }

    /// A flash that accepts programs and erases but does nothing (like
    /// QEMU's STM32F405, whose flash controller is not modelled).
    #[derive(Debug)]
    struct InertFlash(Flash);

    impl ErrorType for InertFlash {
        type Error = SimFlashError;
    }

    impl ReadNorFlash for InertFlash {
        const READ_SIZE: usize = 1;
        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), SimFlashError> {
            self.0.read(offset, bytes)
        }
        fn capacity(&self) -> usize {
            self.0.capacity()
        }
    }

    impl NorFlash for InertFlash {
        const WRITE_SIZE: usize = 4;
        const ERASE_SIZE: usize = S;
        fn erase(&mut self, _: u32, _: u32) -> Result<(), SimFlashError> {
            Ok(())
        }
        fn write(&mut self, _: u32, _: &[u8]) -> Result<(), SimFlashError> {
            Ok(())
        }
    }

    #[test]
    fn a_save_that_does_not_reach_the_flash_is_a_flash_error() {
        let mut store = Store::new(InertFlash(Flash::new()));
        assert_eq!(store.save(b"lost"), Err(StoreError::Flash));
        let mut garbage = Flash::new();
        garbage.sectors_mut()[0].fill(0x55);
        let mut store = Store::new(InertFlash(garbage));
        assert_eq!(
            store.save(b"lost"),
            Err(StoreError::Flash),
            "erase did not erase"
        );
    }

    // ---------------------------------------------------------- wear

    #[test]
    fn many_saves_wear_level_both_sectors() {
        let mut rng = SplitMix64::new(1000);
        let mut store = fresh();
        let mut bytes = 0;
        for i in 0..1000 {
            let img = random_image(&mut rng);
            bytes += record_size(img.len());
            store.save(&img).unwrap();
            assert_eq!(load(&mut store).unwrap(), img);
            if i % 50 == 0 {
                store = reboot(store);
            }
        }
        let [e0, e1] = *store.flash().sector_erases();
        let erases = (e0 + e1) as usize;
        // A move wastes less than one record at the end of a sector.
        let most = bytes.div_ceil(S - MAX_RECORD) + 1;
        let least = bytes / S;
        assert!(
            (least..=most).contains(&erases),
            "{erases} erases for {bytes} record bytes, expected {least}..={most}"
        );
        assert!(e0.abs_diff(e1) <= 1, "sectors alternate: {e0} / {e1}");
        assert_eq!(store.flash().counters().overwrites, 0);
    }

    #[test]
    fn device_geometry_erases_once_per_125_full_saves() {
        // STM32F405 sectors 10 and 11: 128 KiB each.
        let mut flash = Box::new(SimFlash::<{ 128 * 1024 }, 2>::new());
        let mut store = Store::new(&mut *flash);
        for i in 0..300u32 {
            store.save(&[i as u8; MAX_IMAGE]).unwrap();
        }
        assert_eq!((128 * 1024) / MAX_RECORD, 125);
        assert_eq!(store.stats().erases, 3, "saves 1, 126 and 251 erase");
        assert_eq!(load(&mut store).unwrap(), [43; MAX_IMAGE]);
    }

    // ------------------------------------------------------ power cuts

    /// Whether the load after a cut gave the old or the new image.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    enum Outcome {
        Old,
        New,
    }

    #[derive(Debug, Default)]
    struct Tally {
        cut_points: u64,
        old: u64,
        new: u64,
    }

    /// After a cut: power back, reboot, load. Asserts the image is exactly
    /// `old` (or nothing when there was none) or exactly `new`, then that a
    /// further save works and reads back, also after another reboot.
    fn recover<const N: usize>(
        mut flash: SimFlash<N, 2>,
        old: Option<&[u8]>,
        new: &[u8],
        rng: &mut SplitMix64,
    ) -> (Outcome, Store<SimFlash<N, 2>>) {
        flash.restore_power();
        let mut store = Store::new(flash);
        let got = load(&mut store);
        let outcome = match (&got, old) {
            (Ok(v), _) if v == new => Outcome::New,
            (Ok(v), Some(o)) if v == o => Outcome::Old,
            (Err(StoreError::Empty | StoreError::Corrupt), None) => Outcome::Old,
            _ => panic!(
                "after a cut: {:?} (len {:?}); old len {:?}, new len {}",
                got.as_ref().map(|v| v.first()),
                got.as_ref().map(Vec::len),
                old.map(<[u8]>::len),
                new.len()
            ),
        };
        let mut check = store.clone();
        let next = random_image(rng);
        check.save(&next).unwrap();
        assert_eq!(load(&mut check).unwrap(), next);
        let mut check = reboot(check);
        assert_eq!(load(&mut check).unwrap(), next);
        assert_eq!(
            check.flash().counters().overwrites,
            0,
            "a word programmed twice"
        );
        (outcome, store)
    }

    /// Runs `saves` random saves (sizes 1..=MAX_IMAGE) and, for every flash
    /// operation of every save, a branch where power is cut at exactly that
    /// operation. The main line itself gets cut now and then, and reboots
    /// now and then, so later cut points land on torn and dirty flash.
    fn campaign<const N: usize>(seed: u64, saves: usize, tally: &mut Tally) {
        let mut rng = SplitMix64::new(seed);
        let mut store = Store::new(SimFlash::<N, 2>::new());
        let mut last: Option<Vec<u8>> = None;
        for _ in 0..saves {
            let img = random_image(&mut rng);
            // The in-memory state must be what a scan finds, so that a
            // branch (which scans again) does exactly what the main line does.
            if let Some(m) = store.mount {
                let mut scan = Store::new(store.flash().clone());
                assert_eq!(scan.scan_all().unwrap().0, m);
            }
            let start = store.flash().ops();
            let mut done = store.clone();
            done.save(&img).unwrap();
            let ops = done.flash().ops() - start;
            assert!((3..=5).contains(&ops), "{ops} operations in one save");
            for k in 0..ops {
                let mut cut = store.clone();
                cut.flash_mut().cut_power_at(start + k, rng.next_u64());
                assert_eq!(cut.save(&img), Err(StoreError::Flash));
                let (outcome, _) = recover(cut.into_inner(), last.as_deref(), &img, &mut rng);
                tally.cut_points += 1;
                match outcome {
                    Outcome::Old => tally.old += 1,
                    Outcome::New => tally.new += 1,
                }
            }
            if rng.below(6) == 0 {
                // The main line loses power too and carries the torn state on.
                let mut cut = store;
                let k = rng.below(ops as usize) as u64;
                cut.flash_mut().cut_power_at(start + k, rng.next_u64());
                assert_eq!(cut.save(&img), Err(StoreError::Flash));
                let (outcome, s) = recover(cut.into_inner(), last.as_deref(), &img, &mut rng);
                if outcome == Outcome::New {
                    last = Some(img);
                }
                store = s;
            } else {
                store = done;
                last = Some(img);
            }
            if rng.below(8) == 0 {
                store = reboot(store);
            }
        }
    }

    #[test]
    fn power_cut_at_every_operation_leaves_old_or_new() {
        let mut tally = Tally::default();
        for seed in 0..30 {
            campaign::<4096>(seed, 80, &mut tally);
        }
        println!("power_cut_at_every_operation_leaves_old_or_new: {tally:?}");
        assert!(tally.cut_points > 9_000, "{tally:?}");
        assert!(
            tally.old > 0 && tally.new > 0,
            "both outcomes seen: {tally:?}"
        );
    }

    #[test]
    fn power_cut_with_one_full_record_per_sector_leaves_old_or_new() {
        let mut tally = Tally::default();
        for seed in 100..110 {
            campaign::<2048>(seed, 60, &mut tally);
        }
        println!("power_cut_with_one_full_record_per_sector_leaves_old_or_new: {tally:?}");
        assert!(tally.cut_points > 2_000, "{tally:?}");
        assert!(
            tally.old > 0 && tally.new > 0,
            "both outcomes seen: {tally:?}"
        );
    }

    /// Long run (a few minutes in the dev profile): `cargo test -p
    /// bridge-logic --features sim persist::tests::power_cut_long --
    /// --ignored --nocapture`.
    #[test]
    #[ignore = "long: millions of cut points"]
    fn power_cut_long_campaign() {
        let mut tally = Tally::default();
        for seed in 0..2_000 {
            campaign::<4096>(1_000_000 + seed, 200, &mut tally);
        }
        for seed in 0..500 {
            campaign::<2048>(2_000_000 + seed, 200, &mut tally);
        }
        for seed in 0..300 {
            campaign::<8192>(3_000_000 + seed, 300, &mut tally);
        }
        println!("power_cut_long_campaign: {tally:?}");
    }

    #[test]
    fn torn_erase_of_the_next_sector_keeps_the_latest() {
        for seed in 0..50 {
            let mut store = fresh();
            for i in 0..4u8 {
                store.save(&[i; 1000]).unwrap(); // sector 0 full
            }
            let ops = store.flash().ops();
            store.flash_mut().cut_power_at(ops, seed); // the erase of sector 1
            assert_eq!(store.save(&[9; 1000]), Err(StoreError::Flash));
            assert_eq!(store.flash().sector_erases(), &[1, 1]);
            let mut flash = store.into_inner();
            flash.restore_power();
            assert_eq!(load(&mut Store::new(flash)).unwrap(), [3; 1000]);
        }
    }

    #[test]
    fn cut_between_erase_and_record_keeps_the_old_sector() {
        let mut store = fresh();
        for i in 0..4u8 {
            store.save(&[i; 1000]).unwrap();
        }
        let ops = store.flash().ops();
        // Operation `ops` erases sector 1; `ops + 1` is the header, cut
        // before any of it lands.
        store.flash_mut().cut_power_at(ops + 1, 0);
        let _ = store.save(&[9; 1000]);
        let mut flash = store.into_inner();
        flash.restore_power();
        flash.sectors_mut()[1].fill(0xFF); // whatever the torn header did
        let mut store = Store::new(flash);
        assert_eq!(load(&mut store).unwrap(), [3; 1000]);
        assert_eq!(store.stats().sector, Some(0));
    }

    // ---------------------------------------------------------- fuzz

    /// Fills `flash` with one of several kinds of hostile content.
    fn hostile<const N: usize>(flash: &mut SimFlash<N, 2>, rng: &mut SplitMix64, kind: usize) {
        match kind {
            // Uniform noise.
            0 => {
                for s in flash.sectors_mut() {
                    rng.fill(s);
                }
            }
            // Real records, then bit flips and overwritten bytes.
            1 => {
                let mut store = Store::new(flash.clone());
                for _ in 0..rng.range(1, 12) {
                    let img = random_image(rng);
                    store.save(&img).unwrap();
                }
                *flash = store.into_inner();
                for _ in 0..rng.range(1, 20) {
                    let s = rng.below(2);
                    let at = rng.below(N);
                    if rng.coin() {
                        flash.sectors_mut()[s][at] ^= 1 << rng.below(8);
                    } else {
                        flash.sectors_mut()[s][at] = rng.next_u32() as u8;
                    }
                }
            }
            // Framed headers (valid header CRC) with hostile fields, some
            // complete records of any version, runs of 0xFF and 0x00.
            // Kind 2 gives the complete records sequence numbers from one
            // window, as the store writes them; kind 3 any sequence numbers.
            _ => {
                let base = rng.next_u32();
                for s in 0..2 {
                    let mut at = 0;
                    while at + 64 < N {
                        match rng.below(5) {
                            0 => {
                                let h = Header {
                                    version: rng.next_u32() as u16,
                                    len: rng.next_u32() as u16,
                                    seq: rng.next_u32(),
                                };
                                put(flash, s, at, &h.encode());
                                at += HEADER_LEN;
                            }
                            1 => {
                                let len = rng.range(0, (N - at - 28).min(MAX_IMAGE + 8));
                                let payload = image(rng, len);
                                let version = if rng.coin() { 1 } else { rng.below(4) as u16 };
                                let seq = if kind == 2 {
                                    base.wrapping_add(rng.below(1000) as u32)
                                } else {
                                    rng.next_u32()
                                };
                                let r = raw_record(version, seq, &payload);
                                put(flash, s, at, &r);
                                at += r.len();
                            }
                            2 => at += rng.range(1, 300),
                            3 => {
                                let n = rng.range(1, 64);
                                flash.sectors_mut()[s][at..at + n].fill(0);
                                at += n;
                            }
                            _ => {
                                let n = rng.range(1, 64);
                                rng.fill(&mut flash.sectors_mut()[s][at..at + n]);
                                at += n;
                            }
                        }
                        // Sometimes unaligned.
                        if rng.below(4) == 0 {
                            at += rng.below(4);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn random_flash_contents_never_panic_and_a_save_always_recovers() {
        for seed in 0..600u64 {
            let mut rng = SplitMix64::new(seed);
            let mut flash = Flash::new();
            hostile(&mut flash, &mut rng, (seed % 3) as usize);
            let mut store = Store::new(flash.clone());
            match load(&mut store) {
                Ok(v) => assert!(v.len() <= MAX_IMAGE),
                Err(e) => assert!(matches!(e, StoreError::Corrupt), "seed {seed}: {e:?}"),
            }
            let _ = store.stats();
            for mut s in [store, Store::new(flash)] {
                let img = random_image(&mut rng);
                s.save(&img).unwrap();
                assert_eq!(load(&mut s).unwrap(), img, "seed {seed}");
                let mut s = reboot(s);
                assert_eq!(load(&mut s).unwrap(), img, "seed {seed}");
                assert_eq!(s.flash().counters().overwrites, 0, "seed {seed}");
            }
        }
    }

    /// Intact records with sequence numbers all over the circle are not
    /// something the store writes (see the module docs): which of them is
    /// "newest" is then arbitrary, but nothing panics and saves succeed.
    #[test]
    fn forged_records_with_any_sequence_numbers_never_panic() {
        for seed in 0..300u64 {
            let mut rng = SplitMix64::new(seed);
            let mut flash = Flash::new();
            hostile(&mut flash, &mut rng, 3);
            let mut store = Store::new(flash);
            if let Ok(v) = load(&mut store) {
                assert!(v.len() <= MAX_IMAGE);
            }
            for _ in 0..3 {
                store.save(&random_image(&mut rng)).unwrap();
                assert!(load(&mut store).is_ok());
            }
            assert_eq!(store.flash().counters().overwrites, 0, "seed {seed}");
        }
    }
}
