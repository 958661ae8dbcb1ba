//! Settings of the PoStep60s (one per axis) and their persistence image.
//!
//! The image is what "Write settings to EEPROM" stores: a format byte, the
//! bridge-wide settings, then one fixed-size record per axis, all
//! little-endian. Decoding validates every field; an image with any field
//! out of range is rejected as a whole (the store's CRC already rules out
//! torn data, so an invalid field means a different firmware wrote it).

use super::current::Current;
use super::drv8711::{Drv8711Regs, REGISTERS as DRV_REGISTERS};
use crate::ioext::{IoSettings, IMAGE_LEN as IO_IMAGE_LEN};
use crate::powerstep::chain::MAX_DEVICES;

/// PoStep60 driver modes (manual 8.3.11).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DriverMode {
    /// 1: external step/dir.
    External = 1,
    /// 2: step control (USB 0x90 speed).
    StepControl = 2,
    /// 3: DC motor (not possible on a powerSTEP01).
    DcMotor = 3,
    /// 4: position control (trajectory).
    Position = 4,
    /// 5: BINx buttons.
    BinButtons = 5,
    /// 6: auto run (speed mode).
    AutoRun = 6,
}

impl DriverMode {
    pub const fn from_code(code: u8) -> Option<DriverMode> {
        match code {
            1 => Some(DriverMode::External),
            2 => Some(DriverMode::StepControl),
            3 => Some(DriverMode::DcMotor),
            4 => Some(DriverMode::Position),
            5 => Some(DriverMode::BinButtons),
            6 => Some(DriverMode::AutoRun),
            _ => None,
        }
    }
    pub const fn code(self) -> u8 {
        self as u8
    }
}

/// Modbus serial settings (USB 0x80 byte 44 codes 0..=5).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Parity {
    Even,
    Odd,
    /// No parity, two stop bits.
    None,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Serial {
    pub baud: u32,
    pub parity: Parity,
}

impl Serial {
    pub const DEFAULT: Serial = Serial {
        baud: 9600,
        parity: Parity::Even,
    };
    /// Manual code: 0 9600E, 1 9600O, 2 9600N, 3 19200E, 4 19200O, 5 19200N.
    pub const fn from_code(code: u8) -> Option<Serial> {
        let baud = match code / 3 {
            0 => 9600,
            1 => 19200,
            _ => return None,
        };
        let parity = match code % 3 {
            0 => Parity::Even,
            1 => Parity::Odd,
            _ => Parity::None,
        };
        Some(Serial { baud, parity })
    }
    pub const fn code(self) -> u8 {
        let b: u8 = if self.baud == 19200 { 3 } else { 0 };
        b.saturating_add(match self.parity {
            Parity::Even => 0,
            Parity::Odd => 1,
            Parity::None => 2,
        })
    }
}

/// Length of the custom name (USB 0xC0/0xC1).
pub const NAME_LEN: usize = 32;

/// Settings of one PoStep60 (one axis).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AxisSettings {
    pub full_scale: Current,
    pub idle: Current,
    pub overheat: Current,
    /// PoStep60 step mode: 0 = full … 8 = 1/256.
    pub step_mode: u8,
    /// °C (0..=120).
    pub temperature_limit: u8,
    pub mode: DriverMode,
    /// Motion profile, logical steps/s and steps/s².
    pub max_speed: u32,
    pub acc: u32,
    pub dec: u32,
    /// Auto run requested speed, steps/s (USB writes 32 bits; I2C and
    /// Modbus 16).
    pub requested_speed: u32,
    pub invert: bool,
    pub end_switch: bool,
    /// End switch is normally closed (else normally open).
    pub end_switch_nc: bool,
    pub bin1_steps: i32,
    pub bin2_steps: i32,
    pub name: [u8; NAME_LEN],
    /// The DRV8711 register image as stored (USB 0x80; see `drv8711`).
    pub drv: Drv8711Regs,
    /// powerSTEP01 tuning registers written through the extension space.
    pub tuning: Tuning,
    /// Homing parameters (extension).
    pub homing: HomingSettings,
}

