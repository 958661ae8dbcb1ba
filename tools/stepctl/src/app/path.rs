//! `stepctl path FILE.csv` and `stepctl move 1=… 2=…`: a coordinated move
//! of several axes (extension 0x08nn) and a path of waypoints streamed into
//! its queue as it drains (docs/extension-space.md, *Coordinated moves*).

use std::path::Path;
use std::time::{Duration, Instant};

use bridge_logic::ext_space::{block, coord};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

use super::{list, Ctx, Output};
use crate::bus::{deadline, words_of};
use crate::error::{Error, Result};
use crate::ops::{self, ext};

/// The 0x08nn registers stepctl uses.
const COMMAND: u16 = ext(block::COORD, coord::COMMAND);
const ABORT: u16 = ext(block::COORD, coord::ABORT);
const MEMBERS: u16 = ext(block::COORD, coord::MEMBERS);
const REFUSAL: u16 = ext(block::COORD, coord::REFUSAL);
const PATH_LIMITS: u16 = ext(block::COORD, coord::PATH_SPEED);
const QUEUE_FREE: u16 = ext(block::COORD, coord::QUEUE_FREE);
const TARGETS: u16 = ext(block::COORD, coord::TARGETS);
const WAYPOINT: u16 = ext(block::COORD, coord::WAYPOINT);
/// States of 0x0800.
const DONE: u16 = 5;
const ABORTED: u16 = 6;

/// A path as a file gives it: the axes (user ids) and the waypoints, one
/// position per axis each (logical steps).
#[derive(Debug, Clone, PartialEq)]
pub struct PathFile {
    pub axes: Vec<u8>,
    pub rows: Vec<Vec<i32>>,
}

/// Read a path CSV: a header row naming the axes (`1,2`), then one
/// waypoint per row. Blank lines and lines starting with `#` are skipped.
pub fn parse_csv(text: &str) -> Result<PathFile> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i.saturating_add(1), l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let bad = |n: usize, what: String| Error::Usage(format!("path file line {n}: {what}"));
    let (n, header) = lines
        .next()
        .ok_or_else(|| Error::Usage("path file: no header row (the axes, e.g. 1,2)".into()))?;
    let axes: Vec<u8> = header
        .split(',')
        .map(|c| c.trim().parse::<u8>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| {
            bad(
                n,
                format!("the header names the axes by id (e.g. 1,2,3): {e}"),
            )
        })?;
    if axes.is_empty() || axes.len() > 8 {
        return Err(bad(n, format!("{} axes: 1 to 8", axes.len())));
    }
    if axes.contains(&0) {
        return Err(bad(n, "axis ids start at 1".into()));
    }
    let mut sorted = axes.clone();
    sorted.sort_unstable();
    sorted.dedup();
    if sorted.len() != axes.len() {
        return Err(bad(n, "an axis named twice".into()));
    }
    let mut rows = Vec::new();
    for (n, line) in lines {
        let row: Vec<i32> = line
            .split(',')
            .map(|c| c.trim().parse::<i32>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|e| bad(n, format!("a position (steps): {e}")))?;
        if row.len() != axes.len() {
            return Err(bad(
                n,
                format!("{} values for {} axes", row.len(), axes.len()),
            ));
        }
        rows.push(row);
    }
    if rows.is_empty() {
        return Err(Error::Usage("path file: no waypoint rows".into()));
    }
    Ok(PathFile { axes, rows })
}

/// Path limits as `--speed`, `--acc`, `--dec` give them (0: none).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PathLimits {
    pub speed: u32,
    pub acc: u32,
    pub dec: u32,
}

/// One sample of the recorded path: when its reads started, how long they
/// took (the axes are read one after the other), every axis's position.
#[derive(Debug, Clone, PartialEq)]
pub struct PathSample {
    pub t_s: f64,
    pub span_s: f64,
    pub positions: Vec<i32>,
}

/// The 16 registers of a target per chain axis (axes not named: 0).
fn per_axis(ctx: &Ctx, axes: &[u8], values: &[i32]) -> Result<Vec<u16>> {
    let mut regs = vec![0u16; 16];
    for (&a, &v) in axes.iter().zip(values) {
        let k = chain_index(ctx, a)?.saturating_mul(2);
        if let Some(dst) = regs.get_mut(k..k.saturating_add(2)) {
            dst.copy_from_slice(&words_of(v as u32));
        }
    }
    Ok(regs)
}

