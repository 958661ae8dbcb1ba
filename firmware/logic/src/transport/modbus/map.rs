//! The PoStep60 Modbus register map (manual §9.3): which holding-register
//! address is which command, how many registers it takes, and how its data
//! is laid out.
//!
//! * The register address is `0x00nn` with `nn` the PoStep60 command byte
//!   (manual 9.3 NOTE). Addresses `0x01nn..=0xFFnn` are the extension space:
//!   [`Exception::IllegalDataAddress`] for now.
//! * Registers are big-endian on the wire (BYTE1 first, then BYTE0, as the
//!   manual's tables name them). A 32-bit position is two registers, high
//!   word first. A u8 value sits in BYTE0 (the low byte) of one register;
//!   BYTE1 reads 0 and is not used on writes (except where the manual gives
//!   it a meaning: currents, 0x04).
//! * Currents are one register: BYTE1 = Ai, BYTE0 = Tq
//!   (I = 0.065 A · BYTE0 / 2^BYTE1, manual 9.3.11 and 9.3.17).
//! * 0x04 Set address is `(new << 8) | current`.
//! * A command is read with FC 0x03 or written with FC 0x06 (one register)
//!   or FC 0x10; the quantity must be exactly the command's register count.
//!   Commands the manual gives FC 0x06 are also accepted by FC 0x10 with a
//!   quantity of 1 (many PLCs only write with FC 0x10).

use crate::postep60::device::CommandError;
use crate::postep60::{Current, Query, Request, Value};

/// Modbus exception codes (Modbus application protocol V1.1b3, §7).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Exception {
    /// 01: the function code is not 0x03, 0x06 or 0x10.
    IllegalFunction = 1,
    /// 02: no such command at this address, the wrong access (reading a
    /// write-only command or writing a read-only one), or a quantity that is
    /// not the command's register count.
    IllegalDataAddress = 2,
    /// 03: the request's structure: quantity outside the function's range,
    /// byte count ≠ 2 × quantity, or a PDU length that does not fit.
    IllegalDataValue = 3,
    /// 04: the axis cannot perform the command (asleep, faulted, wrong
    /// driver mode, DC motor / PWM, a refused address change).
    ServerDeviceFailure = 4,
}

impl Exception {
    /// The exception code on the wire.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The exception for a refused request; `None` for
    /// [`CommandError::Ignored`], which gets a normal response.
    pub const fn for_error(e: CommandError) -> Option<Exception> {
        match e {
            CommandError::Ignored => None,
            CommandError::WrongMode
            | CommandError::Asleep
            | CommandError::Faulted
            | CommandError::Unsupported
            | CommandError::BadAddress
            | CommandError::Busy
            | CommandError::BootMode
            | CommandError::Grouped => Some(Exception::ServerDeviceFailure),
        }
    }
}

/// Most registers any command reads or writes (0x06 Set PWM, 0x0A HW/FW info).
pub const REGISTERS_MAX: usize = 3;

/// Builds a request from the command's data bytes (exactly 2 × registers).
type Build = fn(&[u8]) -> Request;

#[derive(Clone, Copy)]
enum Shape {
    Read(Query, u8),
    Write(u8, Build),
}

/// BYTE `i` of the data (0 past the end; callers pass exactly the bytes).
fn byte(d: &[u8], i: usize) -> u8 {
    d.get(i).copied().unwrap_or(0)
}

/// BYTE0 (low byte) of the first register.
fn byte0(d: &[u8]) -> u8 {
    byte(d, 1)
}

/// BYTE1 (high byte) of the first register.
fn byte1(d: &[u8]) -> u8 {
    byte(d, 0)
}

fn register(d: &[u8]) -> u16 {
    u16::from_be_bytes([byte(d, 0), byte(d, 1)])
}

fn current(d: &[u8]) -> Current {
    Current {
        tq: byte0(d),
        ai: byte1(d),
    }
}

