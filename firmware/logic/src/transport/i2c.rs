//! PoStep60 I2C slave protocol (manual §8.2): transaction framing only.
//!
//! # What it guarantees
//!
//! * A master write is `command byte, data bytes…`; it is handed to the
//!   [`I2cTarget`] once, when the write ends (STOP, or a repeated START).
//! * A master read returns the response of the **last command written** on
//!   that address, computed when the read is addressed (so a position read
//!   is fresh) — repeatable: reading again recomputes it. Bytes past the end
//!   of the response read as 0x00.
//! * Writes longer than [`WRITE_MAX`] bytes are truncated and the
//!   transaction is flagged as overlong; the target refuses it (a
//!   transaction that is not a well-formed command changes nothing).
//! * [`decode`] takes a command only with exactly the data bytes it needs
//!   ([`I2cError::Short`] with fewer, [`I2cError::Long`] with more): the
//!   manual gives every command a fixed length, and a write with a stray
//!   byte is not the command its first bytes look like.
//! * A bus error (BERR, arbitration loss, overrun) drops the transaction in
//!   progress; nothing is executed from it.
//! * Never panics: every byte from the bus goes through bounded buffers.
//!
//! The firmware's I2C driver calls the `on_*` methods from its event and
//! error interrupts; only [`I2cSlave::on_address`] and [`I2cSlave::on_stop`]
//! touch the target (the bridge), so only they need its lock.

/// Longest master write we keep: command + 6 data bytes (0x06 Set PWM) + slack.
pub const WRITE_MAX: usize = 16;
/// Longest response: 5 bytes (0x0A HW/FW info) + slack.
pub const RESPONSE_MAX: usize = 8;

/// Which own address matched (STM32 OAR1 / OAR2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Which {
    Primary,
    Secondary,
}

/// A finished master write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Write<'a> {
    pub which: Which,
    /// Command byte followed by data, at most [`WRITE_MAX`] bytes.
    pub bytes: &'a [u8],
    /// The master sent more than [`WRITE_MAX`] bytes.
    pub overlong: bool,
}

/// What the bus is connected to (the bridge).
pub trait I2cTarget {
    /// Execute a master write.
    fn i2c_write(&mut self, write: Write<'_>);
    /// Fill `out` with the response to the last command written on `which`;
    /// return its length (≤ [`RESPONSE_MAX`]).
    fn i2c_read(&mut self, which: Which, out: &mut [u8; RESPONSE_MAX]) -> usize;
}

/// A target by reference (the firmware shares `&'static mut Bridge`).
impl<T: I2cTarget + ?Sized> I2cTarget for &mut T {
    fn i2c_write(&mut self, write: Write<'_>) {
        (**self).i2c_write(write)
    }
    fn i2c_read(&mut self, which: Which, out: &mut [u8; RESPONSE_MAX]) -> usize {
        (**self).i2c_read(which, out)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Idle,
    Writing(Which),
    Reading,
}

/// Byte-level state of the I2C slave.
#[derive(Clone, Debug)]
pub struct I2cSlave {
    phase: Phase,
    buf: [u8; WRITE_MAX],
    len: usize,
    overlong: bool,
    response: [u8; RESPONSE_MAX],
    resp_len: usize,
    resp_pos: usize,
    /// Transactions dropped by bus errors.
    pub bus_errors: u32,
}

impl Default for I2cSlave {
    fn default() -> Self {
        I2cSlave::new()
    }
}

impl I2cSlave {
    pub const fn new() -> I2cSlave {
        I2cSlave {
            phase: Phase::Idle,
            buf: [0; WRITE_MAX],
            len: 0,
            overlong: false,
            response: [0; RESPONSE_MAX],
            resp_len: 0,
            resp_pos: 0,
            bus_errors: 0,
        }
    }

    /// ADDR: one of our addresses matched. `read` is the R/W bit.
    /// A write in progress (repeated START) is executed first.
    pub fn on_address(&mut self, which: Which, read: bool, target: &mut impl I2cTarget) {
        self.finish_write(target);
        if read {
            self.resp_len = target.i2c_read(which, &mut self.response).min(RESPONSE_MAX);
            self.resp_pos = 0;
            self.phase = Phase::Reading;
        } else {
            self.len = 0;
            self.overlong = false;
            self.phase = Phase::Writing(which);
        }
    }

