//! PoStep60 USB reports (manual 10.2) ↔ typed requests and responses.
//!
//! Both directions are 64-byte buffers as a hidapi / Windows HID host sees
//! them: `OutDATA[0]` is the output report id (ignored here), `OutDATA[1]`
//! the command, `OutDATA[63]` must be 0; `InDATA[0]` is the input report id
//! 0x02. Byte offsets and byte orders are the manual's tables', including
//! their oddities (module doc of [`super`] and `docs/DECISIONS.md`).
//!
//! Extensions, in bytes every table marks unused ("-"):
//! * `OutDATA[62]` selects the axis a command addresses (0 = axis 0, what a
//!   zero-filled PoStep60 buffer sends);
//! * `InDATA[13]` echoes that axis, `InDATA[14]` says whether the command
//!   was executed ([`status`] codes: 0 = done);
//! * command 0xA2 stops the 0xA0 stream; command 0xDF with "DFU!" in
//!   `OutDATA[20..24]` restarts into ST's ROM DFU bootloader.

use crate::postep60::current::Current;
use crate::postep60::device::Trajectory;
use crate::postep60::drv8711::{Drv8711Regs, REGISTERS};
use crate::postep60::settings::NAME_LEN;

/// Bytes of every report, both directions.
pub const REPORT_LEN: usize = 64;
/// `InDATA[0]`: the input report id.
pub const IN_REPORT_ID: u8 = 0x02;
/// `OutDATA[62]`: the axis a command addresses (extension).
pub const AXIS_BYTE: usize = 62;
/// `InDATA[13]`: the axis a response comes from (extension).
pub const IN_AXIS_BYTE: usize = 13;
/// `InDATA[14]`: what became of the command (extension, [`status`]).
pub const IN_STATUS_BYTE: usize = 14;
/// `InDATA[15]`: "response to command".
pub const IN_RESPONSE_BYTE: usize = 15;
/// The magic that must follow 0xDF at `OutDATA[20..24]`.
pub const DFU_MAGIC: [u8; 4] = *b"DFU!";

/// Codes of `InDATA[14]`.
pub mod status {
    pub const DONE: u8 = 0;
    pub const WRONG_MODE: u8 = 1;
    pub const ASLEEP: u8 = 2;
    pub const FAULTED: u8 = 3;
    pub const IGNORED: u8 = 4;
    pub const UNSUPPORTED: u8 = 5;
    pub const BAD_ADDRESS: u8 = 6;
    pub const BUSY: u8 = 7;
    pub const BOOT_MODE: u8 = 8;
    /// `OutDATA[62]` names an axis the chain does not have.
    pub const NO_AXIS: u8 = 9;
    /// Extension space (0xE0/0xE1): no such register or quantity.
    pub const ILLEGAL_ADDRESS: u8 = 10;
    /// Extension space: a value out of range.
    pub const ILLEGAL_VALUE: u8 = 11;
    /// Extension space: not now (access class, busy…).
    pub const REFUSED: u8 = 12;
    /// Extension space: the chip did not answer in time.
    pub const TIMEOUT: u8 = 13;
    /// The axis is a member of a coordinated move under way.
    pub const GROUPED: u8 = 14;
}

/// Registers one USB extension access carries (0xE0/0xE1).
pub const EXT_MAX: usize = 16;

/// Command bytes (`OutDATA[1]`).
pub mod cmd {
    pub const DEVICE_INFO: u8 = 0x01;
    pub const SYSTEM_RESET: u8 = 0x02;
    pub const WRITE_DRIVER_SETTINGS: u8 = 0x80;
    pub const READ_DRIVER_SETTINGS: u8 = 0x81;
    /// The table of 10.2.5 prints 0x82, its heading 0x83: both erase.
    pub const ERASE_EEPROM_TABLE: u8 = 0x82;
    pub const ERASE_EEPROM: u8 = 0x83;
    pub const READ_EEPROM: u8 = 0x84;
    pub const READ_DRIVER_REGISTERS: u8 = 0x85;
    pub const RESET_FAULTS: u8 = 0x86;
    pub const SAVE_OTHER: u8 = 0x87;
    pub const READ_OTHER: u8 = 0x88;
    pub const STEP_DIR: u8 = 0x90;
    pub const STREAM: u8 = 0xA0;
    pub const RUN_SLEEP: u8 = 0xA1;
    /// Extension: stop the 0xA0 stream.
    pub const STREAM_OFF: u8 = 0xA2;
    pub const SET_PWM: u8 = 0xB0;
    pub const TRAJECTORY: u8 = 0xB1;
    pub const TRAJECTORY_STOP: u8 = 0xB2;
    pub const TRAJECTORY_ZERO: u8 = 0xB3;
    pub const WRITE_NAME: u8 = 0xC0;
    pub const READ_NAME: u8 = 0xC1;
    /// Extension: restart into ST's ROM DFU bootloader.
    pub const ENTER_DFU: u8 = 0xDF;
    /// Extension: read the extension space (`bridge::ext`): `OutDATA[20..21]`
    /// address MSB first, `[22]` quantity 1..=16; answer `[16..]` MSB first.
    pub const EXT_READ: u8 = 0xE0;
    /// Extension: write the extension space: address, quantity, `[24..]` data.
    pub const EXT_WRITE: u8 = 0xE1;
}

