//! The box over USB HID (docs/usb.md): 64-byte reports,
//! byte 0 the report id 2, `OutDATA[1]` the command, `OutDATA[62]` the axis;
//! replies carry the axis in `InDATA[13]` and the outcome in `InDATA[14]`.
//!
//! Commands are written against the Modbus register map ([`Bus`]); this
//! module translates each register to the USB command that carries it:
//!
//! | registers | USB |
//! |---|---|
//! | 0x0A, 0x10, 0x11, 0x12, 0x13 | 0x01 device info (versions, pins [6], supply [8..9], temperature [44..45], status [46]) |
//! | 0x14, 0x20..0x25 | 0x81 driver settings (DRV8711 image [40..55], limit [56], idle [57..58], overheat [59..60], mode [62]) |
//! | 0x41..0x43, 0x46 | 0x88 other configuration (LE32 at [24], [28], [32]; flags [36]) |
//! | 0x40, 0x44, 0x01nn.. | 0xE0 / 0xE1 extension space (0x0602 position, 0x0600 speed) |
//! | writes 0x05, 0x30..0x34 | 0x81 read, the field changed, 0x80 written back (0x80 also stores) |
//! | writes 0x50..0x53 | 0xB1 trajectory with the limits and switches of 0x88 |
//! | writes 0x03, 0x35, 0x3F, 0x5E, 0x5F | 0xA1, 0x86, 0x87, 0xB3, 0xB2 |
//!
//! Not carried over USB (an error says so): 0x04 set address, 0x06 PWM,
//! 0x45 / 0x54 / 0x55 requested speed and invert (no USB command reports the
//! requested speed), 0x60 system reset.

use std::time::{Duration, Instant};

use bridge_logic::postep60::current::Current;
use bridge_logic::postep60::drv8711::{reg, Drv8711Regs, REGISTERS as DRV_REGISTERS};
use bridge_logic::transport::usb::codec::{
    cmd, status, AXIS_BYTE, EXT_MAX, IN_AXIS_BYTE, IN_REPORT_ID, IN_RESPONSE_BYTE, IN_STATUS_BYTE,
};
use bridge_logic::transport::usb::{PID, REPORT_LEN, VID};

use crate::bus::{i32_of, Bus, RawReply};
use crate::error::{Error, Result};

pub type Report = [u8; REPORT_LEN];

/// A HID device: write one output report, read one input report.
pub trait Hid {
    fn write(&mut self, report: &Report) -> std::result::Result<(), String>;
    /// One input report, or `Ok(None)` when none came within `timeout`.
    fn read(&mut self, timeout: Duration) -> std::result::Result<Option<Report>, String>;
    fn name(&self) -> String;
}

/// A USB device found by [`list`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Found {
    pub path: String,
    pub serial: String,
    pub product: String,
}

fn no_hidapi(e: impl std::fmt::Display) -> Error {
    Error::Comm(format!("USB: cannot start hidapi: {e}"))
}

/// Every PoStep60-compatible device (VID 0x1DC3, PID 0x0641) plugged in.
pub fn list() -> Result<Vec<Found>> {
    let api = hidapi::HidApi::new().map_err(no_hidapi)?;
    Ok(api
        .device_list()
        .filter(|d| d.vendor_id() == VID && d.product_id() == PID)
        .map(|d| Found {
            path: d.path().to_string_lossy().into_owned(),
            serial: d.serial_number().unwrap_or("").to_string(),
            product: d.product_string().unwrap_or("").to_string(),
        })
        .collect())
}

/// The message when no device is there.
pub fn not_found() -> Error {
    Error::Comm(format!(
        "USB: no stepbridge/PoStep60 HID device (VID 0x{VID:04X}, PID 0x{PID:04X}) found: is the box \
         plugged in and running a firmware with USB HID (the QEMU image has no USB: use --tcp), \
         and may you open /dev/hidraw* (docs/usb.md: udev rule)?"
    ))
}

/// A real device through hidapi.
pub struct HidapiDevice {
    dev: hidapi::HidDevice,
    name: String,
}

impl std::fmt::Debug for HidapiDevice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HidapiDevice")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

