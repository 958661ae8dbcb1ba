//! The bridge's side of the extension address space ([`crate::ext_space`]:
//! the map and its error): reads and writes of every block.
//!
//! # Chip registers
//!
//! * **Reads** go to the chip: GetParam through the chain scheduler at the
//!   next control tick, so a read answers [`ExtError::NotYet`] first and the
//!   value once it came back (each bus waits its own way: the Modbus server
//!   retries before it answers, I2C returns a not-ready status byte, USB
//!   sends the response when it is there). STATUS is read with
//!   GetParam(STATUS), which clears none of the latched flags the bridge's
//!   own GetStatus reads rely on.
//! * **Writes**: only the tuning registers ([`TUNABLE`]) are writable; they
//!   are stored with the settings ("write settings" persists them) and
//!   written again after every chip reset. The chip's access class is
//!   enforced before anything goes on the wire: a WS register only while
//!   the axis rests, a WH register only while its bridges are off (asleep),
//!   else [`ExtError::Refused`] (Modbus 04), counted. MIN_SPEED takes 0 or a
//!   value with LSPD_OPT (bit 12) set — any other start speed would clamp
//!   the bridge's Run setpoints; CONFIG keeps the board's clock source and
//!   SW_MODE = 1 (bits 4:0). Every other register belongs to the bridge and
//!   is read-only here ([`ExtError::IllegalAddress`], Modbus 02): ABS_POS
//!   (Set position / Set zero), EL_POS, MARK, SPEED, ACC, DEC, MAX_SPEED
//!   (0x51–0x53), KVAL_* (the currents), ADC_OUT, STEP_MODE (0x33), STATUS.
//!
//! # Configured registers (0x07nn)
//!
//! What the bridge writes to each chip (`Axis::programmed`: the chip image,
//! and MAX_SPEED/ACC/DEC as last written), with a mask of which registers
//! those are and how many writes are still pending, so a master can compare
//! intent with 0x01nn (`stepctl doctor` does).

use super::{Bridge, Bus};
use crate::ext_space::{axis, block, configured, coord, diag, homing, watchdog, ExtError};
use crate::motion::AxisState;
use crate::postep60::settings::{Watchdog, WatchdogAction, TUNABLE, WATCHED_BUSES};
use crate::postep60::{Query, Value};
use crate::powerstep::chain::ChainBus;
use crate::powerstep::registers::{Access, Register};
fn io_error(e: crate::ioext::IoError) -> ExtError {
    use crate::ioext::IoError;
    match e {
        IoError::IllegalAddress => ExtError::IllegalAddress,
        IoError::IllegalValue => ExtError::IllegalValue,
        IoError::Unsupported | IoError::Busy | IoError::Disabled => ExtError::Refused,
    }
}

/// Register `at` of a block (nothing if the block is shorter).
fn put16(regs: &mut [u16], at: u8, v: u16) {
    if let Some(slot) = regs.get_mut(usize::from(at)) {
        *slot = v;
    }
}

fn put32(regs: &mut [u16], at: u8, v: u32) {
    let at = usize::from(at);
    if let Some(s) = regs.get_mut(at..at + 2) {
        s.copy_from_slice(&[(v >> 16) as u16, v as u16]);
    }
}

fn get32(data: &[u16]) -> u32 {
    match data {
        [hi, lo] => u32::from(*hi) << 16 | u32::from(*lo),
        _ => 0,
    }
}

/// Copy `out.len()` registers of `block` from `offset`.
fn copy_out(block: &[u16], offset: u8, out: &mut [u16]) -> Result<(), ExtError> {
    let start = usize::from(offset);
    let src = block
        .get(start..start.saturating_add(out.len()))
        .ok_or(ExtError::IllegalAddress)?;
    out.copy_from_slice(src);
    Ok(())
}