fn chain_index(ctx: &Ctx, unit: u8) -> Result<usize> {
    let k = usize::from(unit)
        .checked_sub(usize::from(ctx.first_id))
        .filter(|k| *k < 8)
        .ok_or_else(|| {
            Error::Usage(format!(
                "axis {unit}: not one of the box's (ids {}..={})",
                ctx.first_id,
                u16::from(ctx.first_id) + 7
            ))
        })?;
    Ok(k)
}

/// Why the box refused a start or a waypoint (0x0803), in words.
fn refusal(code: u16) -> String {
    let k = code >> 8;
    match code & 0xFF {
        1 => "a coordinated move is under way".into(),
        2 => "an axis past the chain".into(),
        3 => format!("chain axis {k} is not ready (not at rest, asleep, faulted, homing, or not in position mode)"),
        4 => "a component longer than 2^32 steps".into(),
        5 => "the queue is full".into(),
        6 => "no coordinated move is running".into(),
        7 => format!("the waypoint moves chain axis {k}, which rests through the move (start with a move of every axis)"),
        _ => format!("refusal {code:#06x}"),
    }
}

/// Why a move ended early (0x0801), in words.
fn abort_reason(code: u16) -> String {
    let k = code >> 8;
    let who = if k == 0xFF {
        "the group's stop".to_string()
    } else {
        format!("chain axis {k}")
    };
    let why = match code & 0xFF {
        1 => "stopped",
        2 => "stopped at once (Stop, end switch, sleep)",
        3 => "overcurrent",
        4 => "thermal shutdown",
        5 => "chip reset",
        6 => "chain error",
        _ => "unknown",
    };
    format!("{who}: {why}")
}

/// A refused write: its reason from 0x0803.
fn refused(ctx: &mut Ctx, e: Error, what: &str) -> Error {
    let code = ops::one(ctx.bus, ctx.first_id, REFUSAL).unwrap_or(0);
    if code == 0 {
        return e;
    }
    Error::Fault(format!("{what} refused: {}", refusal(code)))
}

/// Start the coordinated move of `axes` to `targets` with `limits`.
fn start(ctx: &mut Ctx, axes: &[u8], targets: &[i32], limits: PathLimits) -> Result<()> {
    let mut mask = 0u16;
    for &a in axes {
        mask |= 1 << chain_index(ctx, a)?;
        if let Some(n) = super::motion::position_mode(ctx, a)? {
            eprintln!("stepctl: {n}");
        }
    }
    let unit = ctx.first_id;
    ctx.write(unit, MEMBERS, &[mask])?;
    let mut l = Vec::new();
    for v in [limits.speed, limits.acc, limits.dec] {
        l.extend_from_slice(&words_of(v));
    }
    ctx.write(unit, PATH_LIMITS, &l)?;
    let regs = per_axis(ctx, axes, targets)?;
    ctx.write(unit, TARGETS, &regs)?;
    match ctx.bus.write(unit, COMMAND, &[1]) {
        Ok(()) => Ok(()),
        Err(e) => Err(refused(ctx, e, "the coordinated move")),
    }
}

/// Every named axis's position now, one after the other.
fn positions(ctx: &mut Ctx, axes: &[u8]) -> Result<Vec<i32>> {
    axes.iter()
        .map(|&a| Ok(ops::motion(ctx.bus, a)?.position))
        .collect()
}

/// [`positions`] as a sample `t0` on.
fn sample(ctx: &mut Ctx, axes: &[u8], t0: Instant) -> Result<PathSample> {
    let t_s = t0.elapsed().as_secs_f64();
    let positions = positions(ctx, axes)?;
    Ok(PathSample {
        t_s,
        span_s: t0.elapsed().as_secs_f64() - t_s,
        positions,
    })
}