    /// RXNE: a data byte of a master write.
    pub fn on_byte_received(&mut self, byte: u8) {
        if let Phase::Writing(_) = self.phase {
            match self.buf.get_mut(self.len) {
                Some(slot) => {
                    *slot = byte;
                    // len < WRITE_MAX: `get_mut` found a slot.
                    self.len = self.len.saturating_add(1);
                }
                None => self.overlong = true,
            }
        }
    }

    /// TXE: the master clocks the next byte of a read.
    pub fn on_byte_requested(&mut self) -> u8 {
        let b = if self.resp_pos < self.resp_len {
            self.response.get(self.resp_pos).copied().unwrap_or(0)
        } else {
            0
        };
        self.resp_pos = self.resp_pos.saturating_add(1);
        b
    }

    /// STOPF (end of a write) or AF (master NACK ending a read).
    pub fn on_stop(&mut self, target: &mut impl I2cTarget) {
        self.finish_write(target);
        self.phase = Phase::Idle;
    }

    /// BERR / ARLO / OVR: drop the transaction in progress.
    pub fn on_bus_error(&mut self) {
        self.bus_errors = self.bus_errors.saturating_add(1);
        self.phase = Phase::Idle;
        self.len = 0;
    }

    fn finish_write(&mut self, target: &mut impl I2cTarget) {
        if let Phase::Writing(which) = self.phase {
            self.phase = Phase::Idle;
            if self.len > 0 {
                let bytes = self.buf.get(..self.len).unwrap_or(&[]);
                target.i2c_write(Write {
                    which,
                    bytes,
                    overlong: self.overlong,
                });
            }
            self.len = 0;
        }
    }
}

// ------------------------------------------------------------------------
// The PoStep60 I2C command set (manual §8.3), little-endian on the wire.
// ------------------------------------------------------------------------

use crate::postep60::{Current, Query, Request, Value};

/// Extension: select which axis the following commands on this address go to
/// (BYTE0 = axis index). Reading after it returns [selected axis, axis count].
pub const SELECT_AXIS: u8 = 0x70;
/// Extension: decelerate to a stop with the deceleration ramp (no data).
pub const SOFT_STOP: u8 = 0x71;
/// Extension: read registers of the extension space (`bridge::ext`):
/// BYTE0..1 address (MSB first), BYTE2 quantity 1..=3. A read after it
/// returns [status, registers MSB first…]; status 1 = the value is being
/// read from the chip: read again after a control tick (1 ms).
pub const EXT_READ: u8 = 0x72;
/// Extension: write registers of the extension space: BYTE0..1 address,
/// then 1..=3 registers MSB first. A read after it returns the status.
pub const EXT_WRITE: u8 = 0x73;
/// Registers one I2C extension access carries.
pub const EXT_MAX: usize = 3;

/// Status byte of the extension commands' reads.
pub mod ext_status {
    pub const OK: u8 = 0;
    pub const NOT_YET: u8 = 1;
    pub const ILLEGAL_ADDRESS: u8 = 10;
    pub const ILLEGAL_VALUE: u8 = 11;
    pub const REFUSED: u8 = 12;
}

/// A decoded master write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum I2cCommand {
    /// Changes something; a later read returns zeros (loopback: the data).
    Request(Request),
    /// Selects what a later read returns.
    Query(Query),
    /// Extension 0x70 with the axis index.
    SelectAxis(u8),
    /// Reading after a bare 0x70: which axis is selected.
    Selection,
    /// Extension 0x72.
    ExtRead { address: u16, quantity: u8 },
    /// Extension 0x73 (`len` registers of `data`).
    ExtWrite {
        address: u16,
        data: [u16; EXT_MAX],
        len: u8,
    },
    /// What a read after an executed 0x73 returns.
    ExtStatus(u8),
}

/// Why a master write is not a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum I2cError {
    /// Not a PoStep60 (or extension) command.
    Unknown(u8),
    /// Fewer data bytes than the command needs.
    Short { command: u8, needed: u8 },
    /// More data bytes than the command takes (or more than the slave's
    /// buffer holds).
    Long { command: u8, takes: u8 },
}

