//! Every persisted setting of every axis, with units: what `settings show`
//! prints, `settings export` writes as TOML, `settings import` and
//! `settings set` apply. Units are in the key names; a header in the file
//! lists them (PoStep60 manual §8.3 / §9.3 and the README's extension space).
//!
//! Reached over Modbus (and USB, except the requested speed):
//! driver mode, step mode, max speed / acceleration / deceleration,
//! the three currents, temperature limit, requested speed and invert (auto
//! run), homing parameters (extension 0x0403..0x040A), the tunable
//! powerSTEP01 registers (extension 0x01nn) and the bridge's communication
//! watchdog (0x0500..0x0505). The end switch, BINx steps and custom name
//! have no Modbus register; the settings store keeps them as USB sets them.

use std::collections::BTreeMap;

use bridge_logic::ext_space::{block, homing, watchdog};
use bridge_logic::postep60::current::Current;
use bridge_logic::postep60::settings::{TEMPERATURE_LIMIT_MAX, TUNABLE};
use bridge_logic::powerstep::registers::Register;
use serde::{Deserialize, Serialize};

use crate::bus::{u32_of, words_of, Bus};
use crate::error::{Error, Result};
use crate::ops::{self, ext, one};

/// The board's current limit (manual 6.1; README "Currents"), mA.
pub const CURRENT_LIMIT_MA: u32 = 6000;
pub const FORMAT: u32 = 1;

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct SettingsFile {
    /// File format version (1).
    pub format: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exported_from: Option<String>,
    /// The bridge's communication watchdog (bridge-wide).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub watchdog: Option<WatchdogFile>,
    #[serde(default)]
    pub axis: Vec<AxisFile>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct AxisFile {
    /// The axis: Modbus id (USB: 1 + index).
    pub id: u8,
    /// "position" (4), "binx" (5), "auto-run" (6), "external" (1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub driver_mode: Option<String>,
    /// 0 = full step … 8 = 1/256.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub step_mode: Option<u8>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_speed_steps_per_s: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub acceleration_steps_per_s2: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deceleration_steps_per_s2: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub full_scale_current_a: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub idle_current_a: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub overheat_current_a: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temperature_limit_c: Option<u32>,
    /// Auto run only (mode 6).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub requested_speed_steps_per_s: Option<u32>,
    /// Auto run only (mode 6).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub invert: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub homing: Option<HomingFile>,
    /// Tunable powerSTEP01 registers by datasheet name, raw values.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chip: Option<BTreeMap<String, u32>>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct HomingFile {
    /// "forward" or "reverse": toward the switch.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub direction: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub search_speed_steps_per_s: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub release_speed_steps_per_s: Option<u32>,
    /// 0 = no limit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_travel_steps: Option<u32>,
    /// 0 = no limit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timeout_s: Option<u32>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct WatchdogFile {
    /// 0 = off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modbus_timeout_ms: Option<u32>,
    /// "hold", "soft-stop" or "bridges-off".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modbus_action: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub i2c_timeout_ms: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub i2c_action: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub usb_timeout_ms: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub usb_action: Option<String>,
}

/// The file's header: what every key's unit is.
pub const HEADER: &str = "\
# stepctl settings (format 1): `stepctl settings import FILE` applies it,
# `--save` also writes it to the box's flash. Keys carry their units:
#   steps = logical steps of the axis's step_mode (0 = full step .. 8 = 1/256),
#   *_steps_per_s, *_steps_per_s2: speeds and ramps; *_a: amperes (max 6.0,
#   stored as the PoStep60's Tq/Ai code, nearest at or below);
#   temperature_limit_c: degrees C (max 120); *_ms, *_s: milliseconds, seconds.
# driver_mode: position | binx | auto-run | external.
# requested_speed_steps_per_s and invert apply in auto-run only.
# [axis.chip]: powerSTEP01 tuning registers, raw values (datasheet units).
# [watchdog] actions: hold | soft-stop | bridges-off; timeout 0 = off.
";

pub fn mode_code(name: &str) -> Option<u16> {
    Some(match name {
        "external" | "1" => 1,
        "position" | "4" => 4,
        "binx" | "5" => 5,
        "auto-run" | "6" => 6,
        _ => return None,
    })
}

pub fn mode_key(code: u16) -> String {
    match code {
        1 => "external".into(),
        4 => "position".into(),
        5 => "binx".into(),
        6 => "auto-run".into(),
        other => other.to_string(),
    }
}

fn action_code(name: &str) -> Option<u16> {
    Some(match name {
        "hold" => 0,
        "soft-stop" => 1,
        "bridges-off" => 2,
        _ => return None,
    })
}

fn action_key(code: u16) -> String {
    match code {
        0 => "hold".into(),
        1 => "soft-stop".into(),
        2 => "bridges-off".into(),
        other => other.to_string(),
    }
}

/// mA of a 0x20..0x22 register (BYTE1 = Ai, BYTE0 = Tq).
pub fn milliamps(word: u16) -> u32 {
    Current {
        tq: word as u8,
        ai: (word >> 8) as u8,
    }
    .milliamps()
    .unwrap_or(0)
}

/// The register for `ma`: the encoding (Ai 0..=3) whose current is nearest
/// at or below `ma`, preferring an exact one, so what is read back and
/// exported is what was asked when the encoding allows it.
pub fn current_word(ma: u32) -> u16 {
    let mut best = Current::from_milliamps(ma);
    let mut best_ma = best.milliamps().unwrap_or(0);
    for ai in (0..=3u8).rev() {
        for tq in 0..=255u8 {
            let c = Current { tq, ai };
            let m = c.milliamps().unwrap_or(0);
            if m <= ma && m > best_ma {
                best = c;
                best_ma = m;
            }
        }
    }
    u16::from(best.ai) << 8 | u16::from(best.tq)
}

pub fn amps(ma: u32) -> f64 {
    f64::from(ma) / 1000.0
}

fn to_ma(a: f64) -> u32 {
    (a * 1000.0).round() as u32
}

pub fn tunable_name(r: Register) -> &'static str {
    r.info().voltage_mode_name
}

