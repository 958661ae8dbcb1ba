//! `stepctl settings`: show, set, save, export, import.

use std::time::{Duration, Instant};

use bridge_logic::ext_space::{block, diag};
use comfy_table::{presets, Table};
use serde_json::{json, Value};

use super::{table, Ctx, Output};
use crate::bus::{deadline, u32_of, words_at};
use crate::cli::SettingsCmd;
use crate::error::{Error, Result};
use crate::ops::{ext, reg};
use crate::settings::{self, Change, SettingsFile};

pub(super) fn settings_cmd(ctx: &mut Ctx, cmd: &SettingsCmd) -> Result<Output> {
    match cmd {
        SettingsCmd::Show { axes } => {
            let f = read_all(ctx, axes)?;
            Ok(Output::new(
                show_table(&f),
                serde_json::to_value(&f).unwrap_or(Value::Null),
            ))
        }
        SettingsCmd::Set {
            axis,
            key,
            value,
            save,
        } => {
            let f = settings::one_setting(*axis, key, value)?;
            import(ctx, &f, *save)
        }
        SettingsCmd::Save => save(ctx),
        SettingsCmd::Export { file, axes } => {
            let f = read_all(ctx, axes)?;
            std::fs::write(file, f.to_toml())
                .map_err(|e| Error::Usage(format!("cannot write {}: {e}", file.display())))?;
            Ok(Output::new(
                format!("{} axes written to {}", f.axis.len(), file.display()),
                json!({ "file": file, "axes": f.axis.iter().map(|a| a.id).collect::<Vec<_>>() }),
            ))
        }
        SettingsCmd::Import { file, save } => {
            let text = std::fs::read_to_string(file)
                .map_err(|e| Error::Usage(format!("cannot read {}: {e}", file.display())))?;
            let f = SettingsFile::parse(&text)
                .map_err(|e| Error::Usage(format!("{}: {e}", file.display())))?;
            import(ctx, &f, *save)
        }
    }
}

fn read_all(ctx: &mut Ctx, axes: &[u8]) -> Result<SettingsFile> {
    let axes = ctx.axes(axes)?;
    let mut out = Vec::new();
    for a in axes {
        out.push(settings::read_axis(ctx.bus, a)?);
    }
    let watchdog = Some(settings::read_watchdog(ctx.bus, ctx.first_id)?);
    Ok(SettingsFile {
        format: settings::FORMAT,
        exported_from: Some(ctx.bus.name()),
        watchdog,
        axis: out,
    })
}

fn show_table(f: &SettingsFile) -> String {
    let v = serde_json::to_value(f).unwrap_or(Value::Null);
    let axes = v
        .get("axis")
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default();
    let mut header = vec!["setting".to_string()];
    header.extend(axes.iter().map(|a| format!("axis {}", a["id"])));
    let mut t = Table::new();
    t.load_preset(presets::ASCII_BORDERS_ONLY_CONDENSED);
    t.set_header(header);
    let mut keys: Vec<String> = Vec::new();
    let flat = |a: &Value| {
        let mut out: Vec<(String, String)> = Vec::new();
        if let Some(o) = a.as_object() {
            for (k, v) in o {
                match v {
                    Value::Object(inner) => {
                        for (ik, iv) in inner {
                            out.push((format!("{k}.{ik}"), plain(iv)));
                        }
                    }
                    _ if k == "id" => {}
                    _ => out.push((k.clone(), plain(v))),
                }
            }
        }
        out
    };
    let rows: Vec<Vec<(String, String)>> = axes.iter().map(flat).collect();
    for r in &rows {
        for (k, _) in r {
            if !keys.contains(k) {
                keys.push(k.clone());
            }
        }
    }
    for k in keys {
        let mut row = vec![k.clone()];
        for r in &rows {
            let v = r
                .iter()
                .find(|(rk, _)| *rk == k)
                .map_or("-".to_string(), |(_, v)| v.clone());
            row.push(if k == "step_mode" {
                let m: u8 = v.parse().unwrap_or(0);
                format!("{v} ({})", settings::step_fraction(m))
            } else {
                v
            });
        }
        t.add_row(row);
    }
    let mut out = t.to_string();
    if let Some(w) = &f.watchdog {
        out.push_str(&format!(
            "\ncommunication watchdog: modbus {} ms {}, i2c {} ms {}, usb {} ms {} (0 ms = off)",
            w.modbus_timeout_ms.unwrap_or(0),
            w.modbus_action.as_deref().unwrap_or("?"),
            w.i2c_timeout_ms.unwrap_or(0),
            w.i2c_action.as_deref().unwrap_or("?"),
            w.usb_timeout_ms.unwrap_or(0),
            w.usb_action.as_deref().unwrap_or("?"),
        ));
    }
    out
}

