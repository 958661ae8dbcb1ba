//! Modbus RTU server (PoStep60 manual §9, the product rules (`docs/PRODUCT.md`)): serial-line framing,
//! server ids, and the PoStep60 register map of [`map`].
//!
//! # Assumptions
//!
//! * The firmware calls [`RtuServer::on_byte`] from the RX interrupt with the
//!   time the byte's stop bit ended (µs of a monotonic clock), and
//!   [`RtuServer::poll`] once [`RtuServer::deadline`] has passed — again
//!   while the deadline stays ≤ now. It transmits the ADU `poll` returns.
//! * The receiver does not hear our own transmission (RS-485 with RE tied
//!   to DE). An echoed FC 0x06 response is byte-identical to its request.
//! * Characters are 11 bits: start, 8 data, parity (even/odd) or a second
//!   stop bit (no parity), stop. [`Timing::for_serial`] derives t1.5/t3.5
//!   from the settings' [`Serial`]; above 19200 baud the Modbus serial-line
//!   spec's fixed 750 µs / 1750 µs apply.
//!
//! # Framing (Modbus over serial line V1.02, §2.5.1.1)
//!
//! * A frame ends when t3.5 has passed since the end of its last byte. A
//!   byte ending at or after that instant starts a new frame, whether or not
//!   `poll` ran in between (so the outcome never depends on poll latency).
//! * Silence of more than t1.5 between two bytes of a frame (a byte ending
//!   more than one character time + t1.5 after the previous one; the
//!   character time is taken as ⅔·t1.5) marks the frame bad. The bytes after
//!   the gap still belong to it until t3.5 of silence, then the whole frame
//!   is dropped: an interrupted request is never half-executed and its tail
//!   is never taken for a request.
//! * Dropped silently, never answered, nothing executed: frames with a gap
//!   (counted in [`Stats::gaps`]), frames longer than [`ADU_MAX`]
//!   ([`Stats::overruns`]), frames shorter than 4 bytes or with a bad
//!   CRC-16/MODBUS ([`Stats::crc_errors`]).
//! * At most one ended frame waits for `poll`; if another one ends before
//!   `poll` ran, the older one is dropped ([`Stats::overruns`]): a reply
//!   that late would collide with the traffic that followed it.
//!
//! **Resynchronisation on a multidrop bus.** Frame boundaries come only from
//! silence: every t3.5 of silence starts a fresh frame, so after noise, a
//! partial frame or a power-up in the middle of traffic the server is back
//! in sync at the next properly delimited frame. It never searches inside a
//! frame for something that looks like a request: bytes glued to a frame
//! without t3.5 of silence (leading or trailing garbage, two frames with no
//! gap) make one frame whose CRC fails, and it is dropped — the master
//! retries. Other servers' requests and responses are frames with another
//! server id; only their CRC is checked and they are ignored
//! ([`Stats::other_ids`]), whatever their function or length, so a
//! response that happens to look like a request is never executed.
//!
//! # What is answered
//!
//! * Server ids: axis k answers `base + k` ([`ModbusTarget::axis_for_id`]).
//!   Ids 248..=255, and ids of no axis, are never answered.
//! * Broadcast (id 0): a well-formed write (FC 0x06 / 0x10 to a writable
//!   command) is executed on every axis — 0x04 Set address only on the axis
//!   that answers BYTE0 now, an extension write to a bridge-wide block
//!   (`crate::ext_space::is_bridge_wide`) once — and nothing is ever sent
//!   back, not even an exception. Broadcast reads and malformed broadcasts
//!   do nothing.
//! * Exceptions, checked in the Modbus spec's order (response function code
//!   = function | 0x80, the product rules (`docs/PRODUCT.md`)): 01 the function is not 0x03/0x06/0x10;
//!   03 quantity outside 1..=125 (0x03) / 1..=123 (0x10), byte count ≠
//!   2 × quantity, or a PDU length that does not fit the function; 02 no
//!   such command (including the extension space, high address byte ≠ 0,
//!   and I2C-only 0x01), reading a write-only or writing a read-only
//!   command, or a quantity other than the command's register count; 04 the
//!   axis refused (asleep, faulted, wrong mode, DC motor/PWM, bad address
//!   change).
//! * Values the manual says are ignored (e.g. step mode > 8, Run/Sleep other
//!   than 0xDA/0x0F) get the normal response, as on a PoStep60, and are
//!   counted in [`Stats::ignored_values`].
//! * 0x04 Set address: the response always carries the id the request was
//!   sent to (the old one); the target may move its ids at once.
//!   0x60 System reset and 0x3F Write settings: the target defers them
//!   (the bridge's `take_reset` / `take_save`), so the reply goes out first.
//! * Never panics, whatever the bytes and timestamps: every index is checked
//!   and all time arithmetic saturates.