/// 0x80 Write Driver Settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriverSettings {
    /// Bytes 20..35: CTRL … STATUS, each LSB first.
    pub regs: Drv8711Regs,
    /// Byte 37: CONFIG_SET (driver mode 1..=6).
    pub config_set: u8,
    /// Byte 38: MAX_TEMP, °C.
    pub max_temp: u8,
    /// Bytes 39..40 and 41..42: Tq, Ai.
    pub idle: Current,
    pub overheat: Current,
    /// Byte 43: I2C/Modbus address of the addressed axis.
    pub address: u8,
    /// Byte 44: Modbus baud/parity code 0..=5.
    pub serial_code: u8,
}

/// A decoded OUT report.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UsbRequest {
    DeviceInfo,
    SystemReset,
    WriteDriverSettings(DriverSettings),
    ReadDriverSettings,
    EraseEeprom,
    ReadEeprom,
    ReadDriverRegisters,
    ResetFaults,
    SaveOther,
    ReadOther,
    /// 0x90: bytes 20..23 StepValue LSB first, byte 24 direction (1 = invert).
    StepDir {
        step_value: u32,
        reverse: bool,
    },
    StreamOn,
    /// 0xA1 byte 20: 0x01 run, 0x00 sleep (others ignored).
    RunSleep(u8),
    SetPwm,
    Trajectory(Trajectory),
    Stop,
    Zero,
    /// 0xC0 bytes 2..33 (the manual's "up to 32 ASCII characters").
    WriteName([u8; NAME_LEN]),
    ReadName,
    StreamOff,
    EnterDfu,
    ExtRead {
        address: u16,
        quantity: u8,
    },
    ExtWrite {
        address: u16,
        quantity: u8,
        data: [u16; EXT_MAX],
    },
}

/// Why an OUT report was not decoded (it is then ignored and counted).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UsbError {
    /// Not a 64-byte report (nor a 63-byte one: byte 0 stripped).
    Length(usize),
    /// `OutDATA[63]` is not 0 ("Must be always 0x00!").
    LastByte(u8),
    /// No such command.
    Unknown(u8),
    /// 0xDF without its magic.
    DfuMagic,
}

/// Byte `i` (0 past the end).
fn b(r: &[u8], i: usize) -> u8 {
    r.get(i).copied().unwrap_or(0)
}

/// Byte `i + k` (offsets are the tables' constants, below 64).
fn bk(r: &[u8], i: usize, k: usize) -> u8 {
    b(r, i.saturating_add(k))
}

fn le16(r: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([b(r, i), bk(r, i, 1)])
}

fn le32(r: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([b(r, i), bk(r, i, 1), bk(r, i, 2), bk(r, i, 3)])
}