impl<B: ChainBus> Bridge<B> {
    /// Read `out.len()` registers at `address` for axis `k`.
    pub fn ext_read(&mut self, k: usize, address: u16, out: &mut [u16]) -> Result<(), ExtError> {
        let [blk, offset] = address.to_be_bytes();
        match blk {
            block::CHIP => self.chip_read(k, offset, out),
            block::IOEXT => self.io.read(address, out).map_err(io_error),
            block::DIAG => copy_out(&self.diag_block(), offset, out),
            block::HOMING => copy_out(&self.homing_block(k)?, offset, out),
            block::WATCHDOG => copy_out(&self.watchdog_block(), offset, out),
            block::AXIS => copy_out(&self.axis_block(k)?, offset, out),
            block::CONFIGURED => copy_out(&self.configured_block(k)?, offset, out),
            block::COORD => copy_out(&self.coord_block(), offset, out),
            _ => Err(ExtError::IllegalAddress),
        }
    }

    /// [`Bridge::ext_write`] of a request that came on `bus`: a
    /// coordinated move it starts is that bus's for the communication
    /// watchdog.
    pub fn ext_write_from(
        &mut self,
        bus: Bus,
        k: usize,
        address: u16,
        data: &[u16],
    ) -> Result<(), ExtError> {
        let r = self.ext_write(k, address, data);
        let start = u16::from_be_bytes([block::COORD, coord::COMMAND]);
        let waypoint = u16::from_be_bytes([block::COORD, coord::WAYPOINT]);
        let queue = u16::from_be_bytes([block::COORD, coord::QUEUE]);
        let started = (address == start || address == queue) && data.first() == Some(&1);
        if r.is_ok() && (started || address >= waypoint && address >> 8 == waypoint >> 8) {
            self.coord_started_by(bus);
        }
        r
    }

    /// Write `data` at `address` for axis `k`.
    pub fn ext_write(&mut self, k: usize, address: u16, data: &[u16]) -> Result<(), ExtError> {
        let [blk, offset] = address.to_be_bytes();
        let r = match blk {
            block::CHIP => self.chip_write(k, offset, data),
            block::IOEXT if self.saving || self.run_mode == super::RunMode::Boot => {
                Err(ExtError::Refused)
            }
            block::IOEXT => self.io.write(address, data).map_err(io_error),
            block::DIAG if offset == diag::MODBUS_FRAMES => {
                self.clear_diagnostics();
                Ok(())
            }
            block::HOMING => self.homing_write(k, offset, data),
            block::WATCHDOG => self.watchdog_write(offset, data),
            block::COORD => self.coord_write(offset, data),
            _ => Err(ExtError::IllegalAddress),
        };
        if r == Err(ExtError::Refused) {
            self.diag.refused = self.diag.refused.saturating_add(1);
        }
        r
    }

    fn chip_read(&mut self, k: usize, offset: u8, out: &mut [u16]) -> Result<(), ExtError> {
        let reg = Register::from_address(offset).ok_or(ExtError::IllegalAddress)?;
        let width = if reg.bytes() == 3 { 2 } else { 1 };
        if out.len() != width {
            return Err(ExtError::IllegalAddress);
        }
        let axis = self.group.axis_mut(k).ok_or(ExtError::IllegalAddress)?;
        let v = axis.read_register(reg).ok_or(ExtError::NotYet)?;
        match out {
            [one] => *one = v as u16,
            [hi, lo] => {
                *hi = (v >> 16) as u16;
                *lo = v as u16;
            }
            _ => {}
        }
        Ok(())
    }

    fn chip_write(&mut self, k: usize, offset: u8, data: &[u16]) -> Result<(), ExtError> {
        let reg = Register::from_address(offset).ok_or(ExtError::IllegalAddress)?;
        if !TUNABLE.contains(&reg) {
            return Err(ExtError::IllegalAddress);
        }
        let value = match data {
            [v] => *v,
            _ => return Err(ExtError::IllegalAddress),
        };
        if u32::from(value) & !reg.mask() != 0 {
            return Err(ExtError::IllegalValue);
        }
        let value = match reg {
            // 0, or LSPD_OPT with its threshold: the start speed stays 0.
            Register::MinSpeed if value != 0 && value & 1 << 12 == 0 => {
                return Err(ExtError::IllegalValue)
            }
            // The board's clock source and SW_MODE = 1 stay.
            Register::Config => (value & !0x1F) | (self.stage.config_register() & 0x1F),
            _ => value,
        };
        let (Some(d), Some(a)) = (self.devices.get_mut(k), self.group.axis_mut(k)) else {
            return Err(ExtError::IllegalAddress);
        };
        let rests = a.is_at_rest() && !a.status().busy();
        let allowed = match reg.access() {
            Access::Always => true,
            Access::WhenStopped => rests,
            Access::WhenHiZ => rests && a.is_asleep(),
            Access::ReadOnly => false,
        };
        if !allowed || self.saving || self.run_mode == super::RunMode::Boot {
            return Err(ExtError::Refused);
        }
        if d.set_tuning(reg, value, a) {
            Ok(())
        } else {
            Err(ExtError::IllegalAddress)
        }
    }