/// The powerSTEP01 registers a user may tune through the extension space
/// (0x01nn), persisted and written again after every chip reset. Each is
/// `None` until written: the chip keeps its reset value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Tuning {
    values: [Option<u16>; TUNABLE.len()],
}

/// The tunable registers, in image order.
pub const TUNABLE: [crate::powerstep::registers::Register; 13] = {
    use crate::powerstep::registers::Register as R;
    [
        R::MinSpeed,
        R::IntSpeed,
        R::StSlp,
        R::FnSlpAcc,
        R::FnSlpDec,
        R::KTherm,
        R::OcdTh,
        R::StallTh,
        R::FsSpd,
        R::AlarmEn,
        R::GateCfg1,
        R::GateCfg2,
        R::Config,
    ]
};

impl Tuning {
    fn slot(reg: crate::powerstep::registers::Register) -> Option<usize> {
        TUNABLE.iter().position(|r| *r == reg)
    }

    /// The value written for `reg`, if it is tunable and was written.
    pub fn get(&self, reg: crate::powerstep::registers::Register) -> Option<u16> {
        self.values.get(Self::slot(reg)?).copied().flatten()
    }

    /// Store `value` for a tunable register; false if `reg` is not one.
    pub fn set(&mut self, reg: crate::powerstep::registers::Register, value: u16) -> bool {
        match Self::slot(reg).and_then(|i| self.values.get_mut(i)) {
            Some(slot) => {
                *slot = Some(value);
                true
            }
            None => false,
        }
    }

    /// Every written (register, value).
    pub fn iter(&self) -> impl Iterator<Item = (crate::powerstep::registers::Register, u16)> + '_ {
        TUNABLE
            .iter()
            .zip(self.values.iter())
            .filter_map(|(r, v)| v.map(|v| (*r, v)))
    }
}

/// Homing parameters of one axis (logical steps of its step mode).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HomingSettings {
    /// Search toward the switch forward (else reverse).
    pub forward: bool,
    /// Search speed, logical steps/s.
    pub search_speed: u32,
    /// Back-off speed, logical steps/s (at least 5 full steps/s: the
    /// chip's ReleaseSW floor).
    pub release_speed: u32,
    /// Fail beyond this travel, logical steps (0: no limit).
    pub max_travel: u32,
    /// Fail after this many seconds (0: no limit).
    pub timeout_s: u16,
}

impl HomingSettings {
    pub const FACTORY: HomingSettings = HomingSettings {
        forward: false,
        search_speed: 1600,
        release_speed: 80,
        max_travel: 0,
        timeout_s: 60,
    };
    const LEN: usize = 1 + 4 * 3 + 2;
}

/// What the communication watchdog does when a bus has been silent too long.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WatchdogAction {
    /// Stop at once and hold (HardStop).
    Hold = 0,
    /// Decelerate to a stop with the deceleration ramp.
    SoftStop = 1,
    /// Bridges off (as Run/Sleep's sleep).
    HiZ = 2,
}

impl WatchdogAction {
    pub const fn from_code(c: u8) -> Option<WatchdogAction> {
        match c {
            0 => Some(WatchdogAction::Hold),
            1 => Some(WatchdogAction::SoftStop),
            2 => Some(WatchdogAction::HiZ),
            _ => None,
        }
    }
}

/// The communication watchdog of one bus: off when `timeout_ms` is 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Watchdog {
    pub timeout_ms: u16,
    pub action: WatchdogAction,
}

impl Watchdog {
    pub const OFF: Watchdog = Watchdog {
        timeout_ms: 0,
        action: WatchdogAction::SoftStop,
    };
}

/// Buses the watchdog watches, in this order.
pub const WATCHED_BUSES: usize = 3;

/// Highest temperature limit (USB 0x80 byte 38: "max.: 120").
pub const TEMPERATURE_LIMIT_MAX: u8 = 120;