fn tunable(name: &str) -> Option<Register> {
    TUNABLE
        .iter()
        .copied()
        .find(|r| tunable_name(*r).eq_ignore_ascii_case(name))
}

fn check(ok: bool, msg: impl FnOnce() -> String) -> std::result::Result<(), String> {
    if ok {
        Ok(())
    } else {
        Err(msg())
    }
}

fn range(
    key: &str,
    v: Option<u32>,
    min: u32,
    max: u32,
    unit: &str,
) -> std::result::Result<(), String> {
    match v {
        Some(v) => check((min..=max).contains(&v), || {
            format!("{key} = {v} is out of range: {min}..={max} {unit}")
        }),
        None => Ok(()),
    }
}

fn amps_range(key: &str, v: Option<f64>) -> std::result::Result<(), String> {
    match v {
        Some(a) => check(
            a.is_finite() && (0.0..=amps(CURRENT_LIMIT_MA)).contains(&a),
            || format!("{key} = {a} is out of range: 0..=6.0 A (the board's limit)"),
        ),
        None => Ok(()),
    }
}

impl AxisFile {
    /// Every value in range, checked before anything is sent.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let id = self.id;
        let e = |m: String| format!("axis {id}: {m}");
        check((1..=247).contains(&id), || {
            format!("axis id {id} is out of range 1..=247")
        })?;
        if let Some(m) = &self.driver_mode {
            check(mode_code(m).is_some(), || {
                e(format!(
                    "driver_mode = {m:?}: use position, binx, auto-run or external"
                ))
            })?;
        }
        range(
            "step_mode",
            self.step_mode.map(u32::from),
            0,
            8,
            "(0 = full .. 8 = 1/256)",
        )
        .map_err(e)?;
        range(
            "max_speed_steps_per_s",
            self.max_speed_steps_per_s,
            1,
            65535,
            "steps/s",
        )
        .map_err(e)?;
        range(
            "acceleration_steps_per_s2",
            self.acceleration_steps_per_s2,
            1,
            65535,
            "steps/s²",
        )
        .map_err(e)?;
        range(
            "deceleration_steps_per_s2",
            self.deceleration_steps_per_s2,
            1,
            65535,
            "steps/s²",
        )
        .map_err(e)?;
        amps_range("full_scale_current_a", self.full_scale_current_a).map_err(e)?;
        amps_range("idle_current_a", self.idle_current_a).map_err(e)?;
        amps_range("overheat_current_a", self.overheat_current_a).map_err(e)?;
        range(
            "temperature_limit_c",
            self.temperature_limit_c,
            0,
            u32::from(TEMPERATURE_LIMIT_MAX),
            "°C",
        )
        .map_err(e)?;
        range(
            "requested_speed_steps_per_s",
            self.requested_speed_steps_per_s,
            0,
            65535,
            "steps/s",
        )
        .map_err(e)?;
        if let Some(h) = &self.homing {
            if let Some(d) = &h.direction {
                check(d == "forward" || d == "reverse", || {
                    e(format!("homing.direction = {d:?}: use forward or reverse"))
                })?;
            }
            range(
                "homing.search_speed_steps_per_s",
                h.search_speed_steps_per_s,
                1,
                u32::MAX,
                "steps/s",
            )
            .map_err(e)?;
            range(
                "homing.release_speed_steps_per_s",
                h.release_speed_steps_per_s,
                1,
                u32::MAX,
                "steps/s",
            )
            .map_err(e)?;
            range("homing.timeout_s", h.timeout_s, 0, 65535, "s").map_err(e)?;
        }
        if let Some(chip) = &self.chip {
            for (name, v) in chip {
                let r = tunable(name).ok_or_else(|| {
                    e(format!(
                        "chip.{name}: not a tunable register ({})",
                        TUNABLE
                            .iter()
                            .map(|r| tunable_name(*r))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ))
                })?;
                let max = r.mask();
                check(*v <= max, || {
                    e(format!("chip.{name} = {v} is out of range: 0..={max}"))
                })?;
            }
        }
        Ok(())
    }
}

