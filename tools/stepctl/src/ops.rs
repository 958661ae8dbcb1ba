//! What a box is asked, in the register map's terms: axis status, box
//! info, the reasons behind an exception 04.

use bridge_logic::ext_space::{axis, block, diag, homing};
use serde::Serialize;

use crate::bus::{i32_of, u32_of, words_at, Bus};
use crate::error::{Error, Result};

/// PoStep60 registers (docs/modbus.md "Modbus register map").
pub mod reg {
    pub const RUN_SLEEP: u16 = 0x03;
    pub const SET_MODE: u16 = 0x05;
    pub const HW_FW_INFO: u16 = 0x0A;
    pub const VOLTAGE: u16 = 0x10;
    pub const TEMPERATURE: u16 = 0x11;
    pub const DRIVER_STATUS: u16 = 0x13;
    pub const DRIVER_MODE: u16 = 0x14;
    pub const FAULTS: u16 = 0x25;
    pub const RESET_FAULTS: u16 = 0x35;
    pub const WRITE_SETTINGS: u16 = 0x3F;
    pub const POSITION: u16 = 0x40;
    pub const SET_POSITION: u16 = 0x50;
    pub const SET_REQUESTED_SPEED: u16 = 0x54;
    pub const SET_INVERT: u16 = 0x55;
    pub const SET_ZERO: u16 = 0x5E;
    pub const STOP: u16 = 0x5F;
}

/// Run/Sleep values (0x03 BYTE0).
pub const RUN: u16 = 0xDA;
pub const SLEEP: u16 = 0x0F;

/// An extension address: block and offset.
pub const fn ext(blk: u8, offset: u8) -> u16 {
    (blk as u16) << 8 | offset as u16
}

pub const AXIS_BLOCK: u16 = ext(block::AXIS, axis::SPEED);
pub const AXIS_BLOCK_LEN: u16 = axis::LEN as u16;
pub const HOMING_COMMAND: u16 = ext(block::HOMING, homing::COMMAND);

/// Fault bits of 0x25 (manual 8.3.17), bit 0 first.
pub const FAULT_NAMES: [&str; 8] = [
    "OTS", "AOCP", "BOCP", "APDF", "BPDF", "UVLO", "STD", "STDLAT",
];
/// Bits 0–5 stop the axis until Reset faults; the stall bits do not.
pub const STOPPING_FAULTS: u16 = 0x3F;

pub fn fault_names(bits: u16) -> String {
    let names: Vec<&str> = FAULT_NAMES
        .iter()
        .enumerate()
        .filter(|(i, _)| bits >> i & 1 != 0)
        .map(|(_, n)| *n)
        .collect();
    if names.is_empty() {
        "-".into()
    } else {
        names.join(",")
    }
}

pub fn mode_name(code: u16) -> &'static str {
    match code {
        1 => "external",
        2 => "step control",
        3 => "DC motor",
        4 => "position",
        5 => "BINx",
        6 => "auto run",
        _ => "?",
    }
}

pub fn driver_status_name(code: u16) -> &'static str {
    match code {
        1 => "asleep",
        2 => "active",
        3 => "idle",
        4 => "overheated",
        _ => "?",
    }
}

pub fn state_name(code: u16) -> &'static str {
    match code {
        0 => "setup",
        1 => "idle",
        2 => "moving",
        3 => "stopping",
        4 => "landing",
        5 => "homing",
        _ => "?",
    }
}

/// The motion part of an axis (extension 0x0600, one read).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Motion {
    /// Signed, steps/s.
    pub speed: i32,
    pub position: i32,
    pub target: i32,
    pub state: u16,
    pub following_error: i16,
    pub faults: u16,
}

impl Motion {
    pub fn settled(&self) -> bool {
        self.state == 1
    }
}