pub mod map;
mod pdu;

pub use map::Exception;

use crc::{Crc, CRC_16_MODBUS};
use heapless::Vec;

use crate::ext_space::ExtError;
use crate::postep60::settings::{Parity, Serial};
use crate::postep60::{CommandError, Effect, Query, Request, Value};
use pdu::{broadcast, respond};
#[cfg(test)]
use pdu::{parse, Pdu};

/// Largest RTU ADU (server id + PDU + CRC).
pub const ADU_MAX: usize = 256;
/// Highest unicast server id.
pub const ID_MAX: u8 = 247;
/// Bits per character: start, 8 data, parity or second stop, stop.
pub const CHARACTER_BITS: u32 = 11;
/// Highest quantity of FC 0x03 (Modbus application protocol).
pub const READ_QUANTITY_MAX: u16 = 125;
/// Highest quantity of FC 0x10.
pub const WRITE_QUANTITY_MAX: u16 = 123;

static CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_MODBUS);

/// Inter-character (t1.5) and inter-frame (t3.5) silences, µs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Timing {
    pub t15_us: u32,
    pub t35_us: u32,
}

impl Timing {
    /// t1.5 and t3.5 for 11-bit characters at `s.baud`, rounded up
    /// (9600: 1719 / 4011 µs; 19200: 860 / 2006 µs); above 19200 baud the
    /// fixed 750 / 1750 µs. A baud rate of 0 is taken as the default 9600.
    pub const fn for_serial(s: Serial) -> Timing {
        let baud = if s.baud == 0 {
            Serial::DEFAULT.baud as u64
        } else {
            s.baud as u64
        };
        if baud > 19_200 {
            return Timing {
                t15_us: 750,
                t35_us: 1750,
            };
        }
        // 11 bits per character: the products below are constants.
        const BITS_E6: u64 = CHARACTER_BITS as u64 * 1_000_000;
        // half-characters × bits × 1e6 / baud, rounded up; ≤ 38.5 s fits u32.
        // (`baud` is one of the six settings, ≥ 1200: no product overflows.)
        let t15 = (3 * BITS_E6).div_ceil(baud.saturating_mul(2));
        let t35 = (7 * BITS_E6).div_ceil(baud.saturating_mul(2));
        Timing {
            t15_us: t15 as u32,
            t35_us: t35 as u32,
        }
    }

    /// One character time, taken as ⅔·t1.5 (exact up to 19200 baud).
    pub const fn character_us(self) -> u32 {
        ((self.t15_us as u64).saturating_mul(2).div_ceil(3)) as u32
    }
}

/// Stop bits of the UART character format: 2 without parity, else 1.
pub const fn stop_bits(s: Serial) -> u8 {
    match s.parity {
        Parity::None => 2,
        Parity::Even | Parity::Odd => 1,
    }
}

/// Counters of what the server saw (all saturate).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Stats {
    /// Frames with a valid CRC (any server id).
    pub frames_ok: u32,
    /// Frames shorter than 4 bytes or with a bad CRC (dropped).
    pub crc_errors: u32,
    /// Frames with silence > t1.5 inside (dropped).
    pub gaps: u32,
    /// Frames with a character received in error (dropped).
    pub bad_characters: u32,
    /// Frames longer than [`ADU_MAX`], or ended frames replaced before
    /// `poll` ran (dropped).
    pub overruns: u32,
    /// Valid frames for another server id (other servers' traffic; ignored).
    pub other_ids: u32,
    /// Exception responses built.
    pub exceptions: u32,
    /// Valid broadcast frames (id 0).
    pub broadcasts: u32,
    /// Requests answered normally although the axis ignored the value.
    pub ignored_values: u32,
    /// Normal (non-exception) responses built.
    pub responses: u32,
    /// Exceptions 01, 02, 03, 04.
    pub exceptions_by_code: [u32; 4],
    /// Extension reads answered only after a control tick (chip registers).
    pub deferred: u32,
}