    fn diag_block(&self) -> [u16; diag::LEN] {
        let mut r = [0u16; diag::LEN];
        let m = self.modbus_stats();
        for (at, v) in self.diag_counters() {
            put32(&mut r, at, v);
        }
        for (i, x) in m.exceptions_by_code.iter().enumerate() {
            put32(
                &mut r,
                diag::MODBUS_EXCEPTION_01.saturating_add((i as u8).saturating_mul(2)),
                *x,
            );
        }
        for (i, a) in self.group.iter().enumerate() {
            let base = self.resets_base.get(i).copied().unwrap_or(0);
            if let Some(slot) = r.get_mut(usize::from(diag::CHIP_RESETS_AXIS0).saturating_add(i)) {
                *slot = a.chip_resets().wrapping_sub(base).min(0xFFFF) as u16;
            }
        }
        for (at, v) in self.diag_words() {
            if let Some(slot) = r.get_mut(usize::from(at)) {
                *slot = v;
            }
        }
        put32(&mut r, diag::BUILD_ID, self.build_id);
        r
    }

    /// The 32-bit counters of the diagnostics block, by address.
    fn diag_counters(&self) -> [(u8, u32); 22] {
        let m = self.modbus_stats();
        let d = &self.diag;
        [
            (diag::MODBUS_FRAMES, m.frames_ok),
            (diag::MODBUS_CRC_ERRORS, m.crc_errors),
            (
                diag::MODBUS_FRAMING_ERRORS,
                m.gaps
                    .saturating_add(m.bad_characters)
                    .saturating_add(m.overruns),
            ),
            (diag::MODBUS_EXCEPTIONS, m.exceptions),
            (diag::I2C_UNKNOWN, d.i2c_unknown),
            (diag::I2C_SHORT, d.i2c_short),
            (diag::I2C_LONG, d.i2c_long),
            (diag::USB_REPORTS, d.usb_reports),
            (diag::USB_BAD, d.usb_bad),
            (diag::USB_UNKNOWN, d.usb_unknown),
            (diag::CHAIN_ERRORS, d.chain_errors),
            (diag::REFUSED, d.refused),
            (diag::SAVES, d.saves),
            (diag::SAVE_ERRORS, d.save_errors),
            (diag::LIMIT_CLAMPS, d.limit_clamps),
            (diag::CHIP_RESETS, d.chip_resets),
            (diag::WATCHDOG_TRIPS, d.watchdog_trips),
            (diag::UPTIME_S, (self.now_ms / 1000) as u32),
            (diag::TICK_LAST_US, self.timing.last_us),
            (diag::TICK_MAX_US, self.timing.max_us),
            (diag::TICK_OVERRUNS, self.timing.overruns),
            (diag::TICKS, self.timing.ticks),
        ]
    }

    /// The 16-bit words of the diagnostics block, by address.
    fn diag_words(&self) -> [(u8, u16); 10] {
        [
            (diag::CHAIN_LENGTH, self.axes() as u16),
            (diag::RESET_CAUSE, self.reset_cause as u16),
            (diag::SETTINGS_SOURCE, self.source as u16),
            (diag::FIRMWARE_VERSION, {
                let (major, minor) = crate::postep60::device::FW_VERSION;
                u16::from(major) << 8 | u16::from(minor)
            }),
            (
                diag::LAST_SAVE,
                if self.save_pending() {
                    3
                } else {
                    self.last_save
                },
            ),
            (diag::CHAIN_STATE, self.chain_state()),
            (
                diag::TICK_PERIOD_US,
                self.timing.period_us.min(0xFFFF) as u16,
            ),
            (diag::SUPPLY, self.supply),
            (diag::TEMPERATURE, self.temperature),
            (
                diag::LAST_REFUSAL,
                self.last_refusal
                    .map_or(0, |(k, e)| u16::from(k) << 8 | u16::from(e.code())),
            ),
        ]
    }