pub fn motion(bus: &mut dyn Bus, unit: u8) -> Result<Motion> {
    let r = bus.read(unit, AXIS_BLOCK, AXIS_BLOCK_LEN)?;
    let w = |i: usize| r.get(i).copied().unwrap_or(0);
    Ok(Motion {
        speed: i32_of(words_at(&r, 0, 2)),
        position: i32_of(r.get(2..4).unwrap_or(&[])),
        target: i32_of(r.get(4..6).unwrap_or(&[])),
        state: w(6),
        following_error: w(7) as i16,
        faults: w(8),
    })
}

/// One row of `stepctl status`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisStatus {
    pub axis: u8,
    pub position: i32,
    pub target: i32,
    /// steps/s, signed.
    pub speed: i32,
    pub state: &'static str,
    pub mode: u16,
    pub mode_name: &'static str,
    pub driver_status: u16,
    pub driver_status_name: &'static str,
    pub faults: u16,
    pub fault_names: String,
    pub temperature_c: f64,
    pub voltage_v: f64,
}

pub fn axis_status(bus: &mut dyn Bus, unit: u8) -> Result<AxisStatus> {
    let m = motion(bus, unit)?;
    let mode = one(bus, unit, reg::DRIVER_MODE)?;
    let ds = one(bus, unit, reg::DRIVER_STATUS)?;
    let t = one(bus, unit, reg::TEMPERATURE)?;
    let v = one(bus, unit, reg::VOLTAGE)?;
    Ok(AxisStatus {
        axis: unit,
        position: m.position,
        target: m.target,
        speed: m.speed,
        state: state_name(m.state),
        mode,
        mode_name: mode_name(mode),
        driver_status: ds,
        driver_status_name: driver_status_name(ds),
        faults: m.faults,
        fault_names: fault_names(m.faults),
        // Manual 9.3.6 / 9.3.7: 0.125 °C and 0.072 V per LSB.
        temperature_c: f64::from(t) * 0.125,
        voltage_v: (f64::from(v) * 0.072 * 1000.0).round() / 1000.0,
    })
}

pub fn one(bus: &mut dyn Bus, unit: u8, address: u16) -> Result<u16> {
    Ok(bus.read(unit, address, 1)?.first().copied().unwrap_or(0))
}

/// The box: versions and diagnostics (`stepctl info`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoxInfo {
    pub bus: String,
    pub driver_id: String,
    pub hardware: String,
    pub firmware: String,
    pub axes: u16,
    pub build_id: String,
    pub reset_cause: &'static str,
    pub settings_source: &'static str,
    pub uptime_s: u32,
}

pub fn chain_length(bus: &mut dyn Bus, unit: u8) -> Result<u16> {
    one(bus, unit, ext(block::DIAG, diag::CHAIN_LENGTH))
}

pub fn box_info(bus: &mut dyn Bus, unit: u8) -> Result<BoxInfo> {
    let hw = bus.read(unit, reg::HW_FW_INFO, 3)?;
    let w = |i: usize| hw.get(i).copied().unwrap_or(0);
    let d = bus.read(unit, ext(block::DIAG, diag::CHAIN_LENGTH), 6)?;
    let uptime = bus.read(unit, ext(block::DIAG, diag::UPTIME_S), 2)?;
    let dv = |i: usize| d.get(i).copied().unwrap_or(0);
    Ok(BoxInfo {
        bus: bus.name(),
        driver_id: format!("0x{:02X}", w(0) & 0xFF),
        hardware: format!("{}.{}", w(1) >> 8, w(1) & 0xFF),
        firmware: format!("{}.{}", w(2) >> 8, w(2) & 0xFF),
        axes: dv(0),
        build_id: format!("{:08X}", u32_of(words_at(&d, 4, 2))),
        reset_cause: match dv(1) {
            1 => "power-on",
            2 => "reset pin",
            3 => "watchdog",
            4 => "software",
            5 => "brown-out",
            _ => "unknown",
        },
        settings_source: match dv(2) {
            0 => "stored",
            1 => "factory (store empty)",
            2 => "factory (store unreadable!)",
            _ => "?",
        },
        uptime_s: u32_of(&uptime),
    })
}

