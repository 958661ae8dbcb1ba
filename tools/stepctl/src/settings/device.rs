//! Settings on the box: read an axis's and the watchdog's, apply a file's
//! (only what differs, in an order that keeps each value meaningful).

use std::collections::BTreeMap;

use bridge_logic::ext_space::{block, homing, watchdog};
use bridge_logic::postep60::settings::TUNABLE;
use serde::Serialize;

use super::{
    action_code, action_key, amps, current_word, milliamps, mode_code, mode_key, to_ma, tunable,
    tunable_name, AxisFile, HomingFile, WatchdogFile,
};
use crate::bus::{u32_of, words_of, Bus};
use crate::error::Result;
use crate::ops::{self, ext, one};

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
    apply_motion(&mut a, want, now)?;
    if let Some(h) = &want.homing {
        apply_homing(&mut a, h, &now.homing.clone().unwrap_or_default())?;
    }
    if let Some(chip) = &want.chip {
        apply_chip(&mut a, chip, &now.chip.clone().unwrap_or_default())?;
    }
    apply_mode(&mut a, want, now)?;
    Ok(a.changes)
}

/// Step mode first (the speeds are in its unit), then the speeds, the
/// currents and the temperature limit.
fn apply_motion(a: &mut Applier, want: &AxisFile, now: &AxisFile) -> Result<()> {
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
    Ok(())
}

/// The homing parameters (extension 0x0403..0x040A).
fn apply_homing(a: &mut Applier, h: &HomingFile, n: &HomingFile) -> Result<()> {
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
    Ok(())
}

/// The tunable powerSTEP01 registers (extension 0x01nn), by canonical name.
fn apply_chip(
    a: &mut Applier,
    chip: &BTreeMap<String, u32>,
    n: &BTreeMap<String, u32>,
) -> Result<()> {
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
    Ok(())
}

/// The driver mode last, then what auto run needs (invert, the requested
/// speed): written in auto run only, reported as skipped otherwise.
fn apply_mode(a: &mut Applier, want: &AxisFile, now: &AxisFile) -> Result<()> {
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
    Ok(())
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
        let at = base.saturating_add((k as u16).saturating_mul(2));
        a.u16(&format!("watchdog.{bus_name}_timeout_ms"), *nt, *wt, at)?;
        if let Some(w) = wa {
            a.write(
                &format!("watchdog.{bus_name}_action"),
                show(na.clone()),
                w.clone(),
                at.saturating_add(1),
                &[action_code(w).unwrap_or(1)],
            )?;
        }
    }
    for c in &mut a.changes {
        c.axis = None;
    }
    Ok(a.changes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modbus::fake::rtu;
    use crate::settings::test_util::full_axis;

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
