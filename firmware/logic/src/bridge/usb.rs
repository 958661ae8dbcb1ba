//! The bridge as the PoStep60 USB device: every OUT report is executed by
//! the same device models as I2C and Modbus, and answered with the IN
//! report of manual 10.2 (byte layouts in `transport::usb::codec`).
//!
//! # What it guarantees
//!
//! * **Axis**: `OutDATA[62]` selects the axis (0 from a zero-filled
//!   PoStep60 buffer); an axis the chain does not have gets the command's
//!   response with `InDATA[14]` = 9 and no effect.
//! * **Outcome**: every response carries the axis in `InDATA[13]` and what
//!   happened in `InDATA[14]` (0 = done; see `codec::status`) — bytes the
//!   manual leaves unused. A refused command changes nothing.
//! * **Bad reports** (not 64 bytes, `OutDATA[63]` ≠ 0, an unknown command,
//!   0xDF without its magic) are ignored and counted; they get no response
//!   and move nothing.
//! * **Saving**: 0x80 applies the driver settings and stores every setting;
//!   0x87 (save other configurations) and 0xC0 (custom name) store too —
//!   through the same deferred, power-cut-safe save as Write settings
//!   (refused, `InDATA[14]` = 7, while an axis moves). 0x83 erases: every
//!   axis stops, factory settings apply and are stored. 0x84 reads what the
//!   store holds; 0x81 and 0x85 what is in use.
//! * **Stream (0xA0)**: after 0xA0 the bridge sends the selected axis's
//!   data-stream report every [`STREAM_PERIOD_MS`] ms (the IN endpoint's
//!   bInterval) until 0xA2 (extension), a bus reset, or a restart. A command
//!   response goes before a due stream report; the stream then goes on at
//!   its own cadence. Responses wait in a queue of [`QUEUE`]; when a host
//!   does not read, the oldest is dropped and counted.
//! * **0x02** (manual: "send twice; once starts the bootloader"): in the
//!   application every axis stops and the firmware restarts into its boot
//!   mode ([`RunMode::Boot`]: HID answers, 0x01 reports DEVICE_MODE 0xB0,
//!   no motion, bridges off); 0x02 there restarts the application. No
//!   response (the device restarts). 0xDF + "DFU!" restarts into ST's ROM
//!   DFU bootloader the same way.

use heapless::Deque;

use super::{Bridge, Bus, ExtError, ResetTarget, RunMode};
use crate::postep60::drv8711::Drv8711Regs;
use crate::postep60::settings::{DriverMode, Serial, Settings};
use crate::postep60::{CommandError, Query, Request, Value};
use crate::powerstep::chain::ChainBus;
use crate::transport::usb::codec::{cmd, status, DriverSettings, InReport, EXT_MAX};
use crate::transport::usb::{decode, iap_uid, UsbError, UsbRequest};

/// The 0xA0 stream's period: the IN endpoint's bInterval.
pub const STREAM_PERIOD_MS: u64 = crate::transport::usb::IN_INTERVAL_MS as u64;
/// Responses kept for the host.
pub const QUEUE: usize = 4;

/// DEVICE_MODE of the 0x01 reply.
const DEVICE_MODE_APPLICATION: u8 = 0xAB;
const DEVICE_MODE_BOOT: u8 = 0xB0;

/// An extension read waiting for the chip.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PendingRead {
    axis: u8,
    address: u16,
    quantity: u8,
    since_ms: u64,
}

/// An extension read gives up after this long (status 13).
pub const EXT_READ_TIMEOUT_MS: u64 = 50;

#[derive(Clone, Debug, Default)]
pub(super) struct UsbState {
    out: Deque<InReport, QUEUE>,
    pending_read: Option<PendingRead>,
    /// The streamed axis and when its next report is due.
    stream: Option<(u8, u64)>,
    /// A stream report built for `usb_next`, not yet sent.
    stream_report: Option<InReport>,
}

/// `InDATA[14]` of a refusal: the reason's code ([`CommandError::code`],
/// the same numbers as [`status`]'s).
fn status_of(e: CommandError) -> u8 {
    e.code()
}

fn ext_status(r: Result<(), ExtError>) -> u8 {
    match r {
        Ok(()) => status::DONE,
        Err(ExtError::IllegalAddress) => status::ILLEGAL_ADDRESS,
        Err(ExtError::IllegalValue) => status::ILLEGAL_VALUE,
        Err(ExtError::Refused) => status::REFUSED,
        Err(ExtError::NotYet) => status::TIMEOUT,
    }
}