impl WatchdogFile {
    pub fn validate(&self) -> std::result::Result<(), String> {
        for (k, t) in [
            ("modbus", self.modbus_timeout_ms),
            ("i2c", self.i2c_timeout_ms),
            ("usb", self.usb_timeout_ms),
        ] {
            range(&format!("watchdog.{k}_timeout_ms"), t, 0, 65535, "ms")?;
        }
        for (k, a) in [
            ("modbus", &self.modbus_action),
            ("i2c", &self.i2c_action),
            ("usb", &self.usb_action),
        ] {
            if let Some(a) = a {
                check(action_code(a).is_some(), || {
                    format!("watchdog.{k}_action = {a:?}: use hold, soft-stop or bridges-off")
                })?;
            }
        }
        Ok(())
    }
}

impl SettingsFile {
    pub fn validate(&self) -> std::result::Result<(), String> {
        check(self.format == FORMAT, || {
            format!(
                "format = {}: this stepctl reads format {FORMAT}",
                self.format
            )
        })?;
        let mut seen = std::collections::BTreeSet::new();
        for a in &self.axis {
            check(seen.insert(a.id), || format!("axis {} appears twice", a.id))?;
            a.validate()?;
        }
        if let Some(w) = &self.watchdog {
            w.validate()?;
        }
        Ok(())
    }

    pub fn parse(text: &str) -> Result<SettingsFile> {
        let f: SettingsFile =
            toml::from_str(text).map_err(|e| Error::Usage(format!("settings file: {e}")))?;
        f.validate()
            .map_err(|e| Error::Usage(format!("settings file: {e}")))?;
        Ok(f)
    }

    pub fn to_toml(&self) -> String {
        let body = toml::to_string(self).unwrap_or_else(|e| format!("# cannot write: {e}\n"));
        format!("{HEADER}\n{body}")
    }
}

/// Read every setting of axis `unit`.
pub fn read_axis(bus: &mut dyn Bus, unit: u8) -> Result<AxisFile> {
    let mut r = |a: u16| one(bus, unit, a);
    let mode = r(0x14)?;
    let step = r(0x23)?;
    let speed = r(0x41)?;
    let acc = r(0x42)?;
    let dec = r(0x43)?;
    let fs = r(0x20)?;
    let idle = r(0x21)?;
    let oh = r(0x22)?;
    let temp = r(0x24)?;
    let invert = r(0x46)?;
    let modbus = bus.is_modbus();
    let requested = if modbus {
        Some(u32::from(one(bus, unit, 0x45)?))
    } else {
        None
    };
    let h = bus.read(unit, ext(block::HOMING, homing::DIRECTION), 8)?;
    let mut chip = BTreeMap::new();
    for reg in TUNABLE {
        let n = if reg.bytes() == 3 { 2 } else { 1 };
        let v = bus.read(unit, ext(block::CHIP, reg.address()), n)?;
        chip.insert(tunable_name(reg).to_string(), u32_of(&v));
    }
    Ok(AxisFile {
        id: unit,
        driver_mode: Some(mode_key(mode)),
        step_mode: Some(step as u8),
        max_speed_steps_per_s: Some(u32::from(speed)),
        acceleration_steps_per_s2: Some(u32::from(acc)),
        deceleration_steps_per_s2: Some(u32::from(dec)),
        full_scale_current_a: Some(amps(milliamps(fs))),
        idle_current_a: Some(amps(milliamps(idle))),
        overheat_current_a: Some(amps(milliamps(oh))),
        temperature_limit_c: Some(u32::from(temp)),
        requested_speed_steps_per_s: requested,
        invert: Some(invert & 1 != 0),
        homing: Some(HomingFile {
            direction: Some(
                if h.first() == Some(&1) {
                    "forward"
                } else {
                    "reverse"
                }
                .into(),
            ),
            search_speed_steps_per_s: Some(u32_of(h.get(1..3).unwrap_or(&[]))),
            release_speed_steps_per_s: Some(u32_of(h.get(3..5).unwrap_or(&[]))),
            max_travel_steps: Some(u32_of(h.get(5..7).unwrap_or(&[]))),
            timeout_s: Some(u32::from(h.get(7).copied().unwrap_or(0))),
        }),
        chip: Some(chip),
    })
}

