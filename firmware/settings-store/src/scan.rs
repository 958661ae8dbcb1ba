//! Reading a sector: intact records, the newest loadable one, where the
//! erased tail begins (see the module doc).

use embedded_storage::nor_flash::NorFlash;

use super::*;

/// An intact record found by a scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Found {
    pub(super) sector: usize,
    pub(super) offset: usize,
    pub(super) header: Header,
}

/// What one sector holds.
#[derive(Clone, Copy, Debug)]
pub(super) struct SectorScan {
    pub(super) newest_loadable: Option<Found>,
    pub(super) newest_intact: Option<Found>,
    /// Start of the erased rest of the sector.
    pub(super) tail: usize,
    /// Something that is neither a framed record nor erased was seen.
    pub(super) garbage: bool,
}

impl SectorScan {
    pub(super) fn blank(&self) -> bool {
        self.tail == 0 && !self.garbage
    }
}

/// `a` is newer than `b` in serial-number order.
pub(super) fn newer(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

/// The newer of `best` and `candidate`; a tie goes to `candidate` (found
/// later).
pub(super) fn pick(best: Option<Found>, candidate: Option<Found>) -> Option<Found> {
    match (best, candidate) {
        (Some(b), Some(c)) if newer(b.header.seq, c.header.seq) => Some(b),
        (b, None) => b,
        (_, c) => c,
    }
}

impl<F: NorFlash> Store<F> {
    // ------------------------------------------------------------------ scan

    pub(super) fn scan_sector(&mut self, sector: usize) -> Result<SectorScan, StoreError> {
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
    pub(super) fn scan_all(&mut self) -> Result<(Mount, Option<Found>, bool), StoreError> {
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
