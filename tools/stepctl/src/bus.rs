//! The one interface every command is written against: 16-bit registers in
//! the box's Modbus address space (docs/modbus.md "Modbus register map" and
//! docs/extension-space.md), whatever carries them.
//!
//! * `0x00nn` is PoStep60 command `nn` (FC 0x03 reads, 0x06/0x10 writes);
//! * `0x01nn..` is the extension space (chip registers, I/O extension,
//!   diagnostics, homing, watchdog, axis state).
//!
//! `unit` is the axis as the user names it: the Modbus server id (factory:
//! 1 = first axis); over USB, 1 + the axis index (`OutDATA[62]`).

use crate::error::Result;

pub trait Bus {
    /// Read `count` registers at `address` of `unit`.
    fn read(&mut self, unit: u8, address: u16, count: u16) -> Result<Vec<u16>>;
    /// Write `values` at `address` of `unit` (one value: FC 0x06, else 0x10).
    fn write(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<()>;
    /// Where requests go, for messages ("tcp 127.0.0.1:5020").
    fn name(&self) -> String;
    /// Whether this bus is Modbus (exception 04 is then explained by reads).
    fn is_modbus(&self) -> bool;
    /// Shorten or restore the reply timeout (a scan probes many ids).
    fn set_timeout_ms(&mut self, _ms: u64) {}
    /// A raw PoStep60 request; what goes out and what came back, as text.
    fn raw(&mut self, unit: u8, command: u16, data: &[u16], count: Option<u16>)
        -> Result<RawReply>;
}

/// What `stepctl raw` prints.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RawReply {
    /// The bytes sent (a Modbus ADU with its CRC, or a 64-byte USB report).
    pub request: Vec<u8>,
    /// The bytes received.
    pub reply: Vec<u8>,
    /// Registers read, if it was a read.
    pub registers: Vec<u16>,
}

pub fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Two registers, high word first, as i32 (the box's 32-bit layout).
pub fn i32_of(words: &[u16]) -> i32 {
    u32_of(words) as i32
}

pub fn u32_of(words: &[u16]) -> u32 {
    match words {
        [hi, lo, ..] => u32::from(*hi) << 16 | u32::from(*lo),
        [lo] => u32::from(*lo),
        [] => 0,
    }
}

pub fn words_of(v: u32) -> [u16; 2] {
    [(v >> 16) as u16, v as u16]
}

/// Longest wait [`deadline`] gives: a year stands for "no limit".
const LONGEST_WAIT: std::time::Duration = std::time::Duration::from_secs(31_536_000);

/// The instant `after` from now, for polls and replies. A span beyond a year
/// (a `--timeout` of centuries) is a year, so the sum never overflows the
/// clock and never panics.
pub fn deadline(after: std::time::Duration) -> std::time::Instant {
    let now = std::time::Instant::now();
    now.checked_add(after.min(LONGEST_WAIT)).unwrap_or(now)
}

/// `words[at..at + n]`, cut to what is there (empty past the end): a short
/// reply reads as zeros in [`u32_of`], never a panic.
pub fn words_at(words: &[u16], at: usize, n: usize) -> &[u16] {
    let tail = words.get(at..).unwrap_or_default();
    tail.get(..n).unwrap_or(tail)
}