/// The command at low address byte `cmd` (manual §9.3, 39 commands).
fn shape(cmd: u8) -> Option<Shape> {
    use Request as R;
    use Shape::{Read, Write};
    Some(match cmd {
        0x03 => Write(1, |d| R::RunSleep(byte0(d))),
        0x04 => Write(1, |d| R::SetAddress {
            current: byte0(d),
            new: byte1(d),
        }),
        0x05 => Write(1, |d| R::SetMode(byte0(d))),
        0x06 => Write(3, |_| R::SetPwm),
        0x0A => Read(Query::HwFwInfo, 3),
        0x10 => Read(Query::Voltage, 1),
        0x11 => Read(Query::Temperature, 1),
        0x12 => Read(Query::Pins, 1),
        0x13 => Read(Query::DriverStatus, 1),
        0x14 => Read(Query::DriverMode, 1),
        0x20 => Read(Query::FullScaleCurrent, 1),
        0x21 => Read(Query::IdleCurrent, 1),
        0x22 => Read(Query::OverheatCurrent, 1),
        0x23 => Read(Query::StepMode, 1),
        0x24 => Read(Query::TemperatureLimit, 1),
        0x25 => Read(Query::Faults, 1),
        0x30 => Write(1, |d| R::SetFullScaleCurrent(current(d))),
        0x31 => Write(1, |d| R::SetIdleCurrent(current(d))),
        0x32 => Write(1, |d| R::SetOverheatCurrent(current(d))),
        0x33 => Write(1, |d| R::SetStepMode(byte0(d))),
        0x34 => Write(1, |d| R::SetTemperatureLimit(byte0(d))),
        0x35 => Write(1, |_| R::ResetFaults),
        0x3F => Write(1, |_| R::WriteSettings),
        0x40 => Read(Query::Position, 2),
        0x41 => Read(Query::MaxSpeed, 1),
        0x42 => Read(Query::Acceleration, 1),
        0x43 => Read(Query::Deceleration, 1),
        0x44 => Read(Query::CurrentSpeed, 1),
        0x45 => Read(Query::RequestedSpeed, 1),
        0x46 => Read(Query::Invert, 1),
        0x50 => Write(2, |d| {
            R::SetPosition(i32::from_be_bytes([
                byte(d, 0),
                byte(d, 1),
                byte(d, 2),
                byte(d, 3),
            ]))
        }),
        0x51 => Write(1, |d| R::SetMaxSpeed(u32::from(register(d)))),
        0x52 => Write(1, |d| R::SetAcceleration(u32::from(register(d)))),
        0x53 => Write(1, |d| R::SetDeceleration(u32::from(register(d)))),
        0x54 => Write(1, |d| R::SetRequestedSpeed(u32::from(register(d)))),
        0x55 => Write(1, |d| R::SetInvert(byte0(d))),
        0x5E => Write(1, |_| R::SetZero),
        0x5F => Write(1, |_| R::Stop),
        0x60 => Write(1, |_| R::SystemReset),
        _ => return None,
    })
}

/// An address in the extension space (high byte ≠ 0, `bridge::ext`).
pub const fn is_extension(address: u16) -> bool {
    address >> 8 != 0
}

/// The command byte of a register address in the PoStep60 space.
fn command(address: u16) -> Result<u8, Exception> {
    match address.to_be_bytes() {
        [0, cmd] => Ok(cmd),
        // Extension space: filled by a later issue.
        _ => Err(Exception::IllegalDataAddress),
    }
}

/// The query a FC 0x03 read of `quantity` registers at `address` asks for.
pub fn read(address: u16, quantity: u16) -> Result<Query, Exception> {
    match shape(command(address)?) {
        Some(Shape::Read(q, regs)) if u16::from(regs) == quantity => Ok(q),
        _ => Err(Exception::IllegalDataAddress),
    }
}

