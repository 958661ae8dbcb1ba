//! Every command: requests through a [`Bus`], a result as text and as JSON.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use bridge_logic::ext_space::{block, diag, homing};
use comfy_table::{presets, Table};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::{json, Value};

use crate::bus::{hex, u32_of, words_of, Bus};
use crate::cli::{Command, Limits, SettingsCmd, Wait};
use crate::error::{Error, Result};
use crate::ops::{self, ext, one, reg};
use crate::plot::{self, Sample};
use crate::settings::{self, Change, SettingsFile};

/// A command's result.
#[derive(Debug, Clone, PartialEq)]
pub struct Output {
    pub text: String,
    pub json: Value,
    /// The exit status after printing (0, or `exit::DOCTOR_FAIL`).
    pub code: i32,
}

impl Output {
    fn new(text: impl Into<String>, json: Value) -> Output {
        Output {
            text: text.into(),
            json,
            code: 0,
        }
    }
}

/// How the command runs: JSON or not, the first id, progress shown or not.
pub struct Ctx<'a> {
    pub bus: &'a mut dyn Bus,
    pub first_id: u8,
    pub json: bool,
    /// Progress bars and live tables (stderr / stdout is a terminal).
    pub interactive: bool,
    /// How long to pause between polls (tests use 0).
    pub poll: Duration,
}

impl Ctx<'_> {
    fn explain(&mut self, unit: u8, address: u16, e: Error) -> Error {
        ops::explain(self.bus, unit, address, e)
    }

    fn write(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<()> {
        match self.bus.write(unit, address, values) {
            Ok(()) => Ok(()),
            Err(e) => Err(self.explain(unit, address, e)),
        }
    }

    /// The given axes, or every axis of the box.
    fn axes(&mut self, given: &[u8]) -> Result<Vec<u8>> {
        if !given.is_empty() {
            return Ok(given.to_vec());
        }
        let n = ops::chain_length(self.bus, self.first_id)?;
        let first = u16::from(self.first_id);
        Ok((first..first + n)
            .filter_map(|u| u8::try_from(u).ok())
            .collect())
    }

    fn sleep(&self) {
        std::thread::sleep(self.poll);
    }
}

pub fn run(ctx: &mut Ctx, cmd: &Command) -> Result<Output> {
    match cmd {
        Command::Scan { ids, probe_ms } => scan(ctx, *ids, *probe_ms),
        Command::Info => info(ctx),
        Command::Status { axes } => status(ctx, axes),
        Command::Move {
            axis,
            position,
            limits,
            wait,
        } => move_to(ctx, *axis, *position, limits, wait),
        Command::Jog {
            axis,
            steps,
            limits,
            wait,
        } => {
            let now = ops::motion(ctx.bus, *axis)?;
            let target = now.target.checked_add(*steps).ok_or_else(|| {
                Error::Usage(format!(
                    "jog {steps} from {} leaves the 32-bit position range",
                    now.target
                ))
            })?;
            move_to(ctx, *axis, target, limits, wait)
        }
        Command::Run { axis, speed } => run_at(ctx, *axis, *speed),
        Command::Stop { axes } => {
            let axes = ctx.axes(axes)?;
            for a in &axes {
                ctx.write(*a, reg::STOP, &[0])?;
            }
            Ok(Output::new(
                format!("stopped axis {}", list(&axes)),
                json!({ "stopped": axes }),
            ))
        }
        Command::Zero { axis } => simple(ctx, *axis, reg::SET_ZERO, 0, "position is now 0"),
        Command::Wake { axis } => simple(ctx, *axis, reg::RUN_SLEEP, ops::RUN, "motor powered"),
        Command::Sleep { axis } => simple(
            ctx,
            *axis,
            reg::RUN_SLEEP,
            ops::SLEEP,
            "motor unpowered (asleep)",
        ),
        Command::ResetFaults { axis } => simple(ctx, *axis, reg::RESET_FAULTS, 0, "faults cleared"),
        Command::Home { axis, wait } => home(ctx, *axis, wait),
        Command::Settings(s) => settings_cmd(ctx, s),
        Command::Watch {
            axes,
            interval_ms,
            count,
        } => watch(ctx, axes, *interval_ms, *count),
        Command::Record {
            axis,
            seconds,
            plot,
            csv,
            move_to,
        } => record(
            ctx,
            *axis,
            *seconds,
            plot.as_deref(),
            csv.as_deref(),
            *move_to,
        ),
        Command::Raw {
            axis,
            command,
            values,
            count,
        } => raw(ctx, *axis, *command, values, *count),
        Command::Doctor {
            expect_axes,
            supply,
            loopback,
            seconds,
            tick_tolerance,
        } => doctor(
            ctx,
            *expect_axes,
            *supply,
            *loopback,
            *seconds,
            *tick_tolerance,
        ),
    }
}