/// Run `file`'s path: a coordinated move to its first row, then every
/// other row queued as the queue drains, with a progress bar; wait until
/// it is done. Samples every axis's position at each poll.
pub(super) fn run_path(
    ctx: &mut Ctx,
    file: &PathFile,
    limits: PathLimits,
    timeout_s: f64,
    record: Option<&Path>,
    plot: Option<&Path>,
) -> Result<Output> {
    let axes = &file.axes;
    // Rows where the axes already are move nothing (a move with no distance
    // to go is done at once and takes no waypoints): the path starts with
    // the first row that moves.
    let here = positions(ctx, axes)?;
    let skip = file.rows.iter().take_while(|r| **r == here).count();
    let t0 = Instant::now();
    let Some((first, rest)) = file.rows.get(skip..).and_then(|r| r.split_first()) else {
        return Ok(Output::new(
            format!("path: axes {} already on its last row {here:?}", list(axes)),
            json!({ "axes": axes, "waypoints": file.rows.len(), "positions": here, "arrived": true, "seconds": 0.0, "samples": 0 }),
        ));
    };
    start(ctx, axes, first, limits)?;
    let bar = if ctx.interactive && !ctx.json {
        let b = ProgressBar::new(file.rows.len() as u64);
        if let Ok(style) =
            ProgressStyle::with_template("path [{bar:40}] {pos}/{len} waypoints {msg}")
        {
            b.set_style(style.progress_chars("=> "));
        }
        b
    } else {
        ProgressBar::hidden()
    };
    let end = deadline(Duration::try_from_secs_f64(timeout_s.max(0.0)).unwrap_or(Duration::MAX));
    let unit = ctx.first_id;
    let mut fed = 0usize;
    let mut samples = Vec::new();
    let state = loop {
        let head = ctx.bus.read(unit, COMMAND, 1)?;
        let state = head.first().copied().unwrap_or(0);
        let free = ops::one(ctx.bus, unit, QUEUE_FREE)?;
        let passed = ops::one(ctx.bus, unit, ext(block::COORD, coord::PASSED))?;
        if state == DONE || state == ABORTED {
            break state;
        }
        for _ in 0..free {
            let Some(row) = rest.get(fed) else {
                break;
            };
            let regs = per_axis(ctx, axes, row)?;
            if let Err(e) = ctx.bus.write(unit, WAYPOINT, &regs) {
                bar.abandon();
                let row = fed.saturating_add(2);
                return Err(refused(ctx, e, &format!("waypoint {row}")));
            }
            fed = fed.saturating_add(1);
        }
        samples.push(sample(ctx, axes, t0)?);
        bar.set_position(u64::from(passed).min(file.rows.len() as u64));
        if Instant::now() >= end {
            bar.abandon();
            return Err(Error::Timeout(format!(
                "path: not done after {timeout_s} s ({passed} waypoints passed)"
            )));
        }
        ctx.sleep();
    };
    let end_sample = sample(ctx, axes, t0)?;
    let last = end_sample.positions.clone();
    samples.push(end_sample);
    if let Some(p) = record {
        write_csv(p, axes, &samples)?;
    }
    if let Some(p) = plot {
        let xy: Vec<(f64, f64)> = samples
            .iter()
            .filter_map(|s| {
                Some((
                    f64::from(*s.positions.first()?),
                    f64::from(*s.positions.get(1)?),
                ))
            })
            .collect();
        let names = (
            format!("axis {}", axes.first().copied().unwrap_or(0)),
            format!("axis {}", axes.get(1).copied().unwrap_or(0)),
        );
        crate::plot::xy_svg(p, "path", &names, &xy)?;
    }
    let s = t0.elapsed().as_secs_f64();
    if state == ABORTED {
        bar.abandon();
        let why = ops::one(ctx.bus, unit, ABORT)?;
        return Err(Error::Fault(format!(
            "path: stopped before its end ({}) with axis {} at {last:?}",
            abort_reason(why),
            list(axes)
        )));
    }
    bar.finish_and_clear();
    let wanted = file.rows.last().cloned().unwrap_or_default();
    let at_end = last == wanted;
    Ok(Output::new(
        format!(
            "path: {} waypoints, axes {} at {last:?} after {s:.2} s",
            file.rows.len(),
            list(axes)
        ),
        json!({
            "axes": axes,
            "waypoints": file.rows.len(),
            "positions": last,
            "arrived": at_end,
            "seconds": s,
            "samples": samples.len(),
        }),
    ))
}