/// Builds a command from its data bytes.
type Build = fn(&[u8]) -> I2cCommand;

/// Data bytes after the command byte, and how to build the command.
/// Two commands take a choice of lengths: 0x70 (0 or 1) and 0x73 (2 + 2 per
/// register, 1..=3 registers); [`lengths`] says which.
fn shape(cmd: u8) -> Option<(u8, Build)> {
    query_shape(cmd)
        .or_else(|| request_shape(cmd))
        .or_else(|| extension_shape(cmd))
}

/// The PoStep60 reads (manual 8.3): no data bytes, one [`Query`] each.
fn query_shape(cmd: u8) -> Option<(u8, Build)> {
    fn q(q: Query) -> I2cCommand {
        I2cCommand::Query(q)
    }
    Some(match cmd {
        0x0A => (0, |_| q(Query::HwFwInfo)),
        0x10 => (0, |_| q(Query::Voltage)),
        0x11 => (0, |_| q(Query::Temperature)),
        0x12 => (0, |_| q(Query::Pins)),
        0x13 => (0, |_| q(Query::DriverStatus)),
        0x14 => (0, |_| q(Query::DriverMode)),
        0x20 => (0, |_| q(Query::FullScaleCurrent)),
        0x21 => (0, |_| q(Query::IdleCurrent)),
        0x22 => (0, |_| q(Query::OverheatCurrent)),
        0x23 => (0, |_| q(Query::StepMode)),
        0x24 => (0, |_| q(Query::TemperatureLimit)),
        0x25 => (0, |_| q(Query::Faults)),
        0x40 => (0, |_| q(Query::Position)),
        0x41 => (0, |_| q(Query::MaxSpeed)),
        0x42 => (0, |_| q(Query::Acceleration)),
        0x43 => (0, |_| q(Query::Deceleration)),
        0x44 => (0, |_| q(Query::CurrentSpeed)),
        0x45 => (0, |_| q(Query::RequestedSpeed)),
        0x46 => (0, |_| q(Query::Invert)),
        _ => return None,
    })
}

/// Data byte `i` of a write (0 past its end: the shape's length was checked).
fn b(d: &[u8], i: usize) -> u8 {
    d.get(i).copied().unwrap_or(0)
}

/// The PoStep60 writes (manual 8.3): data bytes, one [`Request`] each.
fn request_shape(cmd: u8) -> Option<(u8, Build)> {
    use I2cCommand as C;
    fn u16le(d: &[u8]) -> u16 {
        u16::from_le_bytes([b(d, 0), b(d, 1)])
    }
    fn current(d: &[u8]) -> Current {
        Current {
            tq: b(d, 0),
            ai: b(d, 1),
        }
    }
    Some(match cmd {
        0x01 => (4, |d| {
            C::Request(Request::Loopback([b(d, 0), b(d, 1), b(d, 2), b(d, 3)]))
        }),
        0x03 => (1, |d| C::Request(Request::RunSleep(b(d, 0)))),
        0x04 => (2, |d| {
            C::Request(Request::SetAddress {
                current: b(d, 0),
                new: b(d, 1),
            })
        }),
        0x05 => (1, |d| C::Request(Request::SetMode(b(d, 0)))),
        0x06 => (6, |_| C::Request(Request::SetPwm)),
        0x30 => (2, |d| C::Request(Request::SetFullScaleCurrent(current(d)))),
        0x31 => (2, |d| C::Request(Request::SetIdleCurrent(current(d)))),
        0x32 => (2, |d| C::Request(Request::SetOverheatCurrent(current(d)))),
        0x33 => (1, |d| C::Request(Request::SetStepMode(b(d, 0)))),
        0x34 => (1, |d| C::Request(Request::SetTemperatureLimit(b(d, 0)))),
        0x35 => (0, |_| C::Request(Request::ResetFaults)),
        0x3F => (0, |_| C::Request(Request::WriteSettings)),
        0x50 => (4, |d| {
            C::Request(Request::SetPosition(i32::from_le_bytes([
                b(d, 0),
                b(d, 1),
                b(d, 2),
                b(d, 3),
            ])))
        }),
        0x51 => (2, |d| C::Request(Request::SetMaxSpeed(u32::from(u16le(d))))),
        0x52 => (2, |d| {
            C::Request(Request::SetAcceleration(u32::from(u16le(d))))
        }),
        0x53 => (2, |d| {
            C::Request(Request::SetDeceleration(u32::from(u16le(d))))
        }),
        0x54 => (2, |d| {
            C::Request(Request::SetRequestedSpeed(u32::from(u16le(d))))
        }),
        0x55 => (1, |d| C::Request(Request::SetInvert(b(d, 0)))),
        0x5E => (0, |_| C::Request(Request::SetZero)),
        0x5F => (0, |_| C::Request(Request::Stop)),
        0x60 => (0, |_| C::Request(Request::SystemReset)),
        _ => return None,
    })
}