impl AxisSettings {
    /// Factory settings (the product rules (`docs/PRODUCT.md`): mode 4, position control).
    pub const FACTORY: AxisSettings = AxisSettings {
        full_scale: Current::from_milliamps(1000),
        idle: Current::from_milliamps(500),
        overheat: Current::from_milliamps(500),
        step_mode: 4,
        temperature_limit: 80,
        mode: DriverMode::Position,
        max_speed: 1000,
        acc: 1000,
        dec: 1000,
        requested_speed: 0,
        invert: false,
        end_switch: false,
        end_switch_nc: false,
        bin1_steps: 100,
        bin2_steps: -100,
        name: *b"stepbridge axis\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0",
        drv: Drv8711Regs::RESET,
        tuning: Tuning {
            values: [None; TUNABLE.len()],
        },
        homing: HomingSettings::FACTORY,
    };

    /// Bytes of an axis record in image format 1 (16-bit requested speed, no
    /// DRV8711 image) and in format 2.
    const RECORD_V1: usize = 2 * 3 + 1 + 1 + 1 + 4 * 3 + 2 + 1 + 4 * 2 + NAME_LEN;
    const RECORD: usize =
        Self::RECORD_V1 + 2 + 2 * DRV_REGISTERS + 2 + 2 * TUNABLE.len() + HomingSettings::LEN;

    fn encode(&self, out: &mut [u8]) {
        let mut w = Writer { out, at: 0 };
        for c in [self.full_scale, self.idle, self.overheat] {
            w.bytes(&c.to_bytes());
        }
        w.bytes(&[self.step_mode, self.temperature_limit, self.mode.code()]);
        for v in [self.max_speed, self.acc, self.dec] {
            w.bytes(&v.to_le_bytes());
        }
        w.bytes(&self.requested_speed.to_le_bytes());
        let flags = u8::from(self.invert)
            | u8::from(self.end_switch) << 1
            | u8::from(self.end_switch_nc) << 2;
        w.bytes(&[flags]);
        w.bytes(&self.bin1_steps.to_le_bytes());
        w.bytes(&self.bin2_steps.to_le_bytes());
        w.bytes(&self.name);
        for r in self.drv.0 {
            w.bytes(&r.to_le_bytes());
        }
        let mask = self
            .tuning
            .values
            .iter()
            .enumerate()
            .fold(0u16, |m, (i, v)| if v.is_some() { m | 1 << i } else { m });
        w.bytes(&mask.to_le_bytes());
        for v in self.tuning.values {
            w.bytes(&v.unwrap_or(0).to_le_bytes());
        }
        let h = &self.homing;
        w.bytes(&[u8::from(h.forward)]);
        for v in [h.search_speed, h.release_speed, h.max_travel] {
            w.bytes(&v.to_le_bytes());
        }
        w.bytes(&h.timeout_s.to_le_bytes());
    }

    /// Decode a record of image format `format` (1 or 2).
    fn decode(input: &[u8], format: u8) -> Option<AxisSettings> {
        let mut r = Reader { input, at: 0 };
        let mut current = || -> Option<Current> {
            let c = Current {
                tq: r.u8()?,
                ai: r.u8()?,
            };
            c.milliamps().map(|_| c)
        };
        let full_scale = current()?;
        let idle = current()?;
        let overheat = current()?;
        let step_mode = r.u8().filter(|m| *m <= 8)?;
        let temperature_limit = r.u8().filter(|t| *t <= TEMPERATURE_LIMIT_MAX)?;
        let mode = DriverMode::from_code(r.u8()?)?;
        let max_speed = r.u32()?;
        let acc = r.u32()?;
        let dec = r.u32()?;
        let requested_speed = if format == 1 {
            u32::from(r.u16()?)
        } else {
            r.u32()?
        };
        let flags = r.u8().filter(|f| *f < 8)?;
        let bin1_steps = r.u32()? as i32;
        let bin2_steps = r.u32()? as i32;
        let mut name = [0u8; NAME_LEN];
        name.copy_from_slice(r.take(NAME_LEN)?);
        let mut drv = Drv8711Regs::RESET;
        let mut tuning = Tuning::default();
        let mut homing = HomingSettings::FACTORY;
        if format >= 2 {
            for slot in drv.0.iter_mut() {
                *slot = r.u16().filter(|v| *v <= 0x0FFF)?;
            }
            let mask = r.u16().filter(|m| *m < 1 << TUNABLE.len())?;
            for (i, (slot, reg)) in tuning.values.iter_mut().zip(TUNABLE).enumerate() {
                let v = r.u16()?;
                if mask & 1 << i != 0 {
                    if u32::from(v) & !reg.mask() != 0 {
                        return None;
                    }
                    *slot = Some(v);
                }
            }
            homing = HomingSettings {
                forward: r.u8().filter(|b| *b <= 1)? == 1,
                search_speed: r.u32()?,
                release_speed: r.u32()?,
                max_travel: r.u32()?,
                timeout_s: r.u16()?,
            };
        }
        Some(AxisSettings {
            full_scale,
            idle,
            overheat,
            step_mode,
            temperature_limit,
            mode,
            max_speed,
            acc,
            dec,
            requested_speed,
            invert: flags & 1 != 0,
            end_switch: flags & 2 != 0,
            end_switch_nc: flags & 4 != 0,
            bin1_steps,
            bin2_steps,
            name,
            drv,
            tuning,
            homing,
        })
    }
}