    fn homing_block(&self, k: usize) -> Result<[u16; homing::LEN], ExtError> {
        let (Some(d), Some(a)) = (self.devices.get(k), self.group.axis(k)) else {
            return Err(ExtError::IllegalAddress);
        };
        let h = &d.settings.homing;
        let state = a.homing_state();
        let mut r = [0u16; homing::LEN];
        put16(&mut r, homing::COMMAND, state.code());
        put16(
            &mut r,
            homing::RESULT,
            match state {
                crate::motion::HomingState::Failed(e) => e.code(),
                _ => d.homing_refusal().map_or(0, |e| e.code()),
            },
        );
        put16(&mut r, homing::HOMED, u16::from(a.is_homed()));
        put16(&mut r, homing::DIRECTION, u16::from(h.forward));
        put32(&mut r, homing::SEARCH_SPEED, h.search_speed);
        put32(&mut r, homing::RELEASE_SPEED, h.release_speed);
        put32(&mut r, homing::MAX_TRAVEL, h.max_travel);
        put16(&mut r, homing::TIMEOUT_S, h.timeout_s);
        put16(
            &mut r,
            homing::END_SWITCH,
            u16::from(d.settings.end_switch) | u16::from(d.settings.end_switch_nc) << 1,
        );
        Ok(r)
    }

    fn homing_write(&mut self, k: usize, offset: u8, data: &[u16]) -> Result<(), ExtError> {
        if self.saving || self.run_mode == super::RunMode::Boot {
            return Err(ExtError::Refused);
        }
        if offset == homing::COMMAND && data == [1] && self.group.coord().is_member(k) {
            return Err(ExtError::Refused);
        }
        let (Some(d), Some(a)) = (self.devices.get_mut(k), self.group.axis_mut(k)) else {
            return Err(ExtError::IllegalAddress);
        };
        let s = &mut d.settings;
        match (offset, data) {
            // Not while homing runs into the switch it uses.
            (homing::END_SWITCH, [v]) if *v <= 3 && a.is_homing() => Err(ExtError::Refused),
            (homing::END_SWITCH, [v]) if *v <= 3 => {
                s.end_switch = v & 1 != 0;
                s.end_switch_nc = v & 2 != 0;
                Ok(())
            }
            (homing::END_SWITCH, _) => Err(ExtError::IllegalValue),
            (homing::COMMAND, [1]) => match d.start_homing(a) {
                Ok(()) => Ok(()),
                Err(e) => {
                    d.note_homing_refusal(e);
                    Err(ExtError::Refused)
                }
            },
            (homing::COMMAND, [0]) => {
                if a.is_homing() {
                    a.stop_now();
                }
                Ok(())
            }
            (homing::COMMAND, [_]) => Err(ExtError::IllegalValue),
            (homing::DIRECTION, [v]) if *v <= 1 => {
                s.homing.forward = *v == 1;
                Ok(())
            }
            (homing::DIRECTION, [_]) => Err(ExtError::IllegalValue),
            (homing::SEARCH_SPEED, [_, _]) => {
                s.homing.search_speed = get32(data).max(1);
                Ok(())
            }
            (homing::RELEASE_SPEED, [_, _]) => {
                s.homing.release_speed = get32(data).max(1);
                Ok(())
            }
            (homing::MAX_TRAVEL, [_, _]) => {
                s.homing.max_travel = get32(data);
                Ok(())
            }
            (homing::TIMEOUT_S, [v]) => {
                s.homing.timeout_s = *v;
                Ok(())
            }
            _ => Err(ExtError::IllegalAddress),
        }
    }