impl Stats {
    const ZERO: Stats = Stats {
        frames_ok: 0,
        crc_errors: 0,
        bad_characters: 0,
        gaps: 0,
        overruns: 0,
        other_ids: 0,
        exceptions: 0,
        broadcasts: 0,
        ignored_values: 0,
        responses: 0,
        exceptions_by_code: [0; 4],
        deferred: 0,
    };

    /// The counts since `base` (saturating at 0).
    pub fn since(&self, base: &Stats) -> Stats {
        let d = |a: u32, b: u32| a.saturating_sub(b);
        let mut by_code = [0u32; 4];
        for ((o, a), b) in by_code
            .iter_mut()
            .zip(self.exceptions_by_code.iter())
            .zip(base.exceptions_by_code.iter())
        {
            *o = d(*a, *b);
        }
        Stats {
            frames_ok: d(self.frames_ok, base.frames_ok),
            crc_errors: d(self.crc_errors, base.crc_errors),
            gaps: d(self.gaps, base.gaps),
            bad_characters: d(self.bad_characters, base.bad_characters),
            overruns: d(self.overruns, base.overruns),
            other_ids: d(self.other_ids, base.other_ids),
            exceptions: d(self.exceptions, base.exceptions),
            broadcasts: d(self.broadcasts, base.broadcasts),
            ignored_values: d(self.ignored_values, base.ignored_values),
            responses: d(self.responses, base.responses),
            exceptions_by_code: by_code,
            deferred: d(self.deferred, base.deferred),
        }
    }
}

fn bump(counter: &mut u32) {
    *counter = counter.saturating_add(1);
}

/// What the server executes requests on (the bridge).
pub trait ModbusTarget {
    /// Axis answering server id `id` (1..=247), if any.
    fn axis_for_id(&self, id: u8) -> Option<usize>;
    fn axes(&self) -> usize;
    fn request(&mut self, axis: usize, req: Request) -> Result<Effect, CommandError>;
    fn query(&mut self, axis: usize, q: Query) -> Option<Value>;
    /// Read registers of the extension space (address high byte ≠ 0).
    fn ext_read(&mut self, axis: usize, address: u16, out: &mut [u16]) -> Result<(), ExtError> {
        let _ = (axis, address, out);
        Err(ExtError::IllegalAddress)
    }
    /// Write registers of the extension space.
    fn ext_write(&mut self, axis: usize, address: u16, data: &[u16]) -> Result<(), ExtError> {
        let _ = (axis, address, data);
        Err(ExtError::IllegalAddress)
    }
}

/// A target by reference (the firmware keeps its bridge in a static slot
/// and shares `&'static mut Bridge`).
impl<T: ModbusTarget + ?Sized> ModbusTarget for &mut T {
    fn axis_for_id(&self, id: u8) -> Option<usize> {
        (**self).axis_for_id(id)
    }
    fn axes(&self) -> usize {
        (**self).axes()
    }
    fn request(&mut self, axis: usize, req: Request) -> Result<Effect, CommandError> {
        (**self).request(axis, req)
    }
    fn query(&mut self, axis: usize, q: Query) -> Option<Value> {
        (**self).query(axis, q)
    }
    fn ext_read(&mut self, axis: usize, address: u16, out: &mut [u16]) -> Result<(), ExtError> {
        (**self).ext_read(axis, address, out)
    }
    fn ext_write(&mut self, axis: usize, address: u16, data: &[u16]) -> Result<(), ExtError> {
        (**self).ext_write(axis, address, data)
    }
}

/// An extension read not answered yet is retried every this many µs …
pub const DEFER_RETRY_US: u64 = 1_000;
/// … and answered with exception 04 after this long.
pub const DEFER_MAX_US: u64 = 50_000;

