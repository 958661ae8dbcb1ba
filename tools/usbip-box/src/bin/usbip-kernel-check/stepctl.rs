//! stepctl `--usb` end to end through the kernel's hidraw: the USB subset
//! of `scripts/stepctl-e2e` (scan, info, status, move, jog, settings export
//! → change → import --save → read back, a second import writes nothing, a
//! value out of range refused before sending).

use std::process::Command;
use std::time::Instant;

use serde_json::Value;

use crate::{Args, Checks};

struct Run {
    code: i32,
    json: Value,
    text: String,
}

fn stepctl(args: &Args, argv: &[&str]) -> Result<Run, String> {
    let t0 = Instant::now();
    let out = Command::new(&args.stepctl)
        .arg("--usb")
        .arg("--json")
        .args(argv)
        .output()
        .map_err(|e| format!("cannot run {}: {e}", args.stepctl))?;
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let json = serde_json::from_slice(&out.stdout).unwrap_or(Value::Null);
    let code = out.status.code().unwrap_or(-1);
    println!(
        "  stepctl --usb {} -> exit {code} in {:.2} s",
        argv.join(" "),
        t0.elapsed().as_secs_f64()
    );
    Ok(Run { code, json, text })
}

/// `stepctl ARGV` exits 0; its JSON.
fn ok(c: &mut Checks, args: &Args, argv: &[&str]) -> Result<Value, String> {
    let r = stepctl(args, argv)?;
    if r.code != 0 {
        c.check(
            &format!("stepctl {}: exit 0", argv.join(" ")),
            false,
            r.text.trim(),
        );
    }
    Ok(r.json)
}

pub fn run(c: &mut Checks, args: &Args) -> Result<(), String> {
    reads(c, args)?;
    moves(c, args)?;
    settings(c, args)
}

/// scan, info, status: one device, 4 axes at rest at 0.
fn reads(c: &mut Checks, args: &Args) -> Result<(), String> {
    let j = ok(c, args, &["scan"])?;
    let found = j["usb"].as_array().cloned().unwrap_or_default();
    c.eq("stepctl scan: one USB device", found.len(), 1);
    c.eq(
        "stepctl scan: product, path",
        (
            found.first().and_then(|f| f["product"].as_str()),
            found
                .first()
                .and_then(|f| f["path"].as_str())
                .is_some_and(|p| p.starts_with("/dev/hidraw")),
        ),
        (Some("PoStep60-256"), true),
    );
    let j = ok(c, args, &["info"])?;
    c.eq("stepctl info: 4 axes", j["axes"].as_u64(), Some(4));
    let j = ok(c, args, &["status"])?;
    let st: Vec<String> = j["axes"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|x| {
                    format!(
                        "{}:{}:{}",
                        x["axis"],
                        x["position"],
                        x["state"].as_str().unwrap_or("?")
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    c.eq(
        "stepctl status: 4 axes at 0, idle",
        st.join(" "),
        "1:0:idle 2:0:idle 3:0:idle 4:0:idle".to_string(),
    );
    Ok(())
}

/// move (waits) and jog on axis 1.
fn moves(c: &mut Checks, args: &Args) -> Result<(), String> {
    let t0 = Instant::now();
    let j = ok(
        c,
        args,
        &[
            "move", "1", "3000", "--speed", "2000", "--acc", "4000", "--dec", "4000",
        ],
    )?;
    c.eq(
        "stepctl move 1 3000 (waits): arrives",
        j["position"].as_i64(),
        Some(3000),
    );
    println!("  (the move took {:.2} s)", t0.elapsed().as_secs_f64());
    let j = ok(c, args, &["status", "1"])?;
    c.eq(
        "stepctl status 1 after the move",
        j["axes"][0]["position"].as_i64(),
        Some(3000),
    );
    let j = ok(c, args, &["jog", "1", "-500"])?;
    c.eq("stepctl jog 1 -500", j["position"].as_i64(), Some(2500));
    Ok(())
}

/// settings export → change → import --save → read back; again writes
/// nothing; a value out of range is refused before sending.
fn settings(c: &mut Checks, args: &Args) -> Result<(), String> {
    let file = format!("{}/usb-box.toml", args.work);
    let changed = format!("{}/usb-changed.toml", args.work);
    ok(c, args, &["settings", "export", &file])?;
    let text = std::fs::read_to_string(&file).map_err(|e| format!("{file}: {e}"))?;
    c.check(
        "stepctl settings export: axis 1's max speed 2000 (set by the move) in the file",
        text.lines().any(|l| l == "max_speed_steps_per_s = 2000"),
        format!("{} axes", text.matches("[[axis]]").count()),
    );
    std::fs::write(&changed, changed_settings(&text)).map_err(|e| format!("{changed}: {e}"))?;
    let j = ok(c, args, &["settings", "import", &changed, "--save"])?;
    c.eq(
        "stepctl settings import --save: 5 written, saved",
        (j["written"].as_u64(), j["saved"].as_bool()),
        (Some(5), Some(true)),
    );
    let j = ok(c, args, &["settings", "show", "1", "2"])?;
    let got = (
        j["axis"][1]["max_speed_steps_per_s"].as_u64(),
        j["axis"][1]["temperature_limit_c"].as_u64(),
        j["axis"][1]["full_scale_current_a"].as_f64(),
        j["axis"][0]["chip"]["OCD_TH"].as_u64(),
        j["watchdog"]["modbus_timeout_ms"].as_u64(),
    );
    // 1.2 A is stored as the nearest Tq/Ai code at or below: 1.194 A.
    c.eq(
        "stepctl settings show: read back what the import wrote",
        got,
        (Some(2500), Some(70), Some(1.194), Some(12), Some(60000)),
    );
    let j = ok(c, args, &["settings", "import", &changed])?;
    c.eq(
        "stepctl settings import again: writes nothing",
        j["written"].as_u64(),
        Some(0),
    );
    let r = stepctl(args, &["settings", "set", "2", "step-mode", "12"])?;
    c.check(
        "stepctl settings set 2 step-mode 12: exit 1 before sending",
        r.code == 1 && r.text.contains("out of range"),
        r.text.lines().last().unwrap_or(""),
    );
    Ok(())
}

/// The exported file with axis 2's max speed 2500, limit 70 °C and 1.2 A,
/// axis 1's OCD_TH 12 and the Modbus watchdog on (as scripts/stepctl-e2e
/// changes them).
fn changed_settings(text: &str) -> String {
    let mut axis = 0;
    let mut out = Vec::new();
    for l in text.lines() {
        if l == "[[axis]]" {
            axis += 1;
        }
        let l = match (axis, l) {
            (2, l) if l.starts_with("max_speed_steps_per_s =") => "max_speed_steps_per_s = 2500",
            (2, l) if l.starts_with("temperature_limit_c =") => "temperature_limit_c = 70",
            (2, l) if l.starts_with("full_scale_current_a =") => "full_scale_current_a = 1.2",
            (1, l) if l.starts_with("OCD_TH =") => "OCD_TH = 12",
            (_, l) if l.starts_with("modbus_timeout_ms =") => "modbus_timeout_ms = 60000",
            (_, l) => l,
        };
        out.push(l);
    }
    out.join("\n") + "\n"
}
