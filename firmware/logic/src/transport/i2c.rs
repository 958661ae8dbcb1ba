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
//!   transaction is flagged as overlong; the target decides what that means.
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
                    self.len += 1;
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