/// Settings of the whole bridge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// Address of axis 0 (I2C and Modbus); axis k answers `base + k`.
    pub base_address: u8,
    pub serial: Serial,
    pub axes: [AxisSettings; MAX_DEVICES],
    /// Communication watchdog per bus: Modbus, I2C, USB (extension).
    pub watchdog: [Watchdog; WATCHED_BUSES],
    /// The SPI I/O extension: enable, configuration, transmit data, mapping.
    pub io: IoSettings,
}

/// Image format written by this firmware. Format 1 (without the DRV8711
/// image, 16-bit requested speed) still loads.
pub const IMAGE_FORMAT: u8 = 2;
/// Bytes of a settings image: header, the watchdogs, the axes, the I/O
/// extension.
pub const IMAGE_LEN: usize =
    3 + 3 * WATCHED_BUSES + MAX_DEVICES * AxisSettings::RECORD + IO_IMAGE_LEN;
/// Where the I/O extension's image starts.
const IO_AT: usize = IMAGE_LEN - IO_IMAGE_LEN;
/// Bytes of a format-1 image.
pub const IMAGE_LEN_V1: usize = 3 + MAX_DEVICES * AxisSettings::RECORD_V1;
const _: () = assert!(
    IMAGE_LEN <= crate::persist::MAX_IMAGE,
    "image must fit the store"
);

/// Why an image was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageError {
    /// Another image format (written by other firmware).
    Format(u8),
    /// Wrong length or a field out of range.
    Invalid,
}

impl Settings {
    pub const FACTORY: Settings = Settings {
        base_address: 1,
        serial: Serial::DEFAULT,
        axes: [AxisSettings::FACTORY; MAX_DEVICES],
        watchdog: [Watchdog::OFF; WATCHED_BUSES],
        io: IoSettings::FACTORY,
    };

    // Writes our own image into a fixed-size array at the layout's constant
    // offsets (each region ends at or before IMAGE_LEN: see the layout's
    // const assertions), no input involved.
    #[allow(clippy::indexing_slicing)]
    pub fn to_image(&self, out: &mut [u8; IMAGE_LEN]) {
        out[0] = IMAGE_FORMAT;
        out[1] = self.base_address;
        out[2] = self.serial.code();
        for (w, chunk) in self.watchdog.iter().zip(out[3..].chunks_exact_mut(3)) {
            let [t0, t1] = w.timeout_ms.to_le_bytes();
            chunk.copy_from_slice(&[t0, t1, w.action as u8]);
        }
        let axes = 3 + 3 * WATCHED_BUSES;
        for (axis, chunk) in self
            .axes
            .iter()
            .zip(out[axes..IO_AT].chunks_exact_mut(AxisSettings::RECORD))
        {
            axis.encode(chunk);
        }
        let mut io = [0u8; IO_IMAGE_LEN];
        self.io.encode(&mut io);
        out[IO_AT..].copy_from_slice(&io);
    }