/// Why a frame in progress will be dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Fault {
    /// Silence > t1.5 inside the frame.
    Gap,
    /// A character arrived with a parity, framing or noise error (or was lost
    /// to an overrun): the frame must be discarded whatever its CRC says.
    BadCharacter,
    /// More than [`ADU_MAX`] bytes.
    Overlong,
}

#[derive(Clone)]
struct Frame {
    buf: [u8; ADU_MAX],
    len: usize,
    fault: Option<Fault>,
    /// End of the last byte, µs.
    last_us: u64,
}

impl Frame {
    const EMPTY: Frame = Frame {
        buf: [0; ADU_MAX],
        len: 0,
        fault: None,
        last_us: 0,
    };

    fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn clear(&mut self) {
        self.len = 0;
        self.fault = None;
    }

    fn push(&mut self, byte: u8) {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = byte;
                // len < ADU_MAX: `get_mut` found a slot.
                self.len = self.len.saturating_add(1);
            }
            None => self.fault = Some(Fault::Overlong),
        }
    }

    fn bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }
}

/// The Modbus RTU server of the bridge: one per serial line.
#[derive(Clone)]
pub struct RtuServer {
    timing: Timing,
    /// Frame in progress.
    rx: Frame,
    /// An ended frame waiting for `poll`.
    ready: Frame,
    /// Response ADU of the last `poll`.
    tx: Vec<u8, ADU_MAX>,
    stats: Stats,
    /// A request whose extension read waits for the chip; retried at
    /// `retry_us`, given up at `give_up_us`.
    deferred: Frame,
    retry_us: u64,
    give_up_us: u64,
}

