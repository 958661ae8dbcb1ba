//! The record header: magic, format version, payload length, sequence
//! number and the header CRC (see the module doc's record format).

use super::*;

/// The decoded, CRC-checked header of a framed record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Header {
    pub(super) version: u16,
    pub(super) len: u16,
    pub(super) seq: u32,
}

impl Header {
    pub(super) fn encode(&self) -> [u8; HEADER_LEN] {
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
    pub(super) fn decode(h: &[u8; HEADER_LEN]) -> Option<Header> {
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

    pub(super) fn payload_len(&self) -> usize {
        usize::from(self.len)
    }

    pub(super) fn loadable(&self) -> bool {
        self.version == FORMAT_VERSION && self.payload_len() <= MAX_IMAGE
    }
}