/// Add what stepctl can find out to an exception 04 from a Modbus box: the
/// axis's driver status, faults and mode say which of the reasons it was.
pub fn explain(bus: &mut dyn Bus, unit: u8, address: u16, e: Error) -> Error {
    let Error::Exception { code: 4, what, .. } = e else {
        return e;
    };
    if !bus.is_modbus() {
        return Error::Exception {
            code: 4,
            what,
            reason: None,
        };
    }
    let reason = find_reason(bus, unit, address);
    Error::Exception {
        code: 4,
        what,
        reason,
    }
}

/// What [`find_reason`] reads of the axis: driver status, faults, mode, moving.
struct AxisNow {
    ds: u16,
    faults: u16,
    mode: u16,
    moving: bool,
}

fn find_reason(bus: &mut dyn Bus, unit: u8, address: u16) -> Option<String> {
    let now = AxisNow {
        ds: one(bus, unit, reg::DRIVER_STATUS).ok()?,
        faults: one(bus, unit, reg::FAULTS).ok()?,
        mode: one(bus, unit, reg::DRIVER_MODE).ok()?,
        moving: motion(bus, unit).map(|m| !m.settled()).unwrap_or(false),
    };
    refused_by_state(unit, address, &now).or_else(|| busy_reason(unit, address, &now))
}

/// The reasons the command itself or the axis's state (faulted, asleep, the
/// wrong driver mode) give, in order.
fn refused_by_state(unit: u8, address: u16, now: &AxisNow) -> Option<String> {
    let mode = now.mode;
    let motion_cmd = matches!(address, 0x50 | 0x54 | 0x55) || address == HOMING_COMMAND;
    if address == reg::SET_MODE {
        return Some(format!(
            "axis is refusing that driver mode (mode 3 DC motor, and 1 external step/dir where \
             the board does not route STEP, cannot run on a powerSTEP01); it stays in mode {mode} ({})",
            mode_name(now.mode)
        ));
    }
    if address == 0x06 {
        return Some(
            "axis cannot drive a DC motor (PWM is refused by a powerSTEP01 bridge)".into(),
        );
    }
    if now.faults & STOPPING_FAULTS != 0 {
        return Some(format!(
            "axis is faulted ({}): clear with `stepctl reset-faults {unit}`",
            fault_names(now.faults)
        ));
    }
    if now.ds == 1 && motion_cmd {
        return Some(format!(
            "axis is asleep: wake it with `stepctl wake {unit}`"
        ));
    }
    if address == reg::SET_POSITION && !matches!(now.mode, 4 | 5) {
        return Some(format!(
            "axis is in driver mode {mode} ({}): set position needs mode 4 (position) or 5 (BINx): \
             `stepctl settings set {unit} mode position`",
            mode_name(now.mode)
        ));
    }
    if matches!(address, 0x54 | 0x55) && now.mode != 6 {
        return Some(format!(
            "axis is in driver mode {mode} ({}): requested speed and invert need mode 6 (auto run)",
            mode_name(now.mode)
        ));
    }
    None
}