impl core::fmt::Debug for RtuServer {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("RtuServer")
            .field("timing", &self.timing)
            .field("rx_len", &self.rx.len)
            .field("ready_len", &self.ready.len)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl RtuServer {
    pub const fn new(timing: Timing) -> RtuServer {
        RtuServer {
            timing,
            rx: Frame::EMPTY,
            ready: Frame::EMPTY,
            tx: Vec::new(),
            stats: Stats::ZERO,
            deferred: Frame::EMPTY,
            retry_us: 0,
            give_up_us: 0,
        }
    }

    pub fn timing(&self) -> Timing {
        self.timing
    }

    pub fn stats(&self) -> Stats {
        self.stats
    }

    fn frame_end(&self, frame: &Frame) -> u64 {
        frame.last_us.saturating_add(u64::from(self.timing.t35_us))
    }

    /// RX interrupt: one byte received (its stop bit ended) at `now_us`.
    pub fn on_byte(&mut self, byte: u8, now_us: u64) {
        if !self.rx.is_empty() {
            if now_us >= self.frame_end(&self.rx) {
                // The frame in progress ended before this byte: it waits
                // for `poll`; this byte starts a new one.
                if !self.ready.is_empty() {
                    bump(&mut self.stats.overruns);
                }
                core::mem::swap(&mut self.rx, &mut self.ready);
                self.rx.clear();
            } else {
                let allowed = u64::from(self.timing.character_us())
                    .saturating_add(u64::from(self.timing.t15_us));
                if now_us.saturating_sub(self.rx.last_us) > allowed && self.rx.fault.is_none() {
                    self.rx.fault = Some(Fault::Gap);
                }
            }
        }
        self.rx.push(byte);
        self.rx.last_us = now_us;
    }

    /// RX interrupt: a character arrived with a parity, framing or noise
    /// error, or characters were lost to an overrun, at `now_us`. The frame it
    /// belongs to is discarded at its end (Modbus serial line spec §2.5.1.2),
    /// even if the remaining bytes happen to pass the CRC.
    pub fn on_bad_byte(&mut self, now_us: u64) {
        self.on_byte(0, now_us);
        if self.rx.fault.is_none() {
            self.rx.fault = Some(Fault::BadCharacter);
        }
    }

    /// When `poll` should run next: t3.5 after the last byte of a frame in
    /// progress (already passed if an ended frame is waiting).
    pub fn deadline(&self) -> Option<u64> {
        let frame = if !self.ready.is_empty() {
            Some(self.frame_end(&self.ready))
        } else if !self.rx.is_empty() {
            Some(self.frame_end(&self.rx))
        } else {
            None
        };
        let retry = (!self.deferred.is_empty()).then_some(self.retry_us);
        match (frame, retry) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// If the frame in progress has ended (now ≥ deadline), process it;
    /// returns the response ADU to transmit (None: nothing to send).
    pub fn poll(&mut self, now_us: u64, target: &mut impl ModbusTarget) -> Option<&[u8]> {
        self.tx.clear();
        let rx_ended = !self.rx.is_empty() && now_us >= self.frame_end(&self.rx);
        let new_frame = rx_ended || !self.ready.is_empty();
        if new_frame && !self.deferred.is_empty() {
            // The master moved on (it timed out): the waiting read is stale.
            bump(&mut self.stats.overruns);
            self.deferred.clear();
        }
        let deferred = if rx_ended {
            if !self.ready.is_empty() {
                // Two ended frames: the older one is stale.
                bump(&mut self.stats.overruns);
                self.ready.clear();
            }
            let d = process(&self.rx, &mut self.tx, &mut self.stats, target, true);
            if d {
                self.deferred = self.rx.clone();
            }
            self.rx.clear();
            d
        } else if !self.ready.is_empty() {
            let d = process(&self.ready, &mut self.tx, &mut self.stats, target, true);
            if d {
                self.deferred = self.ready.clone();
            }
            self.ready.clear();
            d
        } else if !self.deferred.is_empty() && now_us >= self.retry_us {
            let may_wait = now_us < self.give_up_us;
            let frame = core::mem::replace(&mut self.deferred, Frame::EMPTY);
            let d = process(&frame, &mut self.tx, &mut self.stats, target, may_wait);
            if d {
                self.deferred = frame;
                self.retry_us = now_us.saturating_add(DEFER_RETRY_US);
            }
            return (!self.tx.is_empty()).then_some(self.tx.as_slice());
        } else {
            false
        };
        if deferred {
            bump(&mut self.stats.deferred);
            self.retry_us = now_us.saturating_add(DEFER_RETRY_US);
            self.give_up_us = now_us.saturating_add(DEFER_MAX_US);
        }
        if self.tx.is_empty() {
            None
        } else {
            Some(self.tx.as_slice())
        }
    }
}

/// CRC-16/MODBUS of `bytes` (transmitted low byte first).
pub fn crc16(bytes: &[u8]) -> u16 {
    CRC16.checksum(bytes)
}

/// Handle one ended frame; the response (if any) is left in `tx`. Returns
/// true when the request waits for the chip (an extension read, only when
/// `may_wait`; the frame is processed again later — its counters are not
/// counted twice: a retried frame only counts its final outcome).
fn process(
    frame: &Frame,
    tx: &mut Vec<u8, ADU_MAX>,
    stats: &mut Stats,
    target: &mut impl ModbusTarget,
    may_wait: bool,
) -> bool {
    match frame.fault {
        Some(Fault::Gap) => {
            bump(&mut stats.gaps);
            return false;
        }
        Some(Fault::BadCharacter) => {
            bump(&mut stats.bad_characters);
            return false;
        }
        Some(Fault::Overlong) => {
            bump(&mut stats.overruns);
            return false;
        }
        None => {}
    }
    let bytes = frame.bytes();
    let Some(body_len) = bytes.len().checked_sub(2).filter(|n| *n >= 2) else {
        bump(&mut stats.crc_errors);
        return false;
    };
    let (body, crc) = bytes.split_at(body_len);
    if crc16(body).to_le_bytes() != *crc {
        bump(&mut stats.crc_errors);
        return false;
    }
    let Some((&id, pdu)) = body.split_first() else {
        return false;
    };
    match id {
        0 => {
            bump(&mut stats.frames_ok);
            bump(&mut stats.broadcasts);
            broadcast(pdu, stats, target);
            false
        }
        1..=ID_MAX => match target.axis_for_id(id) {
            Some(axis) => {
                let waits = respond(id, axis, pdu, tx, stats, target, may_wait);
                if !waits {
                    bump(&mut stats.frames_ok);
                }
                waits
            }
            None => {
                bump(&mut stats.frames_ok);
                bump(&mut stats.other_ids);
                false
            }
        },
        _ => {
            bump(&mut stats.frames_ok);
            bump(&mut stats.other_ids);
            false
        }
    }
}

#[cfg(test)]
mod tests;