fn doctor(
    ctx: &mut Ctx,
    expect_axes: Option<u16>,
    supply: f64,
    loopback: bool,
    seconds: f64,
    tick_tolerance: f64,
) -> Result<Output> {
    use crate::doctor::{self, Expect, Options};
    if !(1.0..=1000.0).contains(&supply) {
        return Err(Error::Usage(format!(
            "--supply {supply}: a nominal supply in V, 1..=1000"
        )));
    }
    if !(0.0..=100.0).contains(&tick_tolerance) {
        return Err(Error::Usage(format!(
            "--tick-tolerance {tick_tolerance}: a percentage, 0..=100"
        )));
    }
    let opts = Options {
        first_id: ctx.first_id,
        loopback,
        seconds,
    };
    let expect = Expect {
        axes: expect_axes,
        supply_v: supply,
        tick_tolerance: tick_tolerance / 100.0,
    };
    let checks = doctor::run(ctx.bus, &opts, &expect)?;
    let (ok, warn, fail) = doctor::summary(&checks);
    let code = if fail > 0 {
        crate::error::exit::DOCTOR_FAIL
    } else {
        0
    };
    Ok(Output {
        text: doctor::text(&checks),
        json: json!({
            "bus": ctx.bus.name(),
            "checks": checks,
            "summary": { "ok": ok, "warn": warn, "fail": fail },
            "exit_code": code,
        }),
        code,
    })
}