    pub fn from_image(image: &[u8]) -> Result<Settings, ImageError> {
        let (&format, rest) = image.split_first().ok_or(ImageError::Invalid)?;
        let (len, record) = match format {
            1 => (IMAGE_LEN_V1, AxisSettings::RECORD_V1),
            IMAGE_FORMAT => (IMAGE_LEN, AxisSettings::RECORD),
            other => return Err(ImageError::Format(other)),
        };
        if image.len() != len {
            return Err(ImageError::Invalid);
        }
        let (&base_address, rest) = rest.split_first().ok_or(ImageError::Invalid)?;
        let (&serial, rest) = rest.split_first().ok_or(ImageError::Invalid)?;
        // Axis 0's address: an I2C address (1..=127), as 0x04 sets it.
        if !(1..=127).contains(&base_address) {
            return Err(ImageError::Invalid);
        }
        let serial = Serial::from_code(serial).ok_or(ImageError::Invalid)?;
        let mut watchdog = [Watchdog::OFF; WATCHED_BUSES];
        let rest = if format >= 2 {
            let (wd, rest) = rest
                .split_at_checked(3 * WATCHED_BUSES)
                .ok_or(ImageError::Invalid)?;
            for (w, chunk) in watchdog.iter_mut().zip(wd.chunks_exact(3)) {
                let &[t0, t1, a] = chunk else {
                    return Err(ImageError::Invalid);
                };
                *w = Watchdog {
                    timeout_ms: u16::from_le_bytes([t0, t1]),
                    action: WatchdogAction::from_code(a).ok_or(ImageError::Invalid)?,
                };
            }
            rest
        } else {
            rest
        };
        let mut axes = [AxisSettings::FACTORY; MAX_DEVICES];
        let (records, io) = rest
            .split_at_checked(MAX_DEVICES.saturating_mul(record))
            .ok_or(ImageError::Invalid)?;
        for (axis, chunk) in axes.iter_mut().zip(records.chunks_exact(record)) {
            *axis = AxisSettings::decode(chunk, format).ok_or(ImageError::Invalid)?;
        }
        let io = if format >= 2 {
            IoSettings::decode(io).map_err(|_| ImageError::Invalid)?
        } else {
            IoSettings::FACTORY
        };
        Ok(Settings {
            base_address,
            serial,
            axes,
            watchdog,
            io,
        })
    }
}

struct Writer<'a> {
    out: &'a mut [u8],
    at: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) {
        let end = self.at.saturating_add(b.len());
        if let Some(dst) = self.out.get_mut(self.at..end) {
            dst.copy_from_slice(b);
        }
        self.at = end;
    }
}