impl HidapiDevice {
    /// Open the device with `serial`, or the only one plugged in.
    pub fn open(serial: Option<&str>) -> Result<HidapiDevice> {
        let found = list()?;
        let pick = match serial {
            Some(s) => found.iter().find(|f| f.serial == s),
            None => found.first(),
        };
        let Some(f) = pick else {
            return Err(match serial {
                Some(s) if !found.is_empty() => Error::Comm(format!(
                    "USB: no device with serial {s}; found: {}",
                    found
                        .iter()
                        .map(|f| f.serial.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )),
                _ => not_found(),
            });
        };
        if serial.is_none() && found.len() > 1 {
            return Err(Error::Usage(format!(
                "USB: {} devices found, pick one with --usb-serial ({})",
                found.len(),
                found
                    .iter()
                    .map(|f| f.serial.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        }
        let api = hidapi::HidApi::new().map_err(no_hidapi)?;
        let path = std::ffi::CString::new(f.path.clone())
            .map_err(|_| Error::Comm("USB: a device path with a NUL byte".into()))?;
        let dev = api.open_path(&path).map_err(|e| {
            Error::Comm(format!(
                "USB: cannot open {} ({e}): on Linux install the udev rule of docs/usb.md",
                f.path
            ))
        })?;
        Ok(HidapiDevice {
            dev,
            name: format!("usb {} ({})", f.serial, f.path),
        })
    }
}

impl Hid for HidapiDevice {
    fn write(&mut self, report: &Report) -> std::result::Result<(), String> {
        self.dev
            .write(report)
            .map(|_| ())
            .map_err(|e| e.to_string())
    }

    fn read(&mut self, timeout: Duration) -> std::result::Result<Option<Report>, String> {
        let mut buf = [0u8; REPORT_LEN];
        let ms = i32::try_from(timeout.as_millis()).unwrap_or(i32::MAX);
        match self.dev.read_timeout(&mut buf, ms) {
            Ok(0) => Ok(None),
            Ok(_) => Ok(Some(buf)),
            Err(e) => Err(e.to_string()),
        }
    }

    fn name(&self) -> String {
        self.name.clone()
    }
}

/// Queued input reports [`UsbBus::transact`] reads away before it writes
/// (hidraw keeps 64 per reader).
const DRAIN_MAX: usize = 128;

/// The box over a [`Hid`].
#[derive(Debug)]
pub struct UsbBus<H: Hid> {
    pub hid: H,
    pub timeout: Duration,
    pub trace: bool,
}

/// An output report for `command` to axis `unit - 1`.
pub fn out_report(unit: u8, command: u8) -> Report {
    let mut r = [0u8; REPORT_LEN];
    r[0] = IN_REPORT_ID;
    r[1] = command;
    r[AXIS_BYTE] = unit.saturating_sub(1);
    r
}

/// `N` bytes of a reply at `i`; zeros past the report's end (never a panic).
fn bytes_at<const N: usize>(r: &Report, i: usize) -> [u8; N] {
    r.get(i..)
        .and_then(|t| t.get(..N))
        .and_then(|b| <[u8; N]>::try_from(b).ok())
        .unwrap_or([0; N])
}
fn le16(r: &Report, i: usize) -> u16 {
    u16::from_le_bytes(bytes_at(r, i))
}
fn be16(r: &Report, i: usize) -> u16 {
    u16::from_be_bytes(bytes_at(r, i))
}
fn le32(r: &Report, i: usize) -> u32 {
    u32::from_le_bytes(bytes_at(r, i))
}
/// Put `bytes` into a report at `at` (callers keep within its 64 bytes;
/// anything past them is dropped, never a panic).
fn put(out: &mut Report, at: usize, bytes: &[u8]) {
    if let Some(d) = out.get_mut(at..).and_then(|t| t.get_mut(..bytes.len())) {
        d.copy_from_slice(bytes);
    }
}
fn sat16(v: u32) -> u16 {
    u16::try_from(v).unwrap_or(u16::MAX)
}

/// The DRV8711 image of a 0x81 reply (bytes 40..55, LSB first).
fn drv_of(r: &Report) -> Drv8711Regs {
    let mut regs = [0u16; DRV_REGISTERS];
    for (k, v) in regs.iter_mut().enumerate() {
        #[allow(clippy::arithmetic_side_effects)] // k < DRV_REGISTERS (8): bytes 40..55
        let at = 40 + 2 * k;
        *v = le16(r, at);
    }
    Drv8711Regs(regs)
}

fn current_word(c: Current) -> u16 {
    u16::from(c.ai) << 8 | u16::from(c.tq)
}

/// `CTRL.MODE` (bits 6:3) and `CTRL.ISGAIN` (9:8), `TORQUE` (7:0): the
/// fields `bridge_logic::postep60::drv8711` maps.
const MODE_SHIFT: u16 = 3;
const MODE_MASK: u16 = 0xF << MODE_SHIFT;
const ISGAIN_SHIFT: u16 = 8;
const ISGAIN_MASK: u16 = 0x3 << ISGAIN_SHIFT;

impl<H: Hid> UsbBus<H> {
    pub fn new(hid: H, timeout: Duration) -> UsbBus<H> {
        UsbBus {
            hid,
            timeout,
            trace: false,
        }
    }

    /// Send `out` and wait for its reply (the one from the same axis that is
    /// not a 0xA0 stream report); a status other than done is an error.
    pub fn transact(&mut self, out: &Report, what: &str) -> Result<Report> {
        let name = self.hid.name();
        // Reports still queued (a running 0xA0 stream fills Linux hidraw's
        // 63-report queue in 0.63 s, and a full queue drops new ones — the
        // reply to this command among them): read them away first.
        for _ in 0..DRAIN_MAX {
            match self.hid.read(Duration::ZERO) {
                Ok(Some(_)) => continue,
                _ => break,
            }
        }
        if self.trace {
            eprintln!("stepctl: {name} -> {}", crate::bus::hex(out));
        }
        self.hid
            .write(out)
            .map_err(|e| Error::Comm(format!("{what}: cannot write to {name}: {e}")))?;
        let deadline = crate::bus::deadline(self.timeout);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let r = self
                .hid
                .read(left)
                .map_err(|e| Error::Comm(format!("{what}: cannot read from {name}: {e}")))?;
            let Some(r) = r else {
                return Err(Error::Comm(format!(
                    "{what}: no reply from axis {} on {name} within {} ms",
                    u16::from(out[AXIS_BYTE]).saturating_add(1),
                    self.timeout.as_millis()
                )));
            };
            if self.trace {
                eprintln!("stepctl: {name} <- {}", crate::bus::hex(&r));
            }
            let stream = r[IN_RESPONSE_BYTE] == cmd::STREAM && r[1] == 0;
            if r[0] != IN_REPORT_ID || stream || r[IN_AXIS_BYTE] != out[AXIS_BYTE] {
                if left.is_zero() {
                    return Err(Error::Comm(format!("{what}: no reply on {name}")));
                }
                continue;
            }
            if r[IN_STATUS_BYTE] != status::DONE {
                return Err(Error::Refused {
                    status: r[IN_STATUS_BYTE],
                    what: what.to_string(),
                });
            }
            return Ok(r);
        }
    }

    fn call(&mut self, unit: u8, command: u8, what: &str) -> Result<Report> {
        self.transact(&out_report(unit, command), &format!("axis {unit}: {what}"))
    }

    fn ext_read(&mut self, unit: u8, address: u16, count: u16) -> Result<Vec<u16>> {
        let n = usize::from(count);
        if n == 0 || n > EXT_MAX {
            return Err(Error::Usage(format!(
                "USB reads 1..={EXT_MAX} extension registers at a time, not {count}"
            )));
        }
        let mut out = out_report(unit, cmd::EXT_READ);
        out[20..22].copy_from_slice(&address.to_be_bytes());
        out[22] = count as u8;
        let r = self.transact(&out, &format!("axis {unit}: read 0x{address:04X}"))?;
        Ok((16..).step_by(2).take(n).map(|at| be16(&r, at)).collect())
    }

    fn ext_write(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<()> {
        if values.is_empty() || values.len() > EXT_MAX {
            return Err(Error::Usage(format!(
                "USB writes 1..={EXT_MAX} extension registers at a time"
            )));
        }
        let mut out = out_report(unit, cmd::EXT_WRITE);
        out[20..22].copy_from_slice(&address.to_be_bytes());
        out[22] = values.len() as u8;
        let data = out.get_mut(24..).unwrap_or_default().chunks_exact_mut(2);
        for (o, v) in data.zip(values) {
            o.copy_from_slice(&v.to_be_bytes());
        }
        self.transact(&out, &format!("axis {unit}: write 0x{address:04X}"))
            .map(|_| ())
    }

    /// 0x81 → change → 0x80 (which applies and stores every field).
    fn driver_settings(&mut self, unit: u8, change: impl FnOnce(&mut Report)) -> Result<()> {
        let r = self.call(unit, cmd::READ_DRIVER_SETTINGS, "read driver settings")?;
        let mut out = out_report(unit, cmd::WRITE_DRIVER_SETTINGS);
        // 0x81 [40..55] → 0x80 [20..35]; [56] → [38]; [57..60] → [39..42];
        // [61] → [43]; [62] mode → [37]; [63] serial → [44].
        out[20..36].copy_from_slice(&r[40..56]);
        out[37] = r[62];
        out[38] = r[56];
        out[39..43].copy_from_slice(&r[57..61]);
        out[43] = r[61];
        out[44] = r[63];
        change(&mut out);
        self.transact(&out, &format!("axis {unit}: write driver settings"))
            .map(|_| ())
    }

    /// 0x88 → 0xB1 with the given final position and limits.
    fn trajectory(
        &mut self,
        unit: u8,
        final_position: Option<i32>,
        limits: [Option<u32>; 3],
    ) -> Result<()> {
        let mode = self.call(unit, cmd::READ_DRIVER_SETTINGS, "read driver mode")?[62];
        let profile = match mode {
            4 => 0,
            5 => 1,
            _ => {
                return Err(Error::Usage(format!(
                    "axis {unit}: over USB stepctl moves and sets limits only in driver mode 4 or 5 \
                     (this axis is in mode {mode}); switch with `stepctl settings set {unit} mode position`"
                )))
            }
        };
        let other = self.call(unit, cmd::READ_OTHER, "read other configuration")?;
        let target = match final_position {
            Some(p) => p,
            None => i32_of(&self.ext_read(unit, 0x0604, 2)?),
        };
        let mut out = out_report(unit, cmd::TRAJECTORY);
        out[2] = profile;
        out[20..24].copy_from_slice(&target.to_le_bytes());
        for (k, lim) in limits.iter().enumerate() {
            #[allow(clippy::arithmetic_side_effects)] // k < 3: bytes 24..35
            let at = 24 + 4 * k;
            let v = lim.unwrap_or(le32(&other, at));
            put(&mut out, at, &v.to_le_bytes());
        }
        // 0x88 flags: 0 end switch, 1 NC, 4 invert; 0xB1: 0, 1, 2 invert.
        let f = other[36];
        out[36] = (f & 0x03) | ((f >> 4) & 1) << 2;
        out[40..48].copy_from_slice(&other[40..48]);
        self.transact(&out, &format!("axis {unit}: trajectory"))
            .map(|_| ())
    }

    fn unsupported(address: u16) -> Error {
        Error::Usage(format!(
            "register 0x{address:04X} has no USB command (docs/stepctl.md: USB); use Modbus (--tcp/--port)"
        ))
    }
}

impl<H: Hid> Bus for UsbBus<H> {
    fn read(&mut self, unit: u8, address: u16, count: u16) -> Result<Vec<u16>> {
        if address >> 8 != 0 {
            return self.ext_read(unit, address, count);
        }
        let v: Vec<u16> = match address {
            0x0A | 0x10 | 0x11 | 0x12 | 0x13 => {
                let r = self.call(unit, cmd::DEVICE_INFO, "device info")?;
                match address {
                    // 0x41, HW (not reported over USB: 0), FW = application version.
                    0x0A => vec![0x0041, 0, be16(&r, 3)],
                    0x10 => vec![be16(&r, 8)],
                    0x11 => vec![be16(&r, 44)],
                    0x12 => vec![u16::from(r[6])],
                    _ => vec![u16::from(r[46])],
                }
            }
            0x14 | 0x20..=0x25 => {
                let r = self.call(unit, cmd::READ_DRIVER_SETTINGS, "read driver settings")?;
                let m = drv_of(&r).mapped();
                match address {
                    0x14 => vec![u16::from(r[62])],
                    0x20 => vec![current_word(m.full_scale)],
                    0x21 => vec![current_word(Current {
                        tq: r[57],
                        ai: r[58],
                    })],
                    0x22 => vec![current_word(Current {
                        tq: r[59],
                        ai: r[60],
                    })],
                    0x23 => vec![u16::from(m.step_mode.unwrap_or(0))],
                    0x24 => vec![u16::from(r[56])],
                    _ => vec![drv_of(&r).get(reg::STATUS) & 0xFF],
                }
            }
            0x41..=0x43 | 0x46 => {
                let r = self.call(unit, cmd::READ_OTHER, "read other configuration")?;
                match address {
                    0x46 => vec![u16::from(r[36] >> 4 & 1)],
                    _ => {
                        #[allow(clippy::arithmetic_side_effects)]
                        // address in 0x41..=0x43: bytes 24..35
                        let at = 24 + 4 * usize::from(address - 0x41);
                        vec![sat16(le32(&r, at))]
                    }
                }
            }
            0x40 => self.ext_read(unit, 0x0602, 2)?,
            0x44 => {
                let s = i32_of(&self.ext_read(unit, 0x0600, 2)?);
                vec![sat16(s.unsigned_abs())]
            }
            _ => return Err(Self::unsupported(address)),
        };
        if usize::from(count) != v.len() {
            return Err(Error::Usage(format!(
                "register 0x{address:04X} is {} register(s), not {count}",
                v.len()
            )));
        }
        Ok(v)
    }

    fn write(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<()> {
        if address >> 8 != 0 {
            return self.ext_write(unit, address, values);
        }
        let v = values.first().copied().unwrap_or(0);
        match address {
            0x03 => {
                let mut out = out_report(unit, cmd::RUN_SLEEP);
                out[20] = match v & 0xFF {
                    0xDA => 0x01,
                    0x0F => 0x00,
                    _ => 0xFF,
                };
                self.transact(&out, &format!("axis {unit}: run/sleep"))
                    .map(|_| ())
            }
            0x05 => self.driver_settings(unit, |o| o[37] = v as u8),
            0x30 => self.driver_settings(unit, |o| {
                let c = Current {
                    tq: v as u8,
                    ai: (v >> 8) as u8,
                }
                .with_ai_at_most(3);
                let ctrl = le16(o, 20);
                let ctrl = (ctrl & !ISGAIN_MASK) | (u16::from(c.ai) << ISGAIN_SHIFT);
                o[20..22].copy_from_slice(&ctrl.to_le_bytes());
                o[22] = c.tq;
            }),
            0x31 => self.driver_settings(unit, |o| {
                o[39] = v as u8;
                o[40] = (v >> 8) as u8;
            }),
            0x32 => self.driver_settings(unit, |o| {
                o[41] = v as u8;
                o[42] = (v >> 8) as u8;
            }),
            0x33 => self.driver_settings(unit, |o| {
                let ctrl = le16(o, 20);
                let ctrl = (ctrl & !MODE_MASK) | ((v & 0xF) << MODE_SHIFT);
                o[20..22].copy_from_slice(&ctrl.to_le_bytes());
            }),
            0x34 => self.driver_settings(unit, |o| o[38] = v as u8),
            0x35 => self
                .call(unit, cmd::RESET_FAULTS, "reset faults")
                .map(|_| ()),
            0x3F => self
                .call(unit, cmd::SAVE_OTHER, "save settings")
                .map(|_| ()),
            0x50 => self.trajectory(unit, Some(crate::bus::i32_of(values)), [None; 3]),
            0x51..=0x53 => {
                let mut limits = [None; 3];
                if let Some(l) = limits.get_mut(usize::from(address.saturating_sub(0x51))) {
                    *l = Some(u32::from(v));
                }
                self.trajectory(unit, None, limits)
            }
            0x5E => self
                .call(unit, cmd::TRAJECTORY_ZERO, "set zero")
                .map(|_| ()),
            0x5F => self.call(unit, cmd::TRAJECTORY_STOP, "stop").map(|_| ()),
            _ => Err(Self::unsupported(address)),
        }
    }

    fn name(&self) -> String {
        self.hid.name()
    }

    fn is_modbus(&self) -> bool {
        false
    }

    fn set_timeout_ms(&mut self, ms: u64) {
        self.timeout = Duration::from_millis(ms);
    }

    /// Over USB `command` is the USB command byte and `data` the bytes of
    /// `OutDATA[2..]` (each value's low byte).
    fn raw(
        &mut self,
        unit: u8,
        command: u16,
        data: &[u16],
        _count: Option<u16>,
    ) -> Result<RawReply> {
        let command = u8::try_from(command)
            .map_err(|_| Error::Usage(format!("USB command 0x{command:X} is not a byte")))?;
        let mut out = out_report(unit, command);
        if data.len() > 60 {
            return Err(Error::Usage(
                "at most 60 data bytes (OutDATA[2..61])".into(),
            ));
        }
        for (o, v) in out.iter_mut().skip(2).zip(data) {
            *o = *v as u8;
        }
        let reply = match self.transact(&out, &format!("axis {unit}: USB command 0x{command:02X}"))
        {
            Ok(r) => r.to_vec(),
            Err(Error::Refused { status, what }) => return Err(Error::Refused { status, what }),
            Err(e) => return Err(e),
        };
        Ok(RawReply {
            request: out.to_vec(),
            reply,
            registers: Vec::new(),
        })
    }
}

#[cfg(test)]
pub mod fake {
    use super::*;
    use std::collections::VecDeque;

    /// Replies queued per write; every written report is kept.
    #[derive(Debug, Default)]
    pub struct FakeHid {
        pub written: Vec<Report>,
        pub replies: VecDeque<Vec<Report>>,
    }

    impl FakeHid {
        pub fn new(replies: Vec<Vec<Report>>) -> FakeHid {
            FakeHid {
                written: Vec::new(),
                replies: replies.into(),
            }
        }
    }

    #[derive(Debug)]
    pub struct Pending(pub VecDeque<Report>);

    impl Hid for (FakeHid, Pending) {
        fn write(&mut self, report: &Report) -> std::result::Result<(), String> {
            self.0.written.push(*report);
            let next = self.0.replies.pop_front().unwrap_or_default();
            self.1 .0.extend(next);
            Ok(())
        }
        fn read(&mut self, _t: Duration) -> std::result::Result<Option<Report>, String> {
            Ok(self.1 .0.pop_front())
        }
        fn name(&self) -> String {
            "usb fake".into()
        }
    }

    /// An input report: id 2, `[1]` packet id, `[13]` axis, `[14]` status,
    /// `[15]` response byte, then `(offset, bytes)` fields.
    pub fn reply(
        packet: u8,
        axis: u8,
        status: u8,
        response: u8,
        fields: &[(usize, &[u8])],
    ) -> Report {
        let mut r = [0u8; REPORT_LEN];
        r[0] = 0x02;
        r[1] = packet;
        r[13] = axis;
        r[14] = status;
        r[15] = response;
        for (at, b) in fields {
            r[*at..*at + b.len()].copy_from_slice(b);
        }
        r
    }

    pub fn bus(replies: Vec<Vec<Report>>) -> UsbBus<(FakeHid, Pending)> {
        UsbBus::new(
            (FakeHid::new(replies), Pending(VecDeque::new())),
            Duration::from_millis(10),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::fake::*;
    use super::*;

    // Layouts: docs/usb.md and docs/DECISIONS.md "USB
    // HID" (0x01: supply [8..9] and temperature [44..45] big-endian, status
    // [46]; 0x81: packet id 0xBA, response 0x81, DRV8711 image [40..55] LSB
    // first, mode [62]; 0x88: 0xCC / 0x87, LE32 limits at [24], [28], [32]).

    /// A hidraw reader: 63 reports queued at most (a 64-slot ring), newer ones dropped.
    struct Hidraw {
        queue: std::collections::VecDeque<Report>,
        reply: Report,
    }

    impl Hid for Hidraw {
        fn write(&mut self, _report: &Report) -> std::result::Result<(), String> {
            if self.queue.len() < 63 {
                self.queue.push_back(self.reply);
            }
            Ok(())
        }
        fn read(&mut self, _t: Duration) -> std::result::Result<Option<Report>, String> {
            Ok(self.queue.pop_front())
        }
        fn name(&self) -> String {
            "hidraw".into()
        }
    }

    #[test]
    fn reports_queued_by_the_stream_are_read_away_before_a_command() {
        // The 0xA0 stream filled the reader's queue (Linux hidraw keeps 64):
        // without reading it away first the reply would be dropped.
        let stream = reply(0, 0, 0, cmd::STREAM, &[]);
        let info = reply(0, 0, 0, 0, &[(46, &[2])]);
        let mut b = UsbBus::new(
            Hidraw {
                queue: std::iter::repeat_n(stream, 63).collect(),
                reply: info,
            },
            Duration::from_millis(10),
        );
        assert_eq!(b.read(1, 0x13, 1), Ok(vec![2]));
    }

    #[test]
    fn every_report_starts_with_id_2_and_selects_the_axis_at_byte_62() {
        let r = out_report(3, 0x01);
        assert_eq!((r[0], r[1], r[62], r[63]), (0x02, 0x01, 2, 0));
        assert_eq!(r.len(), 64);
    }

    #[test]
    fn voltage_and_temperature_come_from_device_info_big_endian() {
        // 333 · 0.072 V = 24 V; 200 · 0.125 °C = 25 °C.
        let info = reply(
            0,
            0,
            0,
            0,
            &[(8, &[0x01, 0x4D]), (44, &[0x00, 0xC8]), (46, &[2])],
        );
        let mut b = bus(vec![vec![info], vec![info], vec![info]]);
        assert_eq!(b.read(1, 0x10, 1), Ok(vec![333]));
        assert_eq!(b.read(1, 0x11, 1), Ok(vec![200]));
        assert_eq!(b.read(1, 0x13, 1), Ok(vec![2]));
        assert_eq!(b.hid.0.written[0][1], 0x01);
    }

    #[test]
    fn step_mode_and_full_scale_current_come_from_the_drv8711_image_of_0x81() {
        // CTRL = ENBL | MODE 4 | ISGAIN 3 = 0x0321, TORQUE = 123: 1/16, 0.999 A.
        let r81 = reply(
            0xBA,
            0,
            0,
            0x81,
            &[
                (40, &[0x21, 0x03]),
                (42, &[123, 0]),
                (56, &[80]),
                (62, &[4]),
            ],
        );
        let mut b = bus(vec![vec![r81], vec![r81], vec![r81], vec![r81]]);
        assert_eq!(b.read(1, 0x23, 1), Ok(vec![4]));
        assert_eq!(b.read(1, 0x20, 1), Ok(vec![0x037B]));
        assert_eq!(b.read(1, 0x24, 1), Ok(vec![80]));
        assert_eq!(b.read(1, 0x14, 1), Ok(vec![4]));
    }

    #[test]
    fn max_speed_comes_from_0x88_little_endian() {
        let r88 = reply(0xCC, 1, 0, 0x87, &[(24, &[0xD0, 0x07, 0, 0])]);
        let mut b = bus(vec![vec![r88]]);
        assert_eq!(b.read(2, 0x41, 1), Ok(vec![2000]));
        assert_eq!(b.hid.0.written[0][62], 1);
    }

    #[test]
    fn position_is_read_through_the_extension_space_0xe0() {
        let r = reply(0, 0, 0, 0xE0, &[(16, &[0xFF, 0xFF, 0xFC, 0x18])]);
        let mut b = bus(vec![vec![r]]);
        assert_eq!(b.read(1, 0x40, 2), Ok(vec![0xFFFF, 0xFC18]));
        let w = b.hid.0.written[0];
        assert_eq!((w[1], w[20], w[21], w[22]), (0xE0, 0x06, 0x02, 2));
    }

    #[test]
    fn a_set_position_is_a_trajectory_0xb1_with_the_limits_of_0x88() {
        let r81 = reply(0xBA, 0, 0, 0x81, &[(62, &[4])]);
        // end switch on, invert (0x88 bit 4) → 0xB1 bits 0 and 2.
        let r88 = reply(
            0xCC,
            0,
            0,
            0x87,
            &[
                (24, &[0xD0, 0x07, 0, 0]),
                (28, &[0x40, 0x1F, 0, 0]),
                (32, &[0x40, 0x1F, 0, 0]),
                (36, &[0x11]),
            ],
        );
        let rb1 = reply(0, 0, 0, 0xB1, &[]);
        let mut b = bus(vec![vec![r81], vec![r88], vec![rb1]]);
        assert_eq!(b.write(1, 0x50, &[0x0000, 0x1388]), Ok(()));
        let t = b.hid.0.written[2];
        assert_eq!(t[1], 0xB1);
        assert_eq!(t[2], 0, "profile: trajectory");
        assert_eq!(&t[20..24], &5000i32.to_le_bytes());
        assert_eq!(&t[24..28], &2000u32.to_le_bytes());
        assert_eq!(&t[28..32], &8000u32.to_le_bytes());
        assert_eq!(t[36], 0x05);
    }

    #[test]
    fn a_refused_command_names_its_usb_status() {
        let r = reply(0, 0, 2, 0x00, &[]);
        let mut b = bus(vec![vec![r]]);
        let e = b.write(1, 0x5E, &[0]).unwrap_err();
        assert_eq!(e.exit_code(), 3);
        assert!(e.to_string().contains("status 2: axis is asleep"), "{e}");
    }

    #[test]
    fn stream_reports_and_other_axes_replies_are_skipped() {
        let stream = reply(0, 0, 0, 0xA0, &[]);
        let other = reply(0, 1, 0, 0, &[]);
        let done = reply(0, 0, 0, 0, &[]);
        let mut b = bus(vec![vec![stream, other, done]]);
        assert_eq!(b.write(1, 0x5F, &[0]), Ok(()));
        assert_eq!(b.hid.0.written[0][1], 0xB2);
    }

    #[test]
    fn no_reply_is_a_communication_error() {
        let mut b = bus(vec![vec![]]);
        let e = b.read(1, 0x10, 1).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(
            e.to_string().contains("no reply from axis 1 on usb fake"),
            "{e}"
        );
    }

    #[test]
    fn a_step_mode_change_rewrites_the_driver_settings_through_0x80() {
        let r81 = reply(
            0xBA,
            0,
            0,
            0x81,
            &[
                (40, &[0x21, 0x03]),
                (42, &[123, 0]),
                (56, &[80]),
                (57, &[61, 3]),
                (61, &[1]),
                (62, &[4]),
            ],
        );
        let r80 = reply(0, 0, 0, 0, &[]);
        let mut b = bus(vec![vec![r81], vec![r80]]);
        assert_eq!(b.write(1, 0x33, &[2]), Ok(()));
        let w = b.hid.0.written[1];
        assert_eq!(w[1], 0x80);
        assert_eq!(le16(&w, 20), 0x0311, "MODE 2, ISGAIN and ENBL kept");
        assert_eq!((w[37], w[38], w[39], w[40], w[43]), (4, 80, 61, 3, 1));
    }

    #[test]
    fn registers_without_a_usb_command_are_refused_before_sending() {
        let mut b = bus(vec![]);
        assert_eq!(b.read(1, 0x45, 1).unwrap_err().exit_code(), 1);
        assert!(b.hid.0.written.is_empty());
    }
}