fn list(axes: &[u8]) -> String {
    axes.iter()
        .map(u8::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

fn simple(ctx: &mut Ctx, unit: u8, address: u16, value: u16, done: &str) -> Result<Output> {
    ctx.write(unit, address, &[value])?;
    Ok(Output::new(
        format!("axis {unit}: {done}"),
        json!({ "axis": unit, "ok": true }),
    ))
}

fn scan(ctx: &mut Ctx, (lo, hi): (u8, u8), probe_ms: u64) -> Result<Output> {
    let name = ctx.bus.name();
    ctx.bus.set_timeout_ms(probe_ms);
    let mut found = Vec::new();
    for id in lo..=hi {
        match ctx.bus.read(id, reg::HW_FW_INFO, 3) {
            Ok(v) => {
                let fw = v.get(2).copied().unwrap_or(0);
                found.push(json!({
                    "id": id,
                    "driver_id": format!("0x{:02X}", v.first().copied().unwrap_or(0) & 0xFF),
                    "firmware": format!("{}.{}", fw >> 8, fw & 0xFF),
                }));
            }
            // It answered, if only with an exception: something is there.
            Err(Error::Exception { code, .. }) => {
                found.push(json!({ "id": id, "exception": code }))
            }
            Err(_) => {}
        }
    }
    if found.is_empty() {
        return Err(Error::Comm(format!(
            "no id in {lo}-{hi} answered on {name} within {probe_ms} ms each \
             (baud rate and parity as the box's settings? --probe-ms longer?)"
        )));
    }
    let mut t = table(&["id", "driver id", "firmware"]);
    for f in &found {
        t.add_row(vec![
            f["id"].to_string(),
            f["driver_id"].as_str().unwrap_or("?").to_string(),
            f["firmware"].as_str().unwrap_or("-").to_string(),
        ]);
    }
    Ok(Output::new(
        format!("{} id(s) answered on {name}:\n{t}", found.len()),
        json!({ "bus": name, "ids": found }),
    ))
}

fn table(header: &[&str]) -> Table {
    let mut t = Table::new();
    t.load_preset(presets::ASCII_BORDERS_ONLY_CONDENSED);
    t.set_header(header.to_vec());
    t
}

fn info(ctx: &mut Ctx) -> Result<Output> {
    let i = ops::box_info(ctx.bus, ctx.first_id)?;
    let text = format!(
        "box on {}\n  PoStep60 driver id {}, hardware {}, firmware {} (build {})\n  axes: {} (ids {}..={})\n  \
         last reset: {}; settings: {}; up {} s",
        i.bus,
        i.driver_id,
        i.hardware,
        i.firmware,
        i.build_id,
        i.axes,
        ctx.first_id,
        u16::from(ctx.first_id) + i.axes.max(1) - 1,
        i.reset_cause,
        i.settings_source,
        i.uptime_s
    );
    Ok(Output::new(
        text,
        serde_json::to_value(&i).unwrap_or(Value::Null),
    ))
}

fn status_table(rows: &[ops::AxisStatus]) -> Table {
    let mut t = table(&[
        "axis", "position", "target", "speed/s", "state", "mode", "driver", "faults", "temp °C",
        "supply V",
    ]);
    for s in rows {
        t.add_row(vec![
            s.axis.to_string(),
            s.position.to_string(),
            s.target.to_string(),
            s.speed.to_string(),
            s.state.to_string(),
            format!("{} {}", s.mode, s.mode_name),
            s.driver_status_name.to_string(),
            s.fault_names.clone(),
            format!("{:.1}", s.temperature_c),
            format!("{:.2}", s.voltage_v),
        ]);
    }
    t
}

fn statuses(ctx: &mut Ctx, axes: &[u8]) -> Result<Vec<ops::AxisStatus>> {
    let axes = ctx.axes(axes)?;
    axes.iter().map(|a| ops::axis_status(ctx.bus, *a)).collect()
}

fn status(ctx: &mut Ctx, axes: &[u8]) -> Result<Output> {
    let rows = statuses(ctx, axes)?;
    Ok(Output::new(
        status_table(&rows).to_string(),
        json!({ "axes": rows }),
    ))
}

/// Switch an auto-run axis to position mode (what a move means); a note.
fn position_mode(ctx: &mut Ctx, unit: u8) -> Result<Option<String>> {
    let mode = one(ctx.bus, unit, reg::DRIVER_MODE)?;
    if mode == 6 {
        ctx.write(unit, reg::SET_MODE, &[4])?;
        return Ok(Some(format!(
            "axis {unit}: driver mode auto run -> position (for the move)"
        )));
    }
    Ok(None)
}

fn set_limits(ctx: &mut Ctx, unit: u8, l: &Limits) -> Result<()> {
    for (v, address) in [(l.speed, 0x51), (l.acc, 0x52), (l.dec, 0x53)] {
        if let Some(v) = v {
            ctx.write(unit, address, &[v])?;
        }
    }
    Ok(())
}

fn move_to(ctx: &mut Ctx, unit: u8, target: i32, limits: &Limits, wait: &Wait) -> Result<Output> {
    let note = position_mode(ctx, unit)?;
    if let Some(n) = &note {
        eprintln!("stepctl: {n}");
    }
    set_limits(ctx, unit, limits)?;
    let start = ops::motion(ctx.bus, unit)?;
    ctx.write(unit, reg::SET_POSITION, &words_of(target as u32))?;
    if wait.no_wait {
        return Ok(Output::new(
            format!("axis {unit}: moving to {target}"),
            json!({ "axis": unit, "target": target, "waited": false }),
        ));
    }
    let t0 = Instant::now();
    let end = wait_arrival(ctx, unit, start.position, target, wait.timeout)?;
    let s = t0.elapsed().as_secs_f64();
    Ok(Output::new(
        format!("axis {unit}: at {} after {s:.2} s", end.position),
        json!({ "axis": unit, "target": target, "position": end.position, "waited": true, "seconds": s }),
    ))
}

/// Poll until the axis rests on `target`; a fault or a stop elsewhere
/// ends it with [`Error::Fault`], the timeout with [`Error::Timeout`].
fn wait_arrival(
    ctx: &mut Ctx,
    unit: u8,
    from: i32,
    target: i32,
    timeout_s: f64,
) -> Result<ops::Motion> {
    let len = u64::from(target.abs_diff(from));
    let bar = if ctx.interactive && !ctx.json {
        let b = ProgressBar::new(len.max(1));
        if let Ok(style) =
            ProgressStyle::with_template("axis {prefix} [{bar:40}] {pos}/{len} steps {msg}")
        {
            b.set_style(style.progress_chars("=> "));
        }
        b.set_prefix(unit.to_string());
        b
    } else {
        ProgressBar::hidden()
    };
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s.max(0.0));
    let mut resting_elsewhere = 0;
    loop {
        let m = ops::motion(ctx.bus, unit)?;
        bar.set_position(u64::from(m.position.abs_diff(from)).min(len));
        bar.set_message(format!("{} steps/s", m.speed));
        if m.faults & ops::STOPPING_FAULTS != 0 {
            bar.abandon();
            return Err(Error::Fault(format!(
                "axis {unit}: fault {} at position {} (target {target}): the axis stopped; \
                 clear with `stepctl reset-faults {unit}`",
                ops::fault_names(m.faults),
                m.position
            )));
        }
        if m.settled() && m.position == target {
            bar.finish_and_clear();
            return Ok(m);
        }
        // Resting, not on the target, several polls in a row: something
        // stopped it (Stop, an end switch, another master's target).
        if m.settled() {
            resting_elsewhere += 1;
            if resting_elsewhere >= 5 {
                bar.abandon();
                return Err(Error::Fault(format!(
                    "axis {unit}: stopped at {} before reaching {target} (a Stop, the end switch or \
                     another master's command)",
                    m.position
                )));
            }
        } else {
            resting_elsewhere = 0;
        }
        if Instant::now() >= deadline {
            bar.abandon();
            return Err(Error::Timeout(format!(
                "axis {unit}: still at {} ({}) after {timeout_s} s, target {target}",
                m.position,
                ops::state_name(m.state)
            )));
        }
        ctx.sleep();
    }
}

fn run_at(ctx: &mut Ctx, unit: u8, speed: i32) -> Result<Output> {
    if one(ctx.bus, unit, reg::DRIVER_MODE)? != 6 {
        ctx.write(unit, reg::SET_MODE, &[6])?;
    }
    ctx.write(unit, reg::SET_INVERT, &[u16::from(speed < 0)])?;
    ctx.write(
        unit,
        reg::SET_REQUESTED_SPEED,
        &[speed.unsigned_abs() as u16],
    )?;
    Ok(Output::new(
        format!(
            "axis {unit}: running at {speed} steps/s (auto run; `stepctl stop {unit}` stops it)"
        ),
        json!({ "axis": unit, "speed": speed }),
    ))
}

fn homing_result(code: u16) -> &'static str {
    match code {
        1 => "the end switch was not found within the max travel",
        2 => "homing timed out",
        3 => "the end switch is disabled (enable it in the axis's settings, e.g. USB 0xB1)",
        4 => "homing was aborted",
        5 => "the axis faulted",
        6 => "the axis is not ready (moving, asleep or faulted)",
        _ => "unknown reason",
    }
}