struct Reader<'a> {
    input: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.at.checked_add(n)?;
        let s = self.input.get(self.at..end)?;
        self.at = end;
        Some(s)
    }
    fn u8(&mut self) -> Option<u8> {
        self.take(1)?.first().copied()
    }
    fn u16(&mut self) -> Option<u16> {
        let b = self.take(2)?;
        Some(u16::from_le_bytes([*b.first()?, *b.get(1)?]))
    }
    fn u32(&mut self) -> Option<u32> {
        let b = self.take(4)?;
        let mut a = [0u8; 4];
        a.copy_from_slice(b);
        Some(u32::from_le_bytes(a))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec;
    use std::vec::Vec;

    #[test]
    fn factory_image_round_trips() {
        let mut img = [0u8; IMAGE_LEN];
        Settings::FACTORY.to_image(&mut img);
        assert_eq!(Settings::from_image(&img), Ok(Settings::FACTORY));
    }

    #[test]
    fn every_field_survives_the_image() {
        let mut s = Settings::FACTORY;
        s.base_address = 127;
        s.serial = Serial::from_code(5).unwrap();
        s.axes[3] = AxisSettings {
            full_scale: Current { tq: 184, ai: 1 },
            idle: Current { tq: 10, ai: 3 },
            overheat: Current { tq: 99, ai: 2 },
            step_mode: 8,
            temperature_limit: 120,
            mode: DriverMode::AutoRun,
            max_speed: 65_535,
            acc: 1,
            dec: 4_000_000,
            requested_speed: 4_000_000,
            invert: true,
            end_switch: true,
            end_switch_nc: true,
            bin1_steps: i32::MIN,
            bin2_steps: i32::MAX,
            name: [b'x'; NAME_LEN],
            drv: Drv8711Regs([0xFFF, 0, 1, 2, 3, 4, 5, 0]),
            tuning: {
                let mut t = Tuning::default();
                t.set(crate::powerstep::registers::Register::OcdTh, 0x1F);
                t.set(crate::powerstep::registers::Register::Config, 0xFFFF);
                t
            },
            homing: HomingSettings {
                forward: true,
                search_speed: u32::MAX,
                release_speed: 7,
                max_travel: 123_456,
                timeout_s: 9,
            },
        };
        s.watchdog[1] = Watchdog {
            timeout_ms: 65_535,
            action: WatchdogAction::HiZ,
        };
        let mut img = [0u8; IMAGE_LEN];
        s.to_image(&mut img);
        assert_eq!(Settings::from_image(&img), Ok(s));
    }

    #[test]
    fn other_formats_and_out_of_range_fields_are_rejected() {
        let mut img = [0u8; IMAGE_LEN];
        Settings::FACTORY.to_image(&mut img);
        let mut other = img;
        other[0] = 3;
        assert_eq!(Settings::from_image(&other), Err(ImageError::Format(3)));
        let mut bad_mode = img;
        bad_mode[3 + 8] = 7; // mode of axis 0 (after 3 currents, step mode, limit)
        assert_eq!(Settings::from_image(&bad_mode), Err(ImageError::Invalid));
        assert_eq!(
            Settings::from_image(&img[..IMAGE_LEN - 1]),
            Err(ImageError::Invalid)
        );
        assert_eq!(Settings::from_image(&[]), Err(ImageError::Invalid));
    }

    /// A format-1 image as the previous firmware wrote it (built here by
    /// hand, byte by byte, from that format's layout).
    fn v1_image(s: &Settings) -> Vec<u8> {
        let mut out = vec![1, s.base_address, s.serial.code()];
        for a in s.axes.iter() {
            for c in [a.full_scale, a.idle, a.overheat] {
                out.extend_from_slice(&[c.tq, c.ai]);
            }
            out.extend_from_slice(&[a.step_mode, a.temperature_limit, a.mode.code()]);
            for v in [a.max_speed, a.acc, a.dec] {
                out.extend_from_slice(&v.to_le_bytes());
            }
            out.extend_from_slice(&(a.requested_speed as u16).to_le_bytes());
            out.push(
                u8::from(a.invert) | u8::from(a.end_switch) << 1 | u8::from(a.end_switch_nc) << 2,
            );
            out.extend_from_slice(&a.bin1_steps.to_le_bytes());
            out.extend_from_slice(&a.bin2_steps.to_le_bytes());
            out.extend_from_slice(&a.name);
        }
        out
    }

    #[test]
    fn an_image_of_the_previous_format_still_loads() {
        let mut s = Settings::FACTORY;
        s.base_address = 17;
        s.axes[1].requested_speed = 777;
        s.axes[1].name = *b"axis one on the left bench\0\0\0\0\0\0";
        let img = v1_image(&s);
        assert_eq!(img.len(), IMAGE_LEN_V1);
        let loaded = Settings::from_image(&img).expect("format 1 loads");
        // Everything it held, and the DRV8711 image at its reset values.
        assert_eq!(loaded, s);
        assert_eq!(loaded.axes[1].drv, Drv8711Regs::RESET);
    }

    #[test]
    fn serial_codes_match_the_manual() {
        assert_eq!(
            Serial::from_code(0),
            Some(Serial {
                baud: 9600,
                parity: Parity::Even
            })
        );
        assert_eq!(
            Serial::from_code(2),
            Some(Serial {
                baud: 9600,
                parity: Parity::None
            })
        );
        assert_eq!(
            Serial::from_code(4),
            Some(Serial {
                baud: 19200,
                parity: Parity::Odd
            })
        );
        assert_eq!(Serial::from_code(6), None);
        for c in 0..6 {
            assert_eq!(Serial::from_code(c).unwrap().code(), c);
        }
    }

    #[test]
    fn random_images_never_panic() {
        let mut x = 0x1234_5678_u32;
        let mut img = [0u8; IMAGE_LEN];
        for _ in 0..2000 {
            for b in img.iter_mut() {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                *b = x as u8;
            }
            img[0] = IMAGE_FORMAT;
            let _ = Settings::from_image(&img);
        }
    }
}