/// The PoStep60-facing firmware version as one u16 (major·256 + minor),
/// MSB first on the wire (`POSTEP60_FW_VERSION`).
const fn app_version() -> u16 {
    let (major, minor) = crate::postep60::device::POSTEP60_FW_VERSION;
    (major as u16) << 8 | minor as u16
}

impl<B: ChainBus> Bridge<B> {
    /// An OUT report (from the OUT endpoint or a SET_REPORT) at `now_ms`.
    pub fn on_usb_report(&mut self, report: &[u8], now_ms: u64) {
        let (req, axis) = match decode(report) {
            Ok(d) => d,
            Err(UsbError::Unknown(_)) => {
                self.diag.usb_unknown = self.diag.usb_unknown.saturating_add(1);
                return;
            }
            Err(_) => {
                self.diag.usb_bad = self.diag.usb_bad.saturating_add(1);
                return;
            }
        };
        self.diag.usb_reports = self.diag.usb_reports.saturating_add(1);
        self.heard(Bus::Usb);
        if let Some(response) = self.respond(req, axis, now_ms) {
            self.queue(response);
        }
    }

    /// The response to a well-formed OUT report for `axis` (None: there is
    /// none, or not yet).
    fn respond(&mut self, req: UsbRequest, axis: u8, now_ms: u64) -> Option<InReport> {
        let k = usize::from(axis);
        let exists = self.usb_axis_exists(k, &req);
        Some(match req {
            UsbRequest::SystemReset => {
                let target = match self.run_mode {
                    RunMode::Application => ResetTarget::BootMode,
                    RunMode::Boot => ResetTarget::Application,
                };
                self.request_reset(target);
                return None;
            }
            UsbRequest::EnterDfu => {
                self.request_reset(ResetTarget::RomDfu);
                return None;
            }
            UsbRequest::DeviceInfo => self.device_info(axis),
            UsbRequest::StreamOff => {
                self.usb.stream = None;
                self.usb.stream_report = None;
                InReport::new(0, cmd::STREAM_OFF, axis, status::DONE)
            }
            _ if !exists => InReport::new(0, 0, axis, status::NO_AXIS),
            UsbRequest::StreamOn => {
                self.usb.stream = Some((axis, now_ms.saturating_add(STREAM_PERIOD_MS)));
                InReport::new(0, 0x00, axis, status::DONE)
            }
            UsbRequest::WriteDriverSettings(d) => {
                let st = self.write_driver_settings(k, d);
                InReport::new(0, 0x00, axis, st)
            }
            UsbRequest::ReadDriverSettings => self.driver_report(k, axis, 0xBA, 0x81, false),
            UsbRequest::ReadDriverRegisters => self.driver_report(k, axis, 0xBC, 0x00, true),
            UsbRequest::ReadEeprom => self.eeprom_report(k, axis),
            UsbRequest::EraseEeprom => {
                let st = self.erase();
                InReport::new(0, 0x00, axis, st)
            }
            UsbRequest::ReadOther => self.other_report(k, axis),
            UsbRequest::WriteName(name) => self.write_name(k, axis, name),
            UsbRequest::ReadName => self.name_report(k, axis),
            UsbRequest::ExtRead { address, quantity } => {
                self.usb.pending_read = Some(PendingRead {
                    axis,
                    address,
                    quantity,
                    since_ms: now_ms,
                });
                self.try_ext_read(now_ms)?
            }
            UsbRequest::ExtWrite {
                address,
                quantity,
                data,
            } => self.ext_write_report(k, axis, address, &data, quantity),
            other => {
                let (req, response) = Self::device_request(other)?;
                self.simple(k, axis, req, response)
            }
        })
    }

    /// Whether a report for axis `k` has an axis to go to. With no chip
    /// detected, axis 0 still takes extension requests (the bridge-scope
    /// blocks answer; an axis's are refused by `ext_read`).
    fn usb_axis_exists(&self, k: usize, req: &UsbRequest) -> bool {
        k < self.axes()
            || (k == 0
                && self.axes() == 0
                && matches!(
                    req,
                    UsbRequest::ExtRead { .. } | UsbRequest::ExtWrite { .. }
                ))
    }

    /// 0xC1: the axis's name.
    fn name_report(&self, k: usize, axis: u8) -> InReport {
        let mut r = InReport::new(0, cmd::WRITE_NAME, axis, status::DONE);
        if let Some(d) = self.devices.get(k) {
            r.put(16, &d.settings.name);
        }
        r
    }