fn write_csv(p: &Path, axes: &[u8], samples: &[PathSample]) -> Result<()> {
    let mut text = String::from("t_s,span_s");
    for a in axes {
        text.push_str(&format!(",axis{a}"));
    }
    text.push('\n');
    for s in samples {
        text.push_str(&format!("{:.4},{:.4}", s.t_s, s.span_s));
        for v in &s.positions {
            text.push_str(&format!(",{v}"));
        }
        text.push('\n');
    }
    std::fs::write(p, text).map_err(|e| Error::Usage(format!("cannot write {}: {e}", p.display())))
}

/// `move 1=3000 2=-500`: the targets, as (axis, position).
pub fn parse_targets(args: &[String]) -> Result<Vec<(u8, i32)>> {
    args.iter()
        .map(|a| {
            let (axis, pos) = a.split_once('=').ok_or_else(|| {
                Error::Usage(format!("{a}: AXIS=POSITION expected (e.g. 1=3000)"))
            })?;
            let axis: u8 = axis
                .trim()
                .parse()
                .map_err(|e| Error::Usage(format!("{a}: an axis id: {e}")))?;
            let pos: i32 = pos
                .trim()
                .parse()
                .map_err(|e| Error::Usage(format!("{a}: a position in steps: {e}")))?;
            Ok((axis, pos))
        })
        .collect()
}

/// `move 1=… 2=…`: one coordinated move of several axes (a path of one row).
pub(super) fn group_move(
    ctx: &mut Ctx,
    targets: &[(u8, i32)],
    limits: PathLimits,
    timeout_s: f64,
    no_wait: bool,
) -> Result<Output> {
    let file = PathFile {
        axes: targets.iter().map(|t| t.0).collect(),
        rows: vec![targets.iter().map(|t| t.1).collect()],
    };
    let mut sorted = file.axes.clone();
    sorted.sort_unstable();
    sorted.dedup();
    if sorted.len() != file.axes.len() {
        return Err(Error::Usage("move: an axis named twice".into()));
    }
    if no_wait {
        let targets: Vec<i32> = targets.iter().map(|t| t.1).collect();
        start(ctx, &file.axes, &targets, limits)?;
        return Ok(Output::new(
            format!("axes {}: moving to {targets:?}", list(&file.axes)),
            json!({ "axes": file.axes, "targets": targets, "waited": false }),
        ));
    }
    run_path(ctx, &file, limits, timeout_s, None, None)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_file_names_its_axes_then_one_waypoint_per_row() {
        let f = parse_csv("# a square\n1,2\n0,0\n100,0\n\n100,-100\n").unwrap();
        assert_eq!(f.axes, [1, 2]);
        assert_eq!(f.rows, [vec![0, 0], vec![100, 0], vec![100, -100]]);
    }

    #[test]
    fn a_bad_path_file_says_which_line() {
        for (text, want) in [
            ("", "no header"),
            ("x,2\n1,1", "line 1"),
            ("1,1\n0,0", "named twice"),
            ("1,2\n0", "line 2: 1 values for 2 axes"),
            ("1,2\n0,zz", "line 2"),
            ("1,2\n", "no waypoint rows"),
            ("0,1\n1,1", "start at 1"),
        ] {
            let e = parse_csv(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }

    #[test]
    fn move_targets_are_axis_equals_position() {
        let t = parse_targets(&["1=3000".into(), "2=-500".into()]).unwrap();
        assert_eq!(t, [(1, 3000), (2, -500)]);
        assert!(parse_targets(&["1:3".into()]).is_err());
        assert!(parse_targets(&["a=3".into()]).is_err());
    }

    #[test]
    fn refusals_and_aborts_are_named() {
        assert!(refusal(5).contains("full"));
        assert!(refusal(0x0207).contains("chain axis 2"));
        assert_eq!(abort_reason(0xFF01), "the group's stop: stopped");
        assert_eq!(abort_reason(0x0103), "chain axis 1: overcurrent");
    }
}