/// Decode an OUT report: the request and the axis it addresses.
///
/// A 63-byte report is `OutDATA[1..63]` without byte 0: a host whose HID
/// stack treats byte 0 as a report id and strips it when it is 0 (Linux
/// usbhid for a hidraw write of a buffer starting 0x00) sends that for the
/// manual's `OutDATA[0]` = "-" (unspecified). It is taken as the 64-byte
/// report with byte 0 = 0.
pub fn decode(r: &[u8]) -> Result<(UsbRequest, u8), UsbError> {
    let mut padded = [0u8; REPORT_LEN];
    let r = full_report(r, &mut padded)?;
    match b(r, 63) {
        0 => {}
        other => return Err(UsbError::LastByte(other)),
    }
    let axis = b(r, AXIS_BYTE);
    let req = match b(r, 1) {
        cmd::DEVICE_INFO => UsbRequest::DeviceInfo,
        cmd::SYSTEM_RESET => UsbRequest::SystemReset,
        cmd::WRITE_DRIVER_SETTINGS => UsbRequest::WriteDriverSettings(driver_settings(r)),
        cmd::READ_DRIVER_SETTINGS => UsbRequest::ReadDriverSettings,
        cmd::ERASE_EEPROM | cmd::ERASE_EEPROM_TABLE => UsbRequest::EraseEeprom,
        cmd::READ_EEPROM => UsbRequest::ReadEeprom,
        cmd::READ_DRIVER_REGISTERS => UsbRequest::ReadDriverRegisters,
        cmd::RESET_FAULTS => UsbRequest::ResetFaults,
        cmd::SAVE_OTHER => UsbRequest::SaveOther,
        cmd::READ_OTHER => UsbRequest::ReadOther,
        cmd::STEP_DIR => UsbRequest::StepDir {
            step_value: le32(r, 20),
            reverse: b(r, 24) == 0x01,
        },
        cmd::STREAM => UsbRequest::StreamOn,
        cmd::RUN_SLEEP => UsbRequest::RunSleep(b(r, 20)),
        cmd::STREAM_OFF => UsbRequest::StreamOff,
        cmd::SET_PWM => UsbRequest::SetPwm,
        cmd::TRAJECTORY => UsbRequest::Trajectory(trajectory(r)),
        cmd::TRAJECTORY_STOP => UsbRequest::Stop,
        cmd::TRAJECTORY_ZERO => UsbRequest::Zero,
        cmd::WRITE_NAME => {
            let mut name = [0u8; NAME_LEN];
            for (k, slot) in name.iter_mut().enumerate() {
                *slot = bk(r, 2, k);
            }
            UsbRequest::WriteName(name)
        }
        cmd::READ_NAME => UsbRequest::ReadName,
        cmd::EXT_READ => UsbRequest::ExtRead {
            address: u16::from_be_bytes([b(r, 20), b(r, 21)]),
            quantity: b(r, 22),
        },
        cmd::EXT_WRITE => ext_write(r),
        cmd::ENTER_DFU => {
            if [b(r, 20), b(r, 21), b(r, 22), b(r, 23)] != DFU_MAGIC {
                return Err(UsbError::DfuMagic);
            }
            UsbRequest::EnterDfu
        }
        other => return Err(UsbError::Unknown(other)),
    };
    Ok((req, axis))
}

/// The 64-byte report: `r` itself, or a 63-byte `r` behind a zero byte 0
/// (copied into `padded`).
fn full_report<'a>(r: &'a [u8], padded: &'a mut [u8; REPORT_LEN]) -> Result<&'a [u8], UsbError> {
    match r.len() {
        REPORT_LEN => Ok(r),
        n if n == REPORT_LEN - 1 => {
            for (dst, src) in padded.iter_mut().skip(1).zip(r.iter()) {
                *dst = *src;
            }
            Ok(&padded[..])
        }
        n => Err(UsbError::Length(n)),
    }
}

/// 0x81's payload (manual 10.2): the DRV8711 registers from byte 20 and
/// the settings after them.
fn driver_settings(r: &[u8]) -> DriverSettings {
    let mut regs = [0u16; REGISTERS];
    for (k, slot) in regs.iter_mut().enumerate() {
        *slot = le16(r, 20usize.saturating_add(k.saturating_mul(2)));
    }
    DriverSettings {
        regs: Drv8711Regs(regs),
        config_set: b(r, 37),
        max_temp: b(r, 38),
        idle: Current {
            tq: b(r, 39),
            ai: b(r, 40),
        },
        overheat: Current {
            tq: b(r, 41),
            ai: b(r, 42),
        },
        address: b(r, 43),
        serial_code: b(r, 44),
    }
}

/// 0xB1's payload (manual 10.2): target, limits, flags, BIN steps, speed.
fn trajectory(r: &[u8]) -> Trajectory {
    let flags = b(r, 36);
    Trajectory {
        profile: b(r, 2),
        final_position: le32(r, 20) as i32,
        max_speed: le32(r, 24),
        acc: le32(r, 28),
        dec: le32(r, 32),
        end_switch: flags & 0x01 != 0,
        end_switch_nc: flags & 0x02 != 0,
        invert: flags & 0x04 != 0,
        bin1_steps: le32(r, 40) as i32,
        bin2_steps: le32(r, 44) as i32,
        requested_speed: le32(r, 48),
    }
}

/// The extension write's payload: address, quantity, big-endian registers
/// from byte 24.
fn ext_write(r: &[u8]) -> UsbRequest {
    let mut data = [0u16; EXT_MAX];
    for (k, slot) in data.iter_mut().enumerate() {
        let at = 24usize.saturating_add(k.saturating_mul(2));
        *slot = u16::from_be_bytes([b(r, at), bk(r, at, 1)]);
    }
    UsbRequest::ExtWrite {
        address: u16::from_be_bytes([b(r, 20), b(r, 21)]),
        quantity: b(r, 22),
        data,
    }
}