/// The request a write of `quantity` registers (`data`: 2 × quantity bytes,
/// big-endian) at `address` carries.
pub fn write(address: u16, quantity: u16, data: &[u8]) -> Result<Request, Exception> {
    match shape(command(address)?) {
        Some(Shape::Write(regs, build))
            if u16::from(regs) == quantity && data.len() == 2 * usize::from(regs) =>
        {
            Ok(build(data))
        }
        _ => Err(Exception::IllegalDataAddress),
    }
}

/// Register count of the command at `address`: `(registers, writable)`.
pub fn registers(address: u16) -> Option<(u8, bool)> {
    match shape(command(address).ok()?)? {
        Shape::Read(_, regs) => Some((regs, false)),
        Shape::Write(regs, _) => Some((regs, true)),
    }
}

/// A query's value as big-endian registers; returns the byte count (always
/// even, at most 2 × [`REGISTERS_MAX`]).
pub fn encode(value: Value, out: &mut [u8; 2 * REGISTERS_MAX]) -> usize {
    *out = [0; 2 * REGISTERS_MAX];
    let (bytes, len): ([u8; 2 * REGISTERS_MAX], usize) = match value {
        Value::U8(v) => ([0, v, 0, 0, 0, 0], 2),
        Value::U16(v) => {
            let [a, b] = v.to_be_bytes();
            ([a, b, 0, 0, 0, 0], 2)
        }
        Value::I32(v) => {
            let [a, b, c, d] = v.to_be_bytes();
            ([a, b, c, d, 0, 0], 4)
        }
        Value::Current(c) => ([c.ai, c.tq, 0, 0, 0, 0], 2),
        // An odd count gets a leading 0x00 (0x0A: register 1 is 0x0041).
        Value::Bytes(b, n) => {
            let n = usize::from(n).min(b.len());
            let pad = n % 2;
            let mut o = [0u8; 2 * REGISTERS_MAX];
            for (slot, v) in o.iter_mut().skip(pad).zip(b.iter().take(n)) {
                *slot = *v;
            }
            (o, n.saturating_add(pad).min(2 * REGISTERS_MAX))
        }
    };
    *out = bytes;
    len
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every command of manual §9.3, with its access and register count.
    const MANUAL_9_3: [(u8, u8, bool); 39] = [
        (0x03, 1, true),
        (0x04, 1, true),
        (0x05, 1, true),
        (0x06, 3, true),
        (0x0A, 3, false),
        (0x10, 1, false),
        (0x11, 1, false),
        (0x12, 1, false),
        (0x13, 1, false),
        (0x14, 1, false),
        (0x20, 1, false),
        (0x21, 1, false),
        (0x22, 1, false),
        (0x23, 1, false),
        (0x24, 1, false),
        (0x25, 1, false),
        (0x30, 1, true),
        (0x31, 1, true),
        (0x32, 1, true),
        (0x33, 1, true),
        (0x34, 1, true),
        (0x35, 1, true),
        (0x3F, 1, true),
        (0x40, 2, false),
        (0x41, 1, false),
        (0x42, 1, false),
        (0x43, 1, false),
        (0x44, 1, false),
        (0x45, 1, false),
        (0x46, 1, false),
        (0x50, 2, true),
        (0x51, 1, true),
        (0x52, 1, true),
        (0x53, 1, true),
        (0x54, 1, true),
        (0x55, 1, true),
        (0x5E, 1, true),
        (0x5F, 1, true),
        (0x60, 1, true),
    ];

    #[test]
    fn the_map_has_exactly_the_39_commands_of_9_3() {
        for (cmd, regs, writable) in MANUAL_9_3 {
            assert_eq!(
                registers(u16::from(cmd)),
                Some((regs, writable)),
                "{cmd:#04x}"
            );
        }
        let mapped = (0..=255u16).filter(|a| registers(*a).is_some()).count();
        assert_eq!(mapped, 39);
    }

    #[test]
    fn the_extension_space_and_i2c_only_commands_are_illegal_addresses() {
        assert_eq!(read(0x0114, 1), Err(Exception::IllegalDataAddress));
        assert_eq!(read(0xFF14, 1), Err(Exception::IllegalDataAddress));
        assert_eq!(
            write(0x015F, 1, &[0, 0]),
            Err(Exception::IllegalDataAddress)
        );
        // 0x01 loopback and the I2C extensions 0x70/0x71 are not in 9.3.
        for cmd in [0x01, 0x70, 0x71, 0x00, 0xFF] {
            assert_eq!(read(cmd, 1), Err(Exception::IllegalDataAddress));
            assert_eq!(write(cmd, 1, &[0, 0]), Err(Exception::IllegalDataAddress));
        }
    }

    #[test]
    fn access_and_register_count_must_match() {
        assert_eq!(read(0x40, 2), Ok(Query::Position));
        assert_eq!(read(0x40, 1), Err(Exception::IllegalDataAddress));
        assert_eq!(read(0x40, 3), Err(Exception::IllegalDataAddress));
        assert_eq!(read(0x50, 2), Err(Exception::IllegalDataAddress));
        assert_eq!(write(0x40, 2, &[0; 4]), Err(Exception::IllegalDataAddress));
        assert_eq!(write(0x50, 1, &[0; 2]), Err(Exception::IllegalDataAddress));
        assert_eq!(write(0x50, 2, &[0; 2]), Err(Exception::IllegalDataAddress));
    }

    #[test]
    fn writes_decode_the_manual_layouts() {
        assert_eq!(
            write(0x50, 2, &[0xFF, 0xFF, 0xFC, 0x18]),
            Ok(Request::SetPosition(-1000))
        );
        assert_eq!(
            write(0x50, 2, &[0x00, 0x01, 0x86, 0xA0]),
            Ok(Request::SetPosition(100_000))
        );
        assert_eq!(
            write(0x04, 1, &[0x20, 0x01]),
            Ok(Request::SetAddress {
                current: 1,
                new: 0x20
            })
        );
        assert_eq!(
            write(0x30, 1, &[0x02, 0x99]),
            Ok(Request::SetFullScaleCurrent(Current { tq: 0x99, ai: 2 }))
        );
        assert_eq!(
            write(0x51, 1, &[0x07, 0xD0]),
            Ok(Request::SetMaxSpeed(2000))
        );
        assert_eq!(write(0x03, 1, &[0x00, 0xDA]), Ok(Request::RunSleep(0xDA)));
        assert_eq!(write(0x06, 3, &[0; 6]), Ok(Request::SetPwm));
    }

    #[test]
    fn values_encode_big_endian() {
        let mut o = [0; 6];
        assert_eq!(encode(Value::U8(4), &mut o), 2);
        assert_eq!(&o[..2], [0, 4]);
        assert_eq!(encode(Value::U16(333), &mut o), 2);
        assert_eq!(&o[..2], [0x01, 0x4D]);
        assert_eq!(encode(Value::I32(-1000), &mut o), 4);
        assert_eq!(&o[..4], [0xFF, 0xFF, 0xFC, 0x18]);
        assert_eq!(
            encode(Value::Current(Current { tq: 123, ai: 3 }), &mut o),
            2
        );
        assert_eq!(&o[..2], [3, 123]);
        assert_eq!(encode(Value::Bytes([0x41, 1, 0, 0, 1], 5), &mut o), 6);
        assert_eq!(o, [0, 0x41, 1, 0, 0, 1]);
        assert_eq!(encode(Value::Bytes([1, 2, 3, 4, 5], 9), &mut o), 6);
    }

    #[test]
    fn only_ignored_values_escape_an_exception() {
        assert_eq!(Exception::for_error(CommandError::Ignored), None);
        for e in [
            CommandError::WrongMode,
            CommandError::Asleep,
            CommandError::Faulted,
            CommandError::Unsupported,
            CommandError::BadAddress,
        ] {
            assert_eq!(
                Exception::for_error(e),
                Some(Exception::ServerDeviceFailure)
            );
        }
    }
}