fn home(ctx: &mut Ctx, unit: u8, wait: &Wait) -> Result<Output> {
    let cmd = ext(block::HOMING, homing::COMMAND);
    if let Err(e) = ctx.bus.write(unit, cmd, &[1]) {
        return Err(match e {
            Error::Exception { code: 4, what, .. } => {
                let r = one(ctx.bus, unit, ext(block::HOMING, homing::RESULT)).unwrap_or(0);
                Error::Exception {
                    code: 4,
                    what,
                    reason: Some(format!("homing refused: {}", homing_result(r))),
                }
            }
            other => other,
        });
    }
    if wait.no_wait {
        return Ok(Output::new(
            format!("axis {unit}: homing"),
            json!({ "axis": unit, "waited": false }),
        ));
    }
    let deadline = Instant::now() + Duration::from_secs_f64(wait.timeout.max(0.0));
    loop {
        let h = ctx.bus.read(unit, cmd, 3)?;
        match h.first().copied().unwrap_or(0) {
            4 => {
                return Ok(Output::new(
                    format!("axis {unit}: homed, position 0 is the switch edge"),
                    json!({ "axis": unit, "homed": true }),
                ))
            }
            5 => {
                return Err(Error::Fault(format!(
                    "axis {unit}: homing failed: {}",
                    homing_result(h.get(1).copied().unwrap_or(0))
                )))
            }
            _ => {}
        }
        if Instant::now() >= deadline {
            let _ = ctx.bus.write(unit, cmd, &[0]);
            return Err(Error::Timeout(format!(
                "axis {unit}: homing not done after {} s: aborted",
                wait.timeout
            )));
        }
        ctx.sleep();
    }
}