pub fn read_watchdog(bus: &mut dyn Bus, unit: u8) -> Result<WatchdogFile> {
    let w = bus.read(unit, ext(block::WATCHDOG, watchdog::MODBUS_TIMEOUT_MS), 6)?;
    let g = |i: usize| w.get(i).copied().unwrap_or(0);
    Ok(WatchdogFile {
        modbus_timeout_ms: Some(u32::from(g(0))),
        modbus_action: Some(action_key(g(1))),
        i2c_timeout_ms: Some(u32::from(g(2))),
        i2c_action: Some(action_key(g(3))),
        usb_timeout_ms: Some(u32::from(g(4))),
        usb_action: Some(action_key(g(5))),
    })
}

/// One setting that changed (or was skipped) on import.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Change {
    pub axis: Option<u8>,
    pub key: String,
    pub from: String,
    pub to: String,
    /// Why it was not written, if it was not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub skipped: Option<String>,
}

struct Applier<'a> {
    bus: &'a mut dyn Bus,
    unit: u8,
    changes: Vec<Change>,
}

impl Applier<'_> {
    fn write(
        &mut self,
        key: &str,
        from: String,
        to: String,
        address: u16,
        values: &[u16],
    ) -> Result<()> {
        if from == to {
            return Ok(());
        }
        self.bus
            .write(self.unit, address, values)
            .map_err(|e| ops::explain(self.bus, self.unit, address, e))?;
        self.changes.push(Change {
            axis: Some(self.unit),
            key: key.into(),
            from,
            to,
            skipped: None,
        });
        Ok(())
    }

    fn u16(&mut self, key: &str, now: Option<u32>, want: Option<u32>, address: u16) -> Result<()> {
        if let Some(w) = want {
            self.write(key, show(now), w.to_string(), address, &[w as u16])?;
        }
        Ok(())
    }

    fn u32(&mut self, key: &str, now: Option<u32>, want: Option<u32>, address: u16) -> Result<()> {
        if let Some(w) = want {
            self.write(key, show(now), w.to_string(), address, &words_of(w))?;
        }
        Ok(())
    }

    fn current(
        &mut self,
        key: &str,
        now: Option<f64>,
        want: Option<f64>,
        address: u16,
    ) -> Result<()> {
        if let Some(w) = want {
            let word = current_word(to_ma(w));
            let to = amps(milliamps(word)).to_string();
            let from = now.map_or("?".into(), |a| a.to_string());
            self.write(key, from, to, address, &[word])?;
        }
        Ok(())
    }
}

fn show<T: ToString>(v: Option<T>) -> String {
    v.map_or("?".into(), |v| v.to_string())
}