/// An IN report being built: writes past the end are dropped (never panic).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InReport(pub [u8; REPORT_LEN]);

impl InReport {
    /// A report with the id, the packet identifier `[1]`, the
    /// "response to command" byte `[15]`, and the axis and status extensions.
    pub fn new(packet_id: u8, response: u8, axis: u8, status: u8) -> InReport {
        let mut r = InReport([0; REPORT_LEN]);
        r.put(0, &[IN_REPORT_ID]);
        r.put(1, &[packet_id]);
        r.put(IN_AXIS_BYTE, &[axis]);
        r.put(IN_STATUS_BYTE, &[status]);
        r.put(IN_RESPONSE_BYTE, &[response]);
        r
    }

    pub fn put(&mut self, at: usize, bytes: &[u8]) {
        for (k, v) in bytes.iter().enumerate() {
            if let Some(slot) = at.checked_add(k).and_then(|i| self.0.get_mut(i)) {
                *slot = *v;
            }
        }
    }

    pub fn u8(&mut self, at: usize, v: u8) {
        self.put(at, &[v]);
    }
    pub fn be16(&mut self, at: usize, v: u16) {
        self.put(at, &v.to_be_bytes());
    }
    pub fn le16(&mut self, at: usize, v: u16) {
        self.put(at, &v.to_le_bytes());
    }
    pub fn be32(&mut self, at: usize, v: u32) {
        self.put(at, &v.to_be_bytes());
    }
    pub fn le32(&mut self, at: usize, v: u32) {
        self.put(at, &v.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn a_63_byte_report_is_out_data_1_to_63_with_byte_0_stripped() {
        // Linux hidraw: a write of [0x00, 0x01, 0, …] (64 bytes) reaches the
        // device as its last 63 bytes.
        let mut full = [0u8; REPORT_LEN];
        full[1] = 0x01; // device info
        full[AXIS_BYTE] = 1;
        let stripped = &full[1..];
        assert_eq!(stripped.len(), 63);
        assert_eq!(decode(stripped), decode(&full));
        assert_eq!(decode(stripped), Ok((UsbRequest::DeviceInfo, 1)));
    }

    use super::*;

    fn out(cmd: u8) -> [u8; REPORT_LEN] {
        let mut r = [0u8; REPORT_LEN];
        r[1] = cmd;
        r
    }

    #[test]
    fn a_report_must_be_64_bytes_with_a_zero_last_byte() {
        assert_eq!(decode(&[0, 1]), Err(UsbError::Length(2)));
        assert_eq!(decode(&[0; 62]), Err(UsbError::Length(62)));
        assert_eq!(decode(&[0; 65]), Err(UsbError::Length(65)));
        let mut r = out(0x01);
        r[63] = 1;
        assert_eq!(decode(&r), Err(UsbError::LastByte(1)));
        assert_eq!(decode(&out(0x01)), Ok((UsbRequest::DeviceInfo, 0)));
    }

    #[test]
    fn erase_is_accepted_as_0x83_and_as_the_table_s_0x82() {
        assert_eq!(decode(&out(0x83)).map(|d| d.0), Ok(UsbRequest::EraseEeprom));
        assert_eq!(decode(&out(0x82)).map(|d| d.0), Ok(UsbRequest::EraseEeprom));
    }

    #[test]
    fn unknown_commands_are_errors() {
        for c in [0x00, 0x03, 0x89, 0xA3, 0xFF] {
            assert_eq!(decode(&out(c)), Err(UsbError::Unknown(c)));
        }
    }

    #[test]
    fn byte_62_selects_the_axis() {
        let mut r = out(0xB2);
        r[62] = 3;
        assert_eq!(decode(&r), Ok((UsbRequest::Stop, 3)));
    }

    #[test]
    fn dfu_needs_its_magic() {
        let mut r = out(0xDF);
        assert_eq!(decode(&r), Err(UsbError::DfuMagic));
        r[20..24].copy_from_slice(b"DFU!");
        assert_eq!(decode(&r), Ok((UsbRequest::EnterDfu, 0)));
    }

    #[test]
    fn an_in_report_drops_writes_past_its_end() {
        let mut r = InReport::new(0xBA, 0x81, 1, 0);
        r.be32(62, 0x1122_3344);
        assert_eq!(&r.0[..2], &[0x02, 0xBA]);
        assert_eq!(&r.0[62..], &[0x11, 0x22]);
        assert_eq!(r.0[15], 0x81);
        assert_eq!(r.0[13], 1);
    }
}