    /// The extension write: the first `quantity` registers of `data`.
    fn ext_write_report(
        &mut self,
        k: usize,
        axis: u8,
        address: u16,
        data: &[u16],
        quantity: u8,
    ) -> InReport {
        let r = match data.get(..usize::from(quantity)).filter(|d| !d.is_empty()) {
            Some(d) => self.ext_write_from(Bus::Usb, k, address, d),
            None => Err(ExtError::IllegalValue),
        };
        InReport::new(0, cmd::EXT_WRITE, axis, ext_status(r))
    }

    /// A report that is one PoStep60 request for the axis and answers with
    /// the command's response byte: the request and that byte.
    fn device_request(req: UsbRequest) -> Option<(Request, u8)> {
        Some(match req {
            UsbRequest::ResetFaults => (Request::ResetFaults, 0x00),
            UsbRequest::SaveOther => (Request::WriteSettings, 0x00),
            UsbRequest::StepDir {
                step_value,
                reverse,
            } => (
                Request::StepDir {
                    step_value,
                    reverse,
                },
                cmd::STEP_DIR,
            ),
            // USB: 0x01 run, 0x00 sleep (I2C's 0xDA / 0x0F); others are
            // ignored like I2C's other values.
            UsbRequest::RunSleep(0x01) => (Request::RunSleep(0xDA), 0x00),
            UsbRequest::RunSleep(0x00) => (Request::RunSleep(0x0F), 0x00),
            UsbRequest::RunSleep(_) => (Request::RunSleep(0x00), 0x00),
            UsbRequest::SetPwm => (Request::SetPwm, cmd::SET_PWM),
            UsbRequest::Trajectory(t) => (Request::Trajectory(t), cmd::TRAJECTORY),
            UsbRequest::Stop => (Request::Stop, 0x00),
            UsbRequest::Zero => (Request::SetZero, 0x00),
            _ => return None,
        })
    }

    /// 0xC0: the custom name, stored at once (the manual's "write").
    fn write_name(
        &mut self,
        k: usize,
        axis: u8,
        name: [u8; crate::postep60::settings::NAME_LEN],
    ) -> InReport {
        let st = self.status(k, Request::SetName(name));
        let st = if st == status::DONE {
            self.status(k, Request::WriteSettings)
        } else {
            st
        };
        InReport::new(0, 0x00, axis, st)
    }

    /// Answer the waiting extension read if the chip's value came back (or
    /// the wait is over); None while it still waits.
    fn try_ext_read(&mut self, now_ms: u64) -> Option<InReport> {
        let p = self.usb.pending_read?;
        let mut regs = [0u16; EXT_MAX];
        let n = usize::from(p.quantity);
        let r = match regs.get_mut(..n).filter(|r| !r.is_empty()) {
            Some(regs) => self.ext_read(usize::from(p.axis), p.address, regs),
            None => Err(ExtError::IllegalValue),
        };
        let st = match r {
            Err(ExtError::NotYet) if now_ms.saturating_sub(p.since_ms) < EXT_READ_TIMEOUT_MS => {
                return None
            }
            Err(ExtError::NotYet) => status::TIMEOUT,
            other => ext_status(other),
        };
        self.usb.pending_read = None;
        let mut out = InReport::new(0, cmd::EXT_READ, p.axis, st);
        if st == status::DONE {
            for (i, v) in regs.iter().take(n).enumerate() {
                out.be16(16usize.saturating_add(i.saturating_mul(2)), *v);
            }
        }
        Some(out)
    }

    /// The USB bus was reset, suspended or deconfigured: the stream ends,
    /// unread responses are dropped.
    pub fn on_usb_reset(&mut self) {
        self.usb = UsbState::default();
    }

    /// The next IN report to send at `now_ms` (a queued response first, else
    /// the stream's report when due), without taking it: call
    /// [`Bridge::usb_sent`] once the endpoint took it.
    pub fn usb_next(&mut self, now_ms: u64) -> Option<&InReport> {
        if self.usb.pending_read.is_some() {
            if let Some(r) = self.try_ext_read(now_ms) {
                self.queue(r);
            }
        }
        if self.usb.out.is_empty() && self.usb.stream_report.is_none() {
            if let Some((axis, due)) = self.usb.stream {
                if now_ms >= due {
                    let next = due.saturating_add(STREAM_PERIOD_MS);
                    let next = if next <= now_ms {
                        now_ms.saturating_add(STREAM_PERIOD_MS)
                    } else {
                        next
                    };
                    self.usb.stream = Some((axis, next));
                    self.usb.stream_report = Some(self.stream_report(axis));
                }
            }
        }
        self.usb.out.front().or(self.usb.stream_report.as_ref())
    }