/// Apply `want` to its axis, which now has `now`; only what differs is
/// written, in an order that keeps each value meaningful: step mode first
/// (speeds are in its unit), the mode last, then what auto run needs.
pub fn apply_axis(bus: &mut dyn Bus, want: &AxisFile, now: &AxisFile) -> Result<Vec<Change>> {
    let mut a = Applier {
        bus,
        unit: want.id,
        changes: Vec::new(),
    };
    a.u16(
        "step_mode",
        now.step_mode.map(u32::from),
        want.step_mode.map(u32::from),
        0x33,
    )?;
    a.u16(
        "max_speed_steps_per_s",
        now.max_speed_steps_per_s,
        want.max_speed_steps_per_s,
        0x51,
    )?;
    a.u16(
        "acceleration_steps_per_s2",
        now.acceleration_steps_per_s2,
        want.acceleration_steps_per_s2,
        0x52,
    )?;
    a.u16(
        "deceleration_steps_per_s2",
        now.deceleration_steps_per_s2,
        want.deceleration_steps_per_s2,
        0x53,
    )?;
    a.current(
        "full_scale_current_a",
        now.full_scale_current_a,
        want.full_scale_current_a,
        0x30,
    )?;
    a.current(
        "idle_current_a",
        now.idle_current_a,
        want.idle_current_a,
        0x31,
    )?;
    a.current(
        "overheat_current_a",
        now.overheat_current_a,
        want.overheat_current_a,
        0x32,
    )?;
    a.u16(
        "temperature_limit_c",
        now.temperature_limit_c,
        want.temperature_limit_c,
        0x34,
    )?;
    if let Some(h) = &want.homing {
        let n = now.homing.clone().unwrap_or_default();
        let dir = |d: &Option<String>| d.as_deref().map(|d| u32::from(d == "forward"));
        if let Some(d) = &h.direction {
            let from = show(n.direction.clone());
            a.write(
                "homing.direction",
                from,
                d.clone(),
                ext(block::HOMING, homing::DIRECTION),
                &[dir(&h.direction).unwrap_or(0) as u16],
            )?;
        }
        a.u32(
            "homing.search_speed_steps_per_s",
            n.search_speed_steps_per_s,
            h.search_speed_steps_per_s,
            ext(block::HOMING, homing::SEARCH_SPEED),
        )?;
        a.u32(
            "homing.release_speed_steps_per_s",
            n.release_speed_steps_per_s,
            h.release_speed_steps_per_s,
            ext(block::HOMING, homing::RELEASE_SPEED),
        )?;
        a.u32(
            "homing.max_travel_steps",
            n.max_travel_steps,
            h.max_travel_steps,
            ext(block::HOMING, homing::MAX_TRAVEL),
        )?;
        a.u16(
            "homing.timeout_s",
            n.timeout_s,
            h.timeout_s,
            ext(block::HOMING, homing::TIMEOUT_S),
        )?;
    }
    if let Some(chip) = &want.chip {
        let n = now.chip.clone().unwrap_or_default();
        for (name, v) in chip {
            let Some(reg) = tunable(name) else { continue };
            let canon = tunable_name(reg);
            let from = n.get(canon).copied();
            a.u16(
                &format!("chip.{canon}"),
                from,
                Some(*v),
                ext(block::CHIP, reg.address()),
            )?;
        }
    }
    let final_mode = want
        .driver_mode
        .as_deref()
        .and_then(mode_code)
        .or_else(|| now.driver_mode.as_deref().and_then(mode_code));
    if let Some(m) = &want.driver_mode {
        let code = mode_code(m).unwrap_or(4);
        a.write(
            "driver_mode",
            show(now.driver_mode.clone()),
            mode_key(code),
            ops::reg::SET_MODE,
            &[code],
        )?;
    }
    let auto = final_mode == Some(6);
    for (key, now_v, want_v, address) in [
        (
            "invert",
            now.invert.map(u32::from),
            want.invert.map(u32::from),
            ops::reg::SET_INVERT,
        ),
        (
            "requested_speed_steps_per_s",
            now.requested_speed_steps_per_s,
            want.requested_speed_steps_per_s,
            ops::reg::SET_REQUESTED_SPEED,
        ),
    ] {
        match want_v {
            Some(w) if auto => a.u16(key, now_v, Some(w), address)?,
            Some(w) if now_v.is_some_and(|n| n != w) => a.changes.push(Change {
                axis: Some(want.id),
                key: key.into(),
                from: show(now_v),
                to: w.to_string(),
                skipped: Some(
                    "applies in auto-run mode only (the box refuses it in other modes)".into(),
                ),
            }),
            _ => {}
        }
    }
    Ok(a.changes)
}

pub fn apply_watchdog(
    bus: &mut dyn Bus,
    unit: u8,
    want: &WatchdogFile,
    now: &WatchdogFile,
) -> Result<Vec<Change>> {
    let mut a = Applier {
        bus,
        unit,
        changes: Vec::new(),
    };
    let base = ext(block::WATCHDOG, watchdog::MODBUS_TIMEOUT_MS);
    let rows = [
        (
            "modbus",
            &want.modbus_timeout_ms,
            &now.modbus_timeout_ms,
            &want.modbus_action,
            &now.modbus_action,
        ),
        (
            "i2c",
            &want.i2c_timeout_ms,
            &now.i2c_timeout_ms,
            &want.i2c_action,
            &now.i2c_action,
        ),
        (
            "usb",
            &want.usb_timeout_ms,
            &now.usb_timeout_ms,
            &want.usb_action,
            &now.usb_action,
        ),
    ];
    for (k, (bus_name, wt, nt, wa, na)) in rows.into_iter().enumerate() {
        let at = base + 2 * k as u16;
        a.u16(&format!("watchdog.{bus_name}_timeout_ms"), *nt, *wt, at)?;
        if let Some(w) = wa {
            a.write(
                &format!("watchdog.{bus_name}_action"),
                show(na.clone()),
                w.clone(),
                at + 1,
                &[action_code(w).unwrap_or(1)],
            )?;
        }
    }
    for c in &mut a.changes {
        c.axis = None;
    }
    Ok(a.changes)
}

