//! The commands that follow an axis over time: watch (a live table) and record (samples, plot, CSV).

use std::time::{Duration, Instant};

use serde_json::json;

use super::motion::position_mode;
use super::report::status_table;
use super::{Ctx, Output};
use crate::bus::words_of;
use crate::error::{Error, Result};
use crate::ops::{self, reg};
use crate::plot::{self, Sample};

pub(super) fn watch(ctx: &mut Ctx, axes: &[u8], interval_ms: u64, count: u64) -> Result<Output> {
    let axes = ctx.axes(axes)?;
    let t0 = Instant::now();
    let mut n: u64 = 0;
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
        n = n.saturating_add(1);
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

pub(super) fn record(
    ctx: &mut Ctx,
    unit: u8,
    seconds: f64,
    plot_to: Option<&std::path::Path>,
    csv_to: Option<&std::path::Path>,
    move_to: Option<i32>,
    xy: Option<u8>,
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
    // With --xy: (this axis, the other) per sample.
    let mut pairs = Vec::new();
    while t0.elapsed().as_secs_f64() < seconds {
        let m = ops::motion(ctx.bus, unit)?;
        samples.push(Sample {
            t_s: t0.elapsed().as_secs_f64(),
            position: m.position,
            speed: m.speed,
        });
        faults |= m.faults;
        if let Some(other) = xy {
            let o = ops::motion(ctx.bus, other)?;
            pairs.push((f64::from(m.position), f64::from(o.position)));
            faults |= o.faults;
        }
        std::thread::sleep(Duration::from_millis(5).min(ctx.poll.max(Duration::from_millis(1))));
    }
    if let Some(p) = plot_to {
        let title = format!(
            "axis {unit} on {}: {} samples",
            ctx.bus.name(),
            samples.len()
        );
        match xy {
            Some(other) => {
                let names = (format!("axis {unit}"), format!("axis {other}"));
                plot::xy_svg(p, &title, &names, &pairs)?;
            }
            None => plot::svg(p, &title, &samples)?,
        }
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