fn plain(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

fn import(ctx: &mut Ctx, f: &SettingsFile, save_after: bool) -> Result<Output> {
    let mut changes: Vec<Change> = Vec::new();
    for want in &f.axis {
        let now = settings::read_axis(ctx.bus, want.id)?;
        changes.extend(settings::apply_axis(ctx.bus, want, &now)?);
    }
    if let Some(w) = &f.watchdog {
        let now = settings::read_watchdog(ctx.bus, ctx.first_id)?;
        changes.extend(settings::apply_watchdog(ctx.bus, ctx.first_id, w, &now)?);
    }
    let mut text = String::new();
    let written = changes.iter().filter(|c| c.skipped.is_none()).count();
    if changes.is_empty() {
        text.push_str("nothing to change: the box already has these settings");
    } else {
        let mut t = table(&["axis", "setting", "was", "now"]);
        for c in &changes {
            t.add_row(vec![
                c.axis.map_or("box".into(), |a| a.to_string()),
                c.key.clone(),
                c.from.clone(),
                match &c.skipped {
                    Some(why) => format!("{} (not written: {why})", c.to),
                    None => c.to.clone(),
                },
            ]);
        }
        text.push_str(&format!("{written} setting(s) written\n{t}"));
    }
    let mut saved = false;
    if save_after {
        let s = save(ctx)?;
        text.push('\n');
        text.push_str(&s.text);
        saved = true;
    } else if written > 0 {
        text.push_str("\n(in use now; `stepctl settings save` keeps them across a restart)");
    }
    Ok(Output::new(
        text,
        json!({ "changes": changes, "written": written, "saved": saved }),
    ))
}

/// Write settings (0x3F), retried while an axis still moves (exception 04),
/// then wait until the box's save counter says the flash was written.
fn save(ctx: &mut Ctx) -> Result<Output> {
    let unit = ctx.first_id;
    let counters = ext(block::DIAG, diag::SAVES);
    let before = ctx.bus.read(unit, counters, 4)?;
    let deadline = deadline(Duration::from_secs(15));
    loop {
        match ctx.bus.write(unit, reg::WRITE_SETTINGS, &[0]) {
            Ok(()) => break,
            Err(Error::Exception { code: 4, .. } | Error::Refused { status: 7, .. })
                if Instant::now() < deadline =>
            {
                std::thread::sleep(Duration::from_millis(100).max(ctx.poll))
            }
            Err(e) => return Err(ctx.explain(unit, reg::WRITE_SETTINGS, e)),
        }
    }
    loop {
        let now = ctx.bus.read(unit, counters, 4)?;
        if u32_of(words_at(&now, 2, 2)) != u32_of(words_at(&before, 2, 2)) {
            return Err(Error::Exception {
                code: 4,
                what: format!("id {unit}: write settings"),
                reason: Some(
                    "the box could not write its settings flash (save error counted)".into(),
                ),
            });
        }
        if u32_of(words_at(&now, 0, 2)) != u32_of(words_at(&before, 0, 2)) {
            return Ok(Output::new(
                "settings saved to the box's flash",
                json!({ "saved": true }),
            ));
        }
        if Instant::now() >= deadline {
            return Err(Error::Timeout(
                "the box did not report the settings save within 15 s".into(),
            ));
        }
        std::thread::sleep(Duration::from_millis(50).max(ctx.poll));
    }
}

#[cfg(test)]
mod tests {
    use crate::app::test_util::*;

    #[test]
    fn save_retries_while_an_axis_moves_then_waits_for_the_save_counter() {
        let mut m = rtu(&[
            (
                "01 03 03 1E 00 04 24 4B",
                "01 03 08 00 00 00 02 00 00 00 00 EC 17",
            ),
            ("01 06 00 3F 00 00 B9 C6", "01 86 04 43 A3"),
            ("01 06 00 3F 00 00 B9 C6", "01 06 00 3F 00 00 B9 C6"),
            (
                "01 03 03 1E 00 04 24 4B",
                "01 03 08 00 00 00 03 00 00 00 00 D1 D7",
            ),
        ]);
        let o = run_on(&mut m, &["settings", "save"]).unwrap();
        assert_eq!(o.json["saved"], true);
    }

    #[test]
    fn settings_set_refuses_an_out_of_range_value_without_sending_anything() {
        let mut m = rtu(&[]);
        let e = run_on(&mut m, &["settings", "set", "1", "step-mode", "12"]).unwrap_err();
        assert_eq!(e.exit_code(), 1);
        assert!(m.link.sent.is_empty());
    }
}