    /// The report [`Bridge::usb_next`] returned went out.
    pub fn usb_sent(&mut self) {
        if self.usb.out.pop_front().is_none() {
            self.usb.stream_report = None;
        }
    }

    /// Whether the 0xA0 stream runs (and for which axis).
    pub fn usb_stream(&self) -> Option<u8> {
        self.usb.stream.map(|(a, _)| a)
    }

    fn queue(&mut self, r: InReport) {
        if self.usb.out.is_full() {
            let _ = self.usb.out.pop_front();
            self.diag.usb_dropped = self.diag.usb_dropped.saturating_add(1);
        }
        let _ = self.usb.out.push_back(r);
    }

    fn status(&mut self, k: usize, req: Request) -> u8 {
        match self.request_from(Bus::Usb, k, req) {
            Ok(_) => status::DONE,
            Err(e) => status_of(e),
        }
    }

    /// Execute `req` and answer with the manual's plain response.
    fn simple(&mut self, k: usize, axis: u8, req: Request, response: u8) -> InReport {
        let st = self.status(k, req);
        InReport::new(0, response, axis, st)
    }

    fn u16_query(&self, k: usize, q: Query) -> u16 {
        match self.query(k, q) {
            Some(Value::U16(v)) => v,
            Some(Value::U8(v)) => u16::from(v),
            _ => 0,
        }
    }

    fn pins(&self, k: usize) -> u8 {
        match self.query(k, Query::Pins) {
            Some(Value::U8(p)) => p,
            _ => 0,
        }
    }

    /// Bytes 6 and 8..9, common to the info-like replies.
    fn put_pins_and_voltage(&self, r: &mut InReport, k: usize) {
        r.u8(6, self.pins(k));
        r.be16(8, self.supply);
    }

    fn device_info(&self, axis: u8) -> InReport {
        let k = usize::from(axis);
        let mut r = InReport::new(0, 0x00, axis, status::DONE);
        // [1..2] bootloader version, [3..4] application version: one firmware.
        r.be16(1, app_version());
        r.be16(3, app_version());
        r.u8(
            5,
            match self.run_mode {
                RunMode::Application => DEVICE_MODE_APPLICATION,
                RunMode::Boot => DEVICE_MODE_BOOT,
            },
        );
        self.put_pins_and_voltage(&mut r, k);
        r.u8(15, 0x00);
        for (i, w) in iap_uid(self.uid).iter().enumerate() {
            r.be32(24usize.saturating_add(i.saturating_mul(4)), *w);
        }
        r.be16(44, self.temperature);
        r.u8(46, self.u16_query(k, Query::DriverStatus) as u8);
        r
    }

    /// 0x81 (in use, with CONFIG_SET) and 0x85 (the live registers).
    fn driver_report(&self, k: usize, axis: u8, id: u8, response: u8, live: bool) -> InReport {
        let mut r = InReport::new(id, response, axis, status::DONE);
        self.put_pins_and_voltage(&mut r, k);
        let Some(d) = self.devices.get(k) else {
            return r;
        };
        let regs = d.driver_registers();
        let s = &d.settings;
        self.put_driver_block(&mut r, &regs, s.temperature_limit, s.idle, s.overheat, k);
        if !live {
            r.u8(62, s.mode.code());
        }
        r
    }

    /// 0x84: what the store holds.
    fn eeprom_report(&self, k: usize, axis: u8) -> InReport {
        let mut r = InReport::new(0x84, 0x00, axis, status::DONE);
        self.put_pins_and_voltage(&mut r, k);
        let Some(s) = self.stored.axes.get(k) else {
            return r;
        };
        let regs = s.drv.live(&crate::postep60::drv8711::Mapped {
            enable: true,
            reverse_step_dir: s.drv.mapped().reverse_step_dir,
            step_mode: Some(s.step_mode),
            full_scale: s.full_scale,
            status: 0,
        });
        let address = self.stored.base_address.saturating_add(axis);
        self.put_driver_block(&mut r, &regs, s.temperature_limit, s.idle, s.overheat, k);
        r.u8(61, address);
        r.u8(63, self.stored.serial.code());
        r
    }

