//! Every value of a settings file in range, checked before anything is sent.

use std::collections::BTreeMap;

use bridge_logic::postep60::settings::{TEMPERATURE_LIMIT_MAX, TUNABLE};

use super::{
    action_code, amps, mode_code, tunable, tunable_name, AxisFile, HomingFile, SettingsFile,
    WatchdogFile, CURRENT_LIMIT_MA, FORMAT,
};

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
        check((1..=247).contains(&id), || {
            format!("axis id {id} is out of range 1..=247")
        })?;
        let values = || {
            self.validate_motion()?;
            if let Some(h) = &self.homing {
                validate_homing(h)?;
            }
            if let Some(chip) = &self.chip {
                validate_chip(chip)?;
            }
            Ok(())
        };
        values().map_err(|m: String| format!("axis {id}: {m}"))
    }

    /// The driver mode, step mode, speeds, currents and temperature limit.
    fn validate_motion(&self) -> std::result::Result<(), String> {
        if let Some(m) = &self.driver_mode {
            check(mode_code(m).is_some(), || {
                format!("driver_mode = {m:?}: use position, binx, auto-run or external")
            })?;
        }
        range(
            "step_mode",
            self.step_mode.map(u32::from),
            0,
            8,
            "(0 = full .. 8 = 1/256)",
        )?;
        range(
            "max_speed_steps_per_s",
            self.max_speed_steps_per_s,
            1,
            65535,
            "steps/s",
        )?;
        range(
            "acceleration_steps_per_s2",
            self.acceleration_steps_per_s2,
            1,
            65535,
            "steps/s²",
        )?;
        range(
            "deceleration_steps_per_s2",
            self.deceleration_steps_per_s2,
            1,
            65535,
            "steps/s²",
        )?;
        amps_range("full_scale_current_a", self.full_scale_current_a)?;
        amps_range("idle_current_a", self.idle_current_a)?;
        amps_range("overheat_current_a", self.overheat_current_a)?;
        range(
            "temperature_limit_c",
            self.temperature_limit_c,
            0,
            u32::from(TEMPERATURE_LIMIT_MAX),
            "°C",
        )?;
        range(
            "requested_speed_steps_per_s",
            self.requested_speed_steps_per_s,
            0,
            65535,
            "steps/s",
        )?;
        Ok(())
    }
}

/// The homing parameters (extension 0x0403..0x040A).
fn validate_homing(h: &HomingFile) -> std::result::Result<(), String> {
    if let Some(d) = &h.direction {
        check(d == "forward" || d == "reverse", || {
            format!("homing.direction = {d:?}: use forward or reverse")
        })?;
    }
    range(
        "homing.search_speed_steps_per_s",
        h.search_speed_steps_per_s,
        1,
        u32::MAX,
        "steps/s",
    )?;
    range(
        "homing.release_speed_steps_per_s",
        h.release_speed_steps_per_s,
        1,
        u32::MAX,
        "steps/s",
    )?;
    range("homing.timeout_s", h.timeout_s, 0, 65535, "s")?;
    Ok(())
}

/// The tunable powerSTEP01 registers: known names, values within their masks.
fn validate_chip(chip: &BTreeMap<String, u32>) -> std::result::Result<(), String> {
    for (name, v) in chip {
        let r = tunable(name).ok_or_else(|| {
            format!(
                "chip.{name}: not a tunable register ({})",
                TUNABLE
                    .iter()
                    .map(|r| tunable_name(*r))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })?;
        let max = r.mask();
        check(*v <= max, || {
            format!("chip.{name} = {v} is out of range: 0..={max}")
        })?;
    }
    Ok(())
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
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