fn settings_cmd(ctx: &mut Ctx, cmd: &SettingsCmd) -> Result<Output> {
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
    let axes = v["axis"].as_array().cloned().unwrap_or_default();
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
    let deadline = Instant::now() + Duration::from_secs(15);
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
        if u32_of(&now[2..4]) != u32_of(&before[2..4]) {
            return Err(Error::Exception {
                code: 4,
                what: format!("id {unit}: write settings"),
                reason: Some(
                    "the box could not write its settings flash (save error counted)".into(),
                ),
            });
        }
        if u32_of(&now[..2]) != u32_of(&before[..2]) {
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

fn watch(ctx: &mut Ctx, axes: &[u8], interval_ms: u64, count: u64) -> Result<Output> {
    let axes = ctx.axes(axes)?;
    let t0 = Instant::now();
    let mut n = 0;
    let clear = ctx.interactive && !ctx.json;
    let mut last: Vec<ops::AxisStatus>;
    loop {
        let rows: Vec<ops::AxisStatus> = axes
            .iter()
            .map(|a| ops::axis_status(ctx.bus, *a))
            .collect::<Result<_>>()?;
        let t = t0.elapsed().as_secs_f64();
        if ctx.json {
            println!("{}", json!({ "t_s": t, "axes": rows }));
        } else {
            if clear {
                print!("\x1b[2J\x1b[H");
            }
            println!(
                "{} t = {t:.1} s (Ctrl-C ends)\n{}",
                ctx.bus.name(),
                status_table(&rows)
            );
        }
        last = rows;
        n += 1;
        if count != 0 && n >= count {
            break;
        }
        std::thread::sleep(Duration::from_millis(interval_ms));
    }
    // Everything was printed as it came.
    Ok(Output::new(
        String::new(),
        json!({ "refreshes": n, "axes": last, "printed": true }),
    ))
}

fn record(
    ctx: &mut Ctx,
    unit: u8,
    seconds: f64,
    plot_to: Option<&std::path::Path>,
    csv_to: Option<&std::path::Path>,
    move_to: Option<i32>,
) -> Result<Output> {
    if !(seconds > 0.0 && seconds <= 3600.0) {
        return Err(Error::Usage(format!("--seconds {seconds}: 0 < s <= 3600")));
    }
    if let Some(p) = move_to {
        if let Some(n) = position_mode(ctx, unit)? {
            eprintln!("stepctl: {n}");
        }
        ctx.write(unit, reg::SET_POSITION, &words_of(p as u32))?;
    }
    let t0 = Instant::now();
    let mut samples = Vec::new();
    let mut faults = 0;
    while t0.elapsed().as_secs_f64() < seconds {
        let m = ops::motion(ctx.bus, unit)?;
        samples.push(Sample {
            t_s: t0.elapsed().as_secs_f64(),
            position: m.position,
            speed: m.speed,
        });
        faults |= m.faults;
        std::thread::sleep(Duration::from_millis(5).min(ctx.poll.max(Duration::from_millis(1))));
    }
    if let Some(p) = plot_to {
        let title = format!(
            "axis {unit} on {}: {} samples",
            ctx.bus.name(),
            samples.len()
        );
        plot::svg(p, &title, &samples)?;
    }
    if let Some(p) = csv_to {
        std::fs::write(p, plot::csv(&samples))
            .map_err(|e| Error::Usage(format!("cannot write {}: {e}", p.display())))?;
    }
    let pmin = samples.iter().map(|s| s.position).min().unwrap_or(0);
    let pmax = samples.iter().map(|s| s.position).max().unwrap_or(0);
    let vmax = samples
        .iter()
        .map(|s| s.speed.unsigned_abs())
        .max()
        .unwrap_or(0);
    let mut text = format!(
        "axis {unit}: {} samples in {seconds} s; position {pmin}..{pmax} steps, top speed {vmax} steps/s",
        samples.len()
    );
    if let Some(p) = plot_to {
        text.push_str(&format!("; plot {}", p.display()));
    }
    if let Some(p) = csv_to {
        text.push_str(&format!("; csv {}", p.display()));
    }
    if faults & ops::STOPPING_FAULTS != 0 {
        text.push_str(&format!("; FAULT {}", ops::fault_names(faults)));
    }
    Ok(Output::new(
        text,
        json!({
            "axis": unit, "samples": samples.len(), "seconds": seconds,
            "position_min": pmin, "position_max": pmax, "speed_max": vmax,
            "plot": plot_to, "csv": csv_to, "faults": faults,
        }),
    ))
}

fn raw(
    ctx: &mut Ctx,
    unit: u8,
    command: u16,
    values: &[u16],
    count: Option<u16>,
) -> Result<Output> {
    let count = if !ctx.bus.is_modbus() {
        count
    } else if let Some(c) = count {
        Some(c)
    } else if command >> 8 == 0 && values.is_empty() {
        use bridge_logic::transport::modbus::map::registers;
        match registers(command) {
            Some((n, false)) => Some(u16::from(n)),
            Some((_, true)) => {
                return Err(Error::Usage(format!(
                    "0x{command:04X} is a write command: give its value(s)"
                )))
            }
            // Let the box say what it thinks of it (exception 02).
            None => Some(1),
        }
    } else {
        Some(1)
    };
    let r = match ctx.bus.raw(unit, command, values, count) {
        Ok(r) => r,
        Err(e) => return Err(ctx.explain(unit, command, e)),
    };
    let mut text = format!("-> {}\n<- {}", hex(&r.request), hex(&r.reply));
    if !r.registers.is_empty() {
        let regs: Vec<String> = r
            .registers
            .iter()
            .map(|v| format!("0x{v:04X} ({v})"))
            .collect();
        text.push_str(&format!("\nregisters: {}", regs.join(", ")));
    }
    Ok(Output::new(
        text,
        json!({
            "request": hex(&r.request), "reply": hex(&r.reply), "registers": r.registers,
        }),
    ))
}

/// `scan --usb`: the devices, without opening them.
pub fn scan_usb(found: &[crate::usb::Found]) -> Result<Output> {
    if found.is_empty() {
        return Err(crate::usb::not_found());
    }
    let mut t = table(&["serial", "product", "path"]);
    for f in found {
        t.add_row(vec![f.serial.clone(), f.product.clone(), f.path.clone()]);
    }
    Ok(Output::new(
        format!("{} USB device(s):\n{t}", found.len()),
        json!({ "usb": found }),
    ))
}

pub fn is_terminal() -> bool {
    std::io::stderr().is_terminal()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::Cli;
    use crate::modbus::fake::{fixed, framed, rtu};
    use clap::Parser;

    fn command(args: &[&str]) -> Command {
        Cli::try_parse_from(std::iter::once("stepctl").chain(args.iter().copied()))
            .unwrap()
            .command
    }

    fn run_on(
        m: &mut crate::modbus::Rtu<crate::modbus::fake::FakeLink>,
        args: &[&str],
    ) -> Result<Output> {
        let mut ctx = Ctx {
            bus: m,
            first_id: 1,
            json: true,
            interactive: false,
            poll: Duration::ZERO,
        };
        run(&mut ctx, &command(args))
    }

    /// 0x0600 x10 reply: speed, position, target, state, following error, faults.
    fn motion(id: u8, speed: i32, pos: i32, target: i32, state: u16, faults: u16) -> String {
        let mut b = vec![id, 0x03, 20];
        for v in [speed as u32, pos as u32, target as u32] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        for v in [state, 0, faults, 0] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        framed(&b)
    }

    const MOTION_1: &str = "01 03 06 00 00 0A C5 45";

    #[test]
    fn scan_lists_the_ids_that_answer_and_skips_silent_ones() {
        let mut m = rtu(&[
            (
                "01 03 00 0A 00 03 25 C9",
                "01 03 06 00 41 01 00 00 01 DD 46",
            ),
            (
                "02 03 00 0A 00 03 25 FA",
                "02 03 06 00 41 01 00 00 01 C9 B6",
            ),
            ("03 03 00 0A 00 03 24 2B", ""),
        ]);
        let o = run_on(&mut m, &["scan", "--ids", "1-3"]).unwrap();
        let ids: Vec<u64> = o.json["ids"]
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i["id"].as_u64().unwrap())
            .collect();
        assert_eq!(ids, vec![1, 2]);
        assert_eq!(o.json["ids"][0]["firmware"], "0.1");
    }

    #[test]
    fn scan_with_nothing_answering_is_a_communication_error() {
        let mut m = rtu(&[("05 03 00 0A 00 03 24 4D", "")]);
        assert_eq!(
            run_on(&mut m, &["scan", "--ids", "5"])
                .unwrap_err()
                .exit_code(),
            2
        );
    }

    #[test]
    fn status_without_axes_asks_the_chain_length_then_every_axis() {
        let mut m = rtu(&[
            ("01 03 03 40 00 01 85 9A", "01 03 02 00 01 79 84"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            ("01 03 00 13 00 01 75 CF", "01 03 02 00 02 39 85"),
            ("01 03 00 11 00 01 D4 0F", "01 03 02 00 C8 B9 D2"),
            ("01 03 00 10 00 01 85 CF", "01 03 02 01 4D 79 E1"),
        ]);
        let o = run_on(&mut m, &["status"]).unwrap();
        assert_eq!(o.json["axes"][0]["mode_name"], "position");
        assert!(o.text.contains("position"));
        assert!(m.link.done());
    }

    #[test]
    fn move_writes_the_target_by_fc_10_and_waits_until_it_rests_there() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 0B B8 F1 D1",
                "01 10 00 50 00 02 41 D9",
            ),
            (MOTION_1, &motion(1, 1500, 1000, 3000, 2, 0)),
            (MOTION_1, &motion(1, 0, 3000, 3000, 1, 0)),
        ]);
        let o = run_on(&mut m, &["move", "1", "3000"]).unwrap();
        assert_eq!(o.json["position"], 3000);
        assert!(m.link.done());
    }

    #[test]
    fn move_with_limits_writes_them_first() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            ("01 06 00 51 07 D0 DB B7", "01 06 00 51 07 D0 DB B7"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 FF FF FC 18 B7 BD",
                "01 10 00 50 00 02 41 D9",
            ),
        ]);
        run_on(
            &mut m,
            &["move", "1", "-1000", "--speed", "2000", "--no-wait"],
        )
        .unwrap();
        assert!(m.link.done());
    }

    #[test]
    fn a_fault_during_a_move_exits_4_naming_the_fault() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 0B B8 F1 D1",
                "01 10 00 50 00 02 41 D9",
            ),
            (MOTION_1, &motion(1, 0, 1200, 1200, 1, 0x06)),
        ]);
        let e = run_on(&mut m, &["move", "1", "3000"]).unwrap_err();
        assert_eq!(e.exit_code(), 4);
        assert!(
            e.to_string().contains("fault AOCP,BOCP at position 1200"),
            "{e}"
        );
    }

    #[test]
    fn an_axis_that_rests_short_of_its_target_exits_4() {
        let mut script = vec![
            (
                "01 03 00 14 00 01 C4 0E".to_string(),
                "01 03 02 00 04 B9 87".to_string(),
            ),
            (MOTION_1.to_string(), motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 0B B8 F1 D1".into(),
                "01 10 00 50 00 02 41 D9".into(),
            ),
        ];
        for _ in 0..5 {
            script.push((MOTION_1.into(), motion(1, 0, 800, 800, 1, 0)));
        }
        let script = fixed(&script);
        let refs: Vec<(&str, &str)> = script
            .iter()
            .map(|(a, b)| (a.as_str(), b.as_str()))
            .collect();
        let mut m = rtu(&refs);
        let e = run_on(&mut m, &["move", "1", "3000"]).unwrap_err();
        assert_eq!(e.exit_code(), 4);
        assert!(
            e.to_string()
                .contains("stopped at 800 before reaching 3000"),
            "{e}"
        );
    }

    #[test]
    fn move_on_an_asleep_axis_surfaces_exception_04_with_its_meaning() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            ("01 10 00 50 00 02 04 00 00 0B B8 F1 D1", "01 90 04 4D C3"),
            ("01 03 00 13 00 01 75 CF", "01 03 02 00 01 79 84"),
            ("01 03 00 25 00 01 95 C1", "01 03 02 00 00 B8 44"),
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
        ]);
        let e = run_on(&mut m, &["move", "1", "3000"]).unwrap_err();
        assert_eq!(e.exit_code(), 3);
        assert!(
            e.to_string().contains("exception 04: axis is asleep"),
            "{e}"
        );
    }

    #[test]
    fn move_switches_an_auto_run_axis_to_position_mode_first() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 06 38 46"),
            ("01 06 00 05 00 04 98 08", "01 06 00 05 00 04 98 08"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 00 0A 76 94",
                "01 10 00 50 00 02 41 D9",
            ),
        ]);
        run_on(&mut m, &["move", "1", "10", "--no-wait"]).unwrap();
        assert!(m.link.done());
    }

    #[test]
    fn jog_moves_relative_to_the_current_target() {
        let mut m = rtu(&[
            (MOTION_1, &motion(1, 0, 500, 500, 1, 0)),
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            (MOTION_1, &motion(1, 0, 500, 500, 1, 0)),
            (
                "01 10 00 50 00 02 04 00 00 01 90 F7 6F",
                "01 10 00 50 00 02 41 D9",
            ),
        ]);
        let o = run_on(&mut m, &["jog", "1", "-100", "--no-wait"]).unwrap();
        assert_eq!(o.json["target"], 400);
    }

    #[test]
    fn run_sets_auto_run_then_invert_then_the_speed() {
        let mut m = rtu(&[
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            ("01 06 00 05 00 06 19 C9", "01 06 00 05 00 06 19 C9"),
            ("01 06 00 55 00 01 58 1A", "01 06 00 55 00 01 58 1A"),
            ("01 06 00 54 05 DC CA D3", "01 06 00 54 05 DC CA D3"),
        ]);
        run_on(&mut m, &["run", "1", "-1500"]).unwrap();
        assert!(m.link.done());
    }

    #[test]
    fn stop_zero_wake_sleep_and_reset_faults_write_their_registers() {
        for (args, frame) in [
            (&["stop", "2"][..], "02 06 00 5F 00 00 B9 EB"),
            (&["zero", "1"][..], "01 06 00 5E 00 00 E8 18"),
            (&["wake", "1"][..], "01 06 00 03 00 DA F8 51"),
            (&["sleep", "1"][..], "01 06 00 03 00 0F 39 CE"),
            (&["reset-faults", "1"][..], "01 06 00 35 00 00 99 C4"),
        ] {
            let f = fixed(&[(frame.to_string(), frame.to_string())]);
            let mut m = rtu(&[(f[0].0.as_str(), f[0].1.as_str())]);
            run_on(&mut m, args).unwrap();
            assert!(m.link.done(), "{args:?}");
        }
    }

    #[test]
    fn home_starts_through_the_extension_and_waits_for_done() {
        let mut m = rtu(&[
            ("01 06 04 00 00 01 49 3A", "01 06 04 00 00 01 49 3A"),
            (
                "01 03 04 00 00 03 04 FB",
                "01 03 06 00 02 00 00 00 00 58 B5",
            ),
            (
                "01 03 04 00 00 03 04 FB",
                "01 03 06 00 04 00 00 00 01 11 75",
            ),
        ]);
        let o = run_on(&mut m, &["home", "1"]).unwrap();
        assert_eq!(o.json["homed"], true);
    }

    #[test]
    fn home_refused_names_the_homing_result() {
        let mut m = rtu(&[
            ("01 06 04 00 00 01 49 3A", "01 86 04 43 A3"),
            ("01 03 04 01 00 01 D4 FA", "01 03 02 00 03 F8 45"),
        ]);
        let e = run_on(&mut m, &["home", "1"]).unwrap_err();
        assert!(
            e.to_string()
                .contains("exception 04: homing refused: the end switch is disabled"),
            "{e}"
        );
    }

    #[test]
    fn raw_reads_a_command_with_its_own_register_count() {
        let mut m = rtu(&[("01 03 00 40 00 02 C5 DF", "01 03 04 FF FF FC 18 BB 1D")]);
        let o = run_on(&mut m, &["raw", "1", "0x40"]).unwrap();
        assert_eq!(o.json["registers"], json!([0xFFFF, 0xFC18]));
        assert!(o.text.contains("<- 01 03 04 FF FF FC 18"));
    }

    #[test]
    fn raw_surfaces_an_exception_with_its_meaning() {
        let mut m = rtu(&[("01 03 00 99 00 01 54 25", "01 83 02 C0 F1")]);
        let e = run_on(&mut m, &["raw", "1", "0x99"]).unwrap_err();
        assert!(
            e.to_string().contains("exception 02: illegal data address"),
            "{e}"
        );
    }

    #[test]
    fn raw_refuses_to_read_a_write_command_before_sending() {
        let mut m = rtu(&[]);
        assert_eq!(
            run_on(&mut m, &["raw", "1", "0x50"])
                .unwrap_err()
                .exit_code(),
            1
        );
    }

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