/// The bridge's own commands: axis selection, soft stop, extension space.
fn extension_shape(cmd: u8) -> Option<(u8, Build)> {
    use I2cCommand as C;
    Some(match cmd {
        SELECT_AXIS => (0, |d| match d.first() {
            Some(&axis) => C::SelectAxis(axis),
            None => C::Selection,
        }),
        SOFT_STOP => (0, |_| C::Request(Request::SoftStop)),
        EXT_READ => (3, |d| C::ExtRead {
            address: u16::from_be_bytes([b(d, 0), b(d, 1)]),
            quantity: b(d, 2),
        }),
        EXT_WRITE => (4, |d| {
            let mut data = [0u16; EXT_MAX];
            let mut len = 0u8;
            for (slot, pair) in data
                .iter_mut()
                .zip(d.get(2..).unwrap_or(&[]).chunks_exact(2))
            {
                *slot = u16::from_be_bytes([b(pair, 0), b(pair, 1)]);
                len = len.saturating_add(1);
            }
            C::ExtWrite {
                address: u16::from_be_bytes([b(d, 0), b(d, 1)]),
                data,
                len,
            }
        }),
        _ => return None,
    })
}

/// Whether `n` data bytes are a length command `cmd` takes, given that it
/// takes at least `needed`.
fn lengths(cmd: u8, needed: u8, n: usize) -> bool {
    match cmd {
        SELECT_AXIS => n <= 1,
        EXT_WRITE => n % 2 == 0 && (4..=2 + 2 * EXT_MAX).contains(&n),
        _ => n == usize::from(needed),
    }
}

/// Decode a master write (`bytes[0]` is the command): only with exactly the
/// data bytes the command takes (module doc).
pub fn decode(bytes: &[u8]) -> Result<I2cCommand, I2cError> {
    let (&cmd, data) = bytes.split_first().ok_or(I2cError::Unknown(0))?;
    let (needed, build) = shape(cmd).ok_or(I2cError::Unknown(cmd))?;
    if data.len() < usize::from(needed) {
        return Err(I2cError::Short {
            command: cmd,
            needed,
        });
    }
    if !lengths(cmd, needed, data.len()) {
        return Err(I2cError::Long {
            command: cmd,
            takes: needed,
        });
    }
    Ok(build(data))
}

/// Encode a query's value little-endian (manual §8.3); returns the length.
pub fn encode(value: Value, out: &mut [u8; RESPONSE_MAX]) -> usize {
    *out = [0; RESPONSE_MAX];
    let (bytes, len): ([u8; 5], usize) = match value {
        Value::U8(v) => ([v, 0, 0, 0, 0], 1),
        Value::U16(v) => {
            let [a, b] = v.to_le_bytes();
            ([a, b, 0, 0, 0], 2)
        }
        Value::I32(v) => {
            let [a, b, c, d] = v.to_le_bytes();
            ([a, b, c, d, 0], 4)
        }
        Value::Current(c) => ([c.tq, c.ai, 0, 0, 0], 2),
        Value::Bytes(b, n) => (b, usize::from(n).min(5)),
    };
    for (o, b) in out.iter_mut().zip(bytes.iter().take(len)) {
        *o = *b;
    }
    len
}
