//! Every persisted setting of every axis, with units: what `settings show`
//! prints, `settings export` writes as TOML, `settings import` and
//! `settings set` apply. Units are in the key names; a header in the file
//! lists them (PoStep60 manual §8.3 / §9.3 and docs/extension-space.md).
//!
//! Reached over Modbus (and USB, except the requested speed):
//! driver mode, step mode, max speed / acceleration / deceleration,
//! the three currents, temperature limit, requested speed and invert (auto
//! run), homing parameters (extension 0x0403..0x040A), the tunable
//! powerSTEP01 registers (extension 0x01nn) and the bridge's communication
//! watchdog (0x0500..0x0505). The end switch, BINx steps and custom name
//! have no Modbus register; the settings store keeps them as USB sets them.
//!
//! This file holds the file's format, its units and codes, and `settings
//! set`'s keys; the checks before anything is sent are in `validate.rs`,
//! reading and writing the box in `device.rs`.

mod device;
mod validate;

pub use device::{apply_axis, apply_watchdog, read_axis, read_watchdog, Change};

use std::collections::BTreeMap;

use bridge_logic::postep60::current::Current;
use bridge_logic::postep60::settings::TUNABLE;
use bridge_logic::powerstep::registers::Register;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The board's current limit (manual 6.1; docs/PRODUCT.md "Currents"), mA.
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

impl SettingsFile {
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

/// What the settings tests share: an axis with every setting given.
#[cfg(test)]
mod test_util {
    use super::*;

    pub(crate) fn full_axis() -> AxisFile {
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::test_util::full_axis;

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
    fn currents_encode_to_the_nearest_code_at_or_below_and_read_back_exactly() {
        // 1.0 A has no exact Tq/Ai code: 123/8 · 0.065 = 0.999 A.
        assert_eq!(milliamps(current_word(1000)), 999);
        for ma in [0, 65, 495, 999, 1500, 2800, 6000] {
            let word = current_word(ma);
            assert!(milliamps(word) <= ma);
            assert_eq!(current_word(milliamps(word)), word, "{ma} mA is stable");
        }
        // docs/modbus.md: BYTE1 = Ai, BYTE0 = Tq; 0x037B = Tq 123, Ai 3.
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
}