    fn watchdog_block(&self) -> [u16; watchdog::LEN] {
        let mut r = [0u16; watchdog::LEN];
        let mut tripped = 0u16;
        for (i, (w, s)) in self.watchdog.iter().zip(self.watch.iter()).enumerate() {
            // i < WATCHED_BUSES (3): the offsets are small.
            let i8 = i as u8;
            put16(&mut r, i8.saturating_mul(2), w.timeout_ms);
            put16(
                &mut r,
                i8.saturating_mul(2).saturating_add(1),
                w.action as u16,
            );
            put16(
                &mut r,
                watchdog::TRIPS.saturating_add(i8),
                s.trips.min(0xFFFF) as u16,
            );
            if s.tripped {
                tripped |= 1 << i;
            }
        }
        put16(&mut r, watchdog::TRIPPED, tripped);
        r
    }

    fn watchdog_write(&mut self, offset: u8, data: &[u16]) -> Result<(), ExtError> {
        let mut next = self.watchdog;
        for (i, v) in data.iter().enumerate() {
            let at = usize::from(offset).saturating_add(i);
            let w: &mut Watchdog = next.get_mut(at / 2).ok_or(ExtError::IllegalAddress)?;
            if at % 2 == 0 {
                w.timeout_ms = *v;
            } else {
                w.action = u8::try_from(*v)
                    .ok()
                    .and_then(WatchdogAction::from_code)
                    .ok_or(ExtError::IllegalValue)?;
            }
        }
        if usize::from(offset).saturating_add(data.len()) > 2 * WATCHED_BUSES {
            return Err(ExtError::IllegalAddress);
        }
        self.watchdog = next;
        Ok(())
    }

    fn axis_block(&self, k: usize) -> Result<[u16; axis::LEN], ExtError> {
        let (Some(d), Some(a)) = (self.devices.get(k), self.group.axis(k)) else {
            return Err(ExtError::IllegalAddress);
        };
        let sat = |v: i64| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32 as u32;
        let mut r = [0u16; axis::LEN];
        put32(&mut r, axis::SPEED, sat(a.profile().velocity()));
        let pos = match self.query(k, Query::Position) {
            Some(Value::I32(p)) => p as u32,
            _ => 0,
        };
        put32(&mut r, axis::POSITION, pos);
        put32(&mut r, axis::TARGET, sat(a.required_position()));
        put16(
            &mut r,
            axis::STATE,
            match a.state() {
                AxisState::Setup(_) => 0,
                AxisState::Idle => 1,
                AxisState::Streaming => 2,
                AxisState::Stopping => 3,
                AxisState::Landing => 4,
                AxisState::Homing => 5,
            },
        );
        put16(
            &mut r,
            axis::FOLLOWING_ERROR,
            a.following_error()
                .clamp(i64::from(i16::MIN), i64::from(i16::MAX)) as i16 as u16,
        );
        put16(&mut r, axis::FAULTS, u16::from(d.faults()));
        put16(&mut r, axis::CHIP_STATUS, a.status().raw());
        Ok(r)
    }

    /// 0x07nn: what the bridge configures on axis `k`'s chip.
    fn configured_block(&self, k: usize) -> Result<[u16; configured::LEN], ExtError> {
        let a = self.group.axis(k).ok_or(ExtError::IllegalAddress)?;
        let mut r = [0u16; configured::LEN];
        let mut mask = 0u32;
        for reg in Register::all() {
            if let Some(v) = a.programmed(reg) {
                // Every configured register is at most 16 bits wide.
                put16(&mut r, reg.address(), v.min(0xFFFF) as u16);
                mask |= 1 << reg.address();
            }
        }
        put32(&mut r, configured::MASK, mask);
        put16(
            &mut r,
            configured::PENDING,
            a.chip_image().pending().min(0xFFFF) as u16,
        );
        put16(&mut r, configured::SET_UP, u16::from(a.is_configured()));
        Ok(r)
    }

    /// A bus was heard from: a valid request arrived (watchdog).
    pub(super) fn heard(&mut self, bus: Bus) {
        if let Some(w) = self.watch.get_mut(bus as usize) {
            w.last_ms = self.now_ms;
            w.tripped = false;
        }
    }
}