    /// Bytes 40..61 and 63 of 0x81/0x84/0x85.
    fn put_driver_block(
        &self,
        r: &mut InReport,
        regs: &Drv8711Regs,
        max_temp: u8,
        idle: crate::postep60::Current,
        overheat: crate::postep60::Current,
        k: usize,
    ) {
        for (i, v) in regs.0.iter().enumerate() {
            r.le16(40usize.saturating_add(i.saturating_mul(2)), *v);
        }
        r.u8(56, max_temp);
        r.put(57, &idle.to_bytes());
        r.put(59, &overheat.to_bytes());
        r.u8(61, self.address_of(k).unwrap_or(0));
        r.u8(63, self.serial.code());
    }

    /// 0x88.
    fn other_report(&self, k: usize, axis: u8) -> InReport {
        let mut r = InReport::new(0xCC, cmd::SAVE_OTHER, axis, status::DONE);
        let Some(d) = self.devices.get(k) else {
            return r;
        };
        let s = &d.settings;
        r.le32(24, s.max_speed);
        r.le32(28, s.acc);
        r.le32(32, s.dec);
        let flags = u8::from(s.end_switch)
            | u8::from(s.end_switch_nc) << 1
            | u8::from(s.mode == DriverMode::BinButtons) << 2
            | u8::from(s.mode == DriverMode::AutoRun) << 3
            | u8::from(s.invert) << 4;
        r.u8(36, flags);
        r.le32(40, s.bin1_steps as u32);
        r.le32(44, s.bin2_steps as u32);
        r
    }

    /// The 0xA0 data-stream report of `axis`.
    fn stream_report(&self, axis: u8) -> InReport {
        let k = usize::from(axis);
        let mut r = InReport::new(0x00, cmd::STREAM, axis, status::DONE);
        self.put_pins_and_voltage(&mut r, k);
        if let (Some(a), Some(d)) = (self.group.axis(k), self.devices.get(k)) {
            let sat = |v: i64| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
            let pos = match self.query(k, Query::Position) {
                Some(Value::I32(p)) => p,
                _ => 0,
            };
            r.be32(20, pos as u32);
            r.be32(24, sat(a.profile().velocity()) as u32);
            r.be32(28, sat(a.required_position()) as u32);
            r.be16(44, self.temperature);
            r.u8(46, d.status() as u8);
            r.u8(47, d.settings.mode.code());
            r.le16(54, u16::from(d.faults()));
        }
        r
    }

    /// 0x80: the register image, mode, temperature limit, currents, then
    /// the address and the Modbus serial settings; then everything is
    /// stored. The first refusal is the status; later fields still apply.
    fn write_driver_settings(&mut self, k: usize, d: DriverSettings) -> u8 {
        let mut first = status::DONE;
        let mut note = |st: u8| {
            if first == status::DONE {
                first = st;
            }
        };
        for req in [
            Request::SetDriverRegisters(d.regs),
            Request::SetModeUsb(d.config_set),
            Request::SetTemperatureLimit(d.max_temp),
            Request::SetIdleCurrent(d.idle),
            Request::SetOverheatCurrent(d.overheat),
        ] {
            note(self.status(k, req));
        }
        if let Some(current) = self.address_of(k) {
            if current != d.address {
                note(self.status(
                    k,
                    Request::SetAddress {
                        current,
                        new: d.address,
                    },
                ));
            }
        }
        match Serial::from_code(d.serial_code) {
            // The RS-485 line is set up at boot: the new settings apply
            // after the next restart (once stored).
            Some(serial) => self.serial = serial,
            None => note(status::IGNORED),
        }
        note(self.status(k, Request::WriteSettings));
        first
    }

    /// 0x83: stop, factory settings in use and in the store.
    fn erase(&mut self) -> u8 {
        if self.run_mode == RunMode::Boot {
            return status::BOOT_MODE;
        }
        if self.saving {
            return status::BUSY;
        }
        for i in 0..self.group.len() {
            if let Some(a) = self.group.axis_mut(i) {
                a.stop_now();
            }
        }
        let factory = Settings::FACTORY;
        if factory.base_address != self.base_address {
            self.base_address = factory.base_address;
            self.addresses_changed = true;
        }
        self.serial = factory.serial;
        for (k, (d, s)) in self.devices.iter_mut().zip(factory.axes.iter()).enumerate() {
            d.settings = *s;
            if let Some(a) = self.group.axis_mut(k) {
                a.set_logical_shift(s.step_mode);
                d.clamp_limits(a);
            }
        }
        // Stored once every axis rests (it was just stopped).
        self.queue_save();
        status::DONE
    }
}
