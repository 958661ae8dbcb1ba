//! Writing: flash access in chunks, and programming a record in the order
//! that makes a power cut at any point leave the old or the new record.

use embedded_storage::nor_flash::NorFlash;

use super::*;

impl<F: NorFlash> Store<F> {
    // ----------------------------------------------------------- flash access

    /// Flash offset of `offset` in `sector`.
    pub(super) fn address(sector: usize, offset: usize) -> Result<u32, StoreError> {
        let at = sector
            .checked_mul(Self::SECTOR)
            .and_then(|base| base.checked_add(offset))
            .ok_or(StoreError::Flash)?;
        u32::try_from(at).map_err(flash_err)
    }

    pub(super) fn read(
        &mut self,
        sector: usize,
        offset: usize,
        buf: &mut [u8],
    ) -> Result<(), StoreError> {
        if sector >= SECTORS || add(offset, buf.len())? > Self::SECTOR {
            return Err(StoreError::Flash);
        }
        let at = Self::address(sector, offset)?;
        self.flash.read(at, buf).map_err(flash_err)
    }

    pub(super) fn write(
        &mut self,
        sector: usize,
        offset: usize,
        bytes: &[u8],
    ) -> Result<(), StoreError> {
        if sector >= SECTORS || add(offset, bytes.len())? > Self::SECTOR {
            return Err(StoreError::Flash);
        }
        let at = Self::address(sector, offset)?;
        self.flash.write(at, bytes).map_err(flash_err)
    }

    pub(super) fn erase_sector(&mut self, sector: usize) -> Result<(), StoreError> {
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
    pub(super) fn first_not_erased(
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
    pub(super) fn write_record(
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
    pub(super) fn frame_at(
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
    pub(super) fn intact(
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
    pub(super) fn read_payload(&mut self, found: Found, dst: &mut [u8]) -> Result<(), StoreError> {
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
}