/// `settings set` keys: (key, aliases). Values parse as the file's do.
pub const KEYS: [(&str, &[&str]); 18] = [
    ("driver_mode", &["mode"]),
    ("step_mode", &["step-mode", "microstep"]),
    ("max_speed_steps_per_s", &["max-speed", "speed"]),
    ("acceleration_steps_per_s2", &["acc", "acceleration"]),
    ("deceleration_steps_per_s2", &["dec", "deceleration"]),
    ("full_scale_current_a", &["current", "full-scale-current"]),
    ("idle_current_a", &["idle-current"]),
    ("overheat_current_a", &["overheat-current"]),
    ("temperature_limit_c", &["temp-limit", "temperature-limit"]),
    ("requested_speed_steps_per_s", &["requested-speed"]),
    ("invert", &[]),
    ("homing.direction", &[]),
    ("homing.search_speed_steps_per_s", &["homing.search-speed"]),
    (
        "homing.release_speed_steps_per_s",
        &["homing.release-speed"],
    ),
    ("homing.max_travel_steps", &["homing.max-travel"]),
    ("homing.timeout_s", &["homing.timeout"]),
    ("watchdog.<bus>_timeout_ms", &[]),
    ("watchdog.<bus>_action", &[]),
];

/// A one-setting file for `settings set AXIS KEY VALUE` (also
/// `chip.NAME` and `watchdog.*`); its values are then validated like a
/// file's.
pub fn one_setting(unit: u8, key: &str, value: &str) -> Result<SettingsFile> {
    let canon = KEYS
        .iter()
        .find(|(k, aliases)| *k == key || aliases.contains(&key))
        .map(|(k, _)| *k)
        .unwrap_or(key);
    // TOML for the value: strings quoted, numbers and booleans as they are.
    let quoted = |v: &str| format!("{v:?}");
    let text = if let Some(w) = canon.strip_prefix("watchdog.") {
        let v = if w.ends_with("_action") {
            quoted(value)
        } else {
            value.to_string()
        };
        format!("format = 1\n[watchdog]\n{w} = {v}\n")
    } else if let Some(h) = canon.strip_prefix("homing.") {
        let v = if h == "direction" {
            quoted(value)
        } else {
            value.to_string()
        };
        format!("format = 1\n[[axis]]\nid = {unit}\n[axis.homing]\n{h} = {v}\n")
    } else if let Some(c) = canon.strip_prefix("chip.") {
        let v = parse_int(value).map_err(Error::Usage)?;
        format!("format = 1\n[[axis]]\nid = {unit}\n[axis.chip]\n{c} = {v}\n")
    } else {
        let v = match canon {
            "driver_mode" => quoted(value),
            "step_mode" => step_mode_value(value).map_err(Error::Usage)?,
            "invert" => match value {
                "1" | "true" | "on" => "true".into(),
                "0" | "false" | "off" => "false".into(),
                _ => {
                    return Err(Error::Usage(format!(
                        "invert = {value:?}: use true or false"
                    )))
                }
            },
            k if k.ends_with("_a") => {
                let a: f64 = value.parse().map_err(|_| {
                    Error::Usage(format!("{k} = {value:?}: a current in A, e.g. 1.2"))
                })?;
                format!("{a:?}")
            }
            _ => value.to_string(),
        };
        format!("format = 1\n[[axis]]\nid = {unit}\n{canon} = {v}\n")
    };
    SettingsFile::parse(&text).map_err(|e| match e {
        Error::Usage(m) => Error::Usage(format!(
            "settings set {key} {value}: {}",
            m.trim_start_matches("settings file: ")
        )),
        other => other,
    })
}

/// "1/16" or "4" → "4".
fn step_mode_value(v: &str) -> std::result::Result<String, String> {
    if let Some(d) = v.strip_prefix("1/") {
        let d: u32 = d
            .parse()
            .map_err(|_| format!("step_mode = {v:?}: 0..8 or 1/1..1/256"))?;
        return match d {
            1 | 2 | 4 | 8 | 16 | 32 | 64 | 128 | 256 => Ok(d.trailing_zeros().to_string()),
            _ => Err(format!("step_mode = {v:?}: 1/1, 1/2 .. 1/256")),
        };
    }
    Ok(v.to_string())
}

pub fn step_fraction(mode: u8) -> String {
    format!("1/{}", 1u32 << mode.min(8))
}