/// The reasons that need the axis to rest or sleep: a save, a chip register,
/// homing, or just busy.
fn busy_reason(unit: u8, address: u16, now: &AxisNow) -> Option<String> {
    if address == reg::WRITE_SETTINGS {
        return Some(
            "settings cannot be saved while an axis moves (or while a save is in progress): \
             wait until every axis rests"
                .into(),
        );
    }
    if address >> 8 == block::CHIP as u16 {
        let r = bridge_logic::powerstep::registers::Register::from_address(address as u8)?;
        let info = r.info();
        use bridge_logic::powerstep::registers::Access;
        return Some(match info.access {
            Access::WhenHiZ => format!(
                "chip register {} is writable only while the axis sleeps: `stepctl sleep {unit}` first",
                info.voltage_mode_name
            ),
            Access::WhenStopped => format!(
                "chip register {} is writable only while the axis rests",
                info.voltage_mode_name
            ),
            _ => format!("chip register {} refused the value now", info.voltage_mode_name),
        });
    }
    if address == HOMING_COMMAND {
        return Some(if now.moving {
            "axis is moving: homing starts only from rest".into()
        } else {
            "homing is not possible now (end switch disabled, asleep or faulted)".into()
        });
    }
    if now.moving {
        return Some("axis is busy (moving, homing or saving)".into());
    }
    if now.ds == 1 {
        return Some(format!(
            "axis is asleep: wake it with `stepctl wake {unit}`"
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modbus::fake::rtu;

    #[test]
    fn fault_bits_are_named_in_manual_order() {
        assert_eq!(fault_names(0), "-");
        assert_eq!(fault_names(0x21), "OTS,UVLO");
        assert_eq!(fault_names(0xC0), "STD,STDLAT");
    }

    #[test]
    fn status_reads_the_axis_block_then_mode_status_temperature_and_voltage() {
        // 0x0600 x10: speed 1500, position 3000, target 5000, state 2
        // (moving), following error 0, faults 0; then 0x14 = 4, 0x13 = 2,
        // 0x11 = 200 (25 °C), 0x10 = 333 (23.976 V).
        let mut m = rtu(&[
            (
                "01 03 06 00 00 0A C5 45",
                "01 03 14 00 00 05 DC 00 00 0B B8 00 00 13 88 00 02 00 00 00 00 00 00 54 BE",
            ),
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            ("01 03 00 13 00 01 75 CF", "01 03 02 00 02 39 85"),
            ("01 03 00 11 00 01 D4 0F", "01 03 02 00 C8 B9 D2"),
            ("01 03 00 10 00 01 85 CF", "01 03 02 01 4D 79 E1"),
        ]);
        let s = axis_status(&mut m, 1).unwrap();
        assert_eq!((s.speed, s.position, s.target), (1500, 3000, 5000));
        assert_eq!(
            (s.state, s.mode_name, s.driver_status_name),
            ("moving", "position", "active")
        );
        assert_eq!(s.temperature_c, 25.0);
        assert_eq!(s.voltage_v, 23.976);
        assert!(m.link.done());
    }

    #[test]
    fn an_exception_04_on_an_asleep_axis_says_so_and_how_to_wake_it() {
        let mut m = rtu(&[
            ("01 03 00 13 00 01 75 CF", "01 03 02 00 01 79 84"),
            ("01 03 00 25 00 01 95 C1", "01 03 02 00 00 B8 44"),
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (
                "01 03 06 00 00 0A C5 45",
                "01 03 14 00 00 00 00 00 00 00 00 00 00 00 00 00 01 00 00 00 00 00 00 B3 A7",
            ),
        ]);
        let e = Error::Exception {
            code: 4,
            what: "id 1: write 0x0050 (FC 0x10)".into(),
            reason: None,
        };
        let e = explain(&mut m, 1, 0x50, e);
        assert_eq!(
            e.to_string(),
            "id 1: write 0x0050 (FC 0x10): exception 04: axis is asleep: wake it with `stepctl wake 1`"
        );
    }

    #[test]
    fn an_exception_04_in_auto_run_names_the_mode_set_position_needs() {
        let mut m = rtu(&[
            ("01 03 00 13 00 01 75 CF", "01 03 02 00 02 39 85"),
            ("01 03 00 25 00 01 95 C1", "01 03 02 00 00 B8 44"),
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 06 38 46"),
            (
                "01 03 06 00 00 0A C5 45",
                "01 03 14 00 00 00 00 00 00 00 00 00 00 00 00 00 01 00 00 00 00 00 00 B3 A7",
            ),
        ]);
        let e = Error::Exception {
            code: 4,
            what: "w".into(),
            reason: None,
        };
        let s = explain(&mut m, 1, 0x50, e).to_string();
        assert!(s.contains("driver mode 6 (auto run)"), "{s}");
    }

    #[test]
    fn other_exceptions_are_left_as_they_are() {
        let mut m = rtu(&[]);
        let e = Error::Exception {
            code: 2,
            what: "w".into(),
            reason: None,
        };
        assert_eq!(explain(&mut m, 1, 0x99, e.clone()), e);
    }
}