pub fn parse_int(v: &str) -> std::result::Result<u32, String> {
    let r = match v.strip_prefix("0x").or_else(|| v.strip_prefix("0X")) {
        Some(h) => u32::from_str_radix(h, 16),
        None => v.parse(),
    };
    r.map_err(|_| format!("{v:?} is not a number"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modbus::fake::rtu;

    fn full_axis() -> AxisFile {
        let mut chip = BTreeMap::new();
        chip.insert("OCD_TH".to_string(), 8);
        chip.insert("CONFIG".to_string(), 0x2C88);
        AxisFile {
            id: 2,
            driver_mode: Some("position".into()),
            step_mode: Some(4),
            max_speed_steps_per_s: Some(2000),
            acceleration_steps_per_s2: Some(4000),
            deceleration_steps_per_s2: Some(6000),
            full_scale_current_a: Some(0.999),
            idle_current_a: Some(0.495),
            overheat_current_a: Some(0.495),
            temperature_limit_c: Some(80),
            requested_speed_steps_per_s: Some(0),
            invert: Some(false),
            homing: Some(HomingFile {
                direction: Some("reverse".into()),
                search_speed_steps_per_s: Some(1600),
                release_speed_steps_per_s: Some(80),
                max_travel_steps: Some(0),
                timeout_s: Some(60),
            }),
            chip: Some(chip),
        }
    }

    #[test]
    fn a_settings_file_round_trips_through_toml() {
        let f = SettingsFile {
            format: 1,
            exported_from: Some("tcp 127.0.0.1:5020".into()),
            watchdog: Some(WatchdogFile {
                modbus_timeout_ms: Some(500),
                modbus_action: Some("soft-stop".into()),
                ..WatchdogFile::default()
            }),
            axis: vec![
                full_axis(),
                AxisFile {
                    id: 3,
                    step_mode: Some(8),
                    ..AxisFile::default()
                },
            ],
        };
        let text = f.to_toml();
        assert!(text.starts_with("# stepctl settings"));
        assert_eq!(SettingsFile::parse(&text), Ok(f));
    }

    #[test]
    fn the_file_names_every_unit_in_its_keys() {
        let text = SettingsFile {
            format: 1,
            axis: vec![full_axis()],
            ..SettingsFile::default()
        }
        .to_toml();
        for key in [
            "max_speed_steps_per_s = 2000",
            "acceleration_steps_per_s2",
            "full_scale_current_a = 0.999",
            "temperature_limit_c = 80",
            "[axis.homing]",
            "[axis.chip]",
        ] {
            assert!(text.contains(key), "{key} in\n{text}");
        }
    }

    #[test]
    fn a_hand_written_partial_file_is_accepted() {
        let f = SettingsFile::parse("format = 1\n[[axis]]\nid = 1\nmax_speed_steps_per_s = 3000\n")
            .unwrap();
        assert_eq!(f.axis[0].max_speed_steps_per_s, Some(3000));
        assert_eq!(f.axis[0].step_mode, None);
    }

    #[test]
    fn values_out_of_range_are_refused_with_their_key_and_range() {
        for (line, want) in [
            ("step_mode = 9", "step_mode = 9 is out of range: 0..=8"),
            ("max_speed_steps_per_s = 70000", "1..=65535 steps/s"),
            ("full_scale_current_a = 7.5", "0..=6.0 A"),
            ("temperature_limit_c = 130", "0..=120"),
            (
                "driver_mode = \"dc\"",
                "use position, binx, auto-run or external",
            ),
        ] {
            let e = SettingsFile::parse(&format!("format = 1\n[[axis]]\nid = 1\n{line}\n"))
                .unwrap_err();
            assert_eq!(e.exit_code(), 1);
            assert!(e.to_string().contains(want), "{line}: {e}");
        }
    }

    #[test]
    fn unknown_keys_and_other_formats_are_refused() {
        assert!(SettingsFile::parse("format = 1\n[[axis]]\nid = 1\nspeed = 3\n").is_err());
        assert!(SettingsFile::parse("format = 2\n").is_err());
        assert!(
            SettingsFile::parse("format = 1\n[[axis]]\nid = 1\n[axis.chip]\nABS_POS = 3\n")
                .is_err()
        );
    }

    #[test]
    fn currents_encode_to_the_nearest_code_at_or_below_and_read_back_exactly() {
        // 1.0 A has no exact Tq/Ai code: 123/8 · 0.065 = 0.999 A.
        assert_eq!(milliamps(current_word(1000)), 999);
        for ma in [0, 65, 495, 999, 1500, 2800, 6000] {
            let word = current_word(ma);
            assert!(milliamps(word) <= ma);
            assert_eq!(current_word(milliamps(word)), word, "{ma} mA is stable");
        }
        // README: BYTE1 = Ai, BYTE0 = Tq; 0x037B = Tq 123, Ai 3.
        assert_eq!(current_word(999), 0x037B);
    }

    #[test]
    fn settings_set_takes_aliases_and_fractions() {
        let f = one_setting(1, "max-speed", "2500").unwrap();
        assert_eq!(f.axis[0].max_speed_steps_per_s, Some(2500));
        let f = one_setting(1, "step-mode", "1/16").unwrap();
        assert_eq!(f.axis[0].step_mode, Some(4));
        let f = one_setting(1, "chip.OCD_TH", "0x0F").unwrap();
        assert_eq!(f.axis[0].chip.as_ref().unwrap()["OCD_TH"], 15);
        let f = one_setting(1, "watchdog.modbus_action", "hold").unwrap();
        assert_eq!(f.watchdog.unwrap().modbus_action.as_deref(), Some("hold"));
    }

    #[test]
    fn settings_set_refuses_out_of_range_values_before_sending() {
        let e = one_setting(1, "current", "9").unwrap_err();
        assert!(e.to_string().contains("out of range"), "{e}");
        assert!(one_setting(1, "bogus", "1").is_err());
        assert!(one_setting(1, "step-mode", "1/3").is_err());
    }

    #[test]
    fn import_writes_only_what_differs_step_mode_first_and_by_the_register_map() {
        let now = full_axis();
        let want = AxisFile {
            id: 2,
            max_speed_steps_per_s: Some(3000),
            step_mode: Some(5),
            full_scale_current_a: Some(0.999),
            ..AxisFile::default()
        };
        // 0x33 = 5 then 0x51 = 3000 (0x0BB8), by FC 0x06; the current is unchanged.
        let mut m = rtu(&[
            ("02 06 00 33 00 05 B9 F5", "02 06 00 33 00 05 B9 F5"),
            ("02 06 00 51 0B B8 DF 6A", "02 06 00 51 0B B8 DF 6A"),
        ]);
        let changes = apply_axis(&mut m, &want, &now).unwrap();
        assert_eq!(changes.len(), 2);
        assert_eq!(
            (
                changes[0].key.as_str(),
                changes[0].from.as_str(),
                changes[0].to.as_str()
            ),
            ("step_mode", "4", "5")
        );
        assert!(m.link.done());
    }

    #[test]
    fn import_writes_32_bit_homing_speeds_high_word_first() {
        let now = full_axis();
        let want = AxisFile {
            id: 2,
            homing: Some(HomingFile {
                search_speed_steps_per_s: Some(100_000),
                ..HomingFile::default()
            }),
            ..AxisFile::default()
        };
        // 0x0404 = 100000 = 0x0001_86A0 by FC 0x10.
        let mut m = rtu(&[(
            "02 10 04 04 00 02 04 00 01 86 A0 FC 00",
            "02 10 04 04 00 02 01 0A",
        )]);
        assert_eq!(apply_axis(&mut m, &want, &now).unwrap().len(), 1);
    }

    #[test]
    fn requested_speed_outside_auto_run_is_reported_as_skipped_not_sent() {
        let now = full_axis();
        let want = AxisFile {
            id: 2,
            requested_speed_steps_per_s: Some(500),
            ..AxisFile::default()
        };
        let mut m = rtu(&[]);
        let c = apply_axis(&mut m, &want, &now).unwrap();
        assert_eq!(c.len(), 1);
        assert!(c[0].skipped.is_some());
    }

    #[test]
    fn export_reads_every_setting_by_the_register_map() {
        let mut script = vec![
            ("02 03 00 14 00 01 C4 3D", "02 03 02 00 04 FD 87"),
            ("02 03 00 23 00 01 75 F3", "02 03 02 00 04 FD 87"),
            ("02 03 00 41 00 01 D4 2D", "02 03 02 07 D0 FF E8"),
            ("02 03 00 42 00 01 24 2D", "02 03 02 0F A0 F9 CC"),
            ("02 03 00 43 00 01 75 ED", "02 03 02 17 70 F2 50"),
            ("02 03 00 20 00 01 85 F3", "02 03 02 03 7B BC 97"),
            ("02 03 00 21 00 01 D4 33", "02 03 02 03 3D 3D 65"),
            ("02 03 00 22 00 01 24 33", "02 03 02 03 3D 3D 65"),
            ("02 03 00 24 00 01 C4 32", "02 03 02 00 50 FC 78"),
            ("02 03 00 46 00 01 65 EC", "02 03 02 00 00 FC 44"),
            ("02 03 00 45 00 01 95 EC", "02 03 02 00 00 FC 44"),
            (
                "02 03 04 03 00 08 B5 0F",
                "02 03 10 00 00 00 00 06 40 00 00 00 50 00 00 00 00 00 3C AD C0",
            ),
        ];
        // The 13 tunable chip registers, in image order (0x01nn, one register each).
        let chip: Vec<(String, String)> = TUNABLE
            .iter()
            .map(|r| {
                (
                    format!("02 03 01 {:02X} 00 01 CC CC", r.address()),
                    "02 03 02 00 08 FD 82".to_string(),
                )
            })
            .collect();
        let chip = crate::modbus::fake::fixed(&chip);
        for (q, r) in &chip {
            script.push((q.as_str(), r.as_str()));
        }
        let mut m = rtu(&script);
        let a = read_axis(&mut m, 2).unwrap();
        let mut want = full_axis();
        want.chip = Some(
            TUNABLE
                .iter()
                .map(|r| (tunable_name(*r).to_string(), 8))
                .collect(),
        );
        assert_eq!(a, want);
        assert!(m.link.done());
    }
}
