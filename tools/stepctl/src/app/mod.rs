//! Every command: requests through a [`Bus`], a result as text and as JSON.
//!
//! This file holds the command's context ([`Ctx`]), its result ([`Output`]) and
//! the dispatch ([`run`]); the commands live by role in the submodules.

mod live;
mod motion;
pub mod path;
mod report;
mod settings_cmd;

pub use report::scan_usb;

use std::io::IsTerminal;
use std::time::Duration;

use comfy_table::{presets, Table};
use serde_json::{json, Value};

use crate::bus::Bus;
use crate::cli::Command;
use crate::error::{Error, Result};
use crate::ops::{self, reg};

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

impl std::fmt::Debug for Ctx<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ctx")
            .field("bus", &self.bus.name())
            .field("first_id", &self.first_id)
            .field("json", &self.json)
            .field("interactive", &self.interactive)
            .field("poll", &self.poll)
            .finish()
    }
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
        Ok((first..first.saturating_add(n))
            .filter_map(|u| u8::try_from(u).ok())
            .collect())
    }

    fn sleep(&self) {
        std::thread::sleep(self.poll);
    }
}

pub fn run(ctx: &mut Ctx, cmd: &Command) -> Result<Output> {
    match cmd {
        Command::Scan { ids, probe_ms } => report::scan(ctx, *ids, *probe_ms),
        Command::Info => report::info(ctx),
        Command::Status { axes } => report::status(ctx, axes),
        Command::Move {
            axis,
            position,
            limits,
            wait,
        } => motion::move_to(ctx, *axis, *position, limits, wait),
        Command::Jog {
            axis,
            steps,
            limits,
            wait,
        } => motion::jog(ctx, *axis, *steps, limits, wait),
        Command::GroupMove {
            targets,
            limits,
            timeout,
            no_wait,
        } => path::group_move(
            ctx,
            &path::parse_targets(targets)?,
            path_limits(limits),
            *timeout,
            *no_wait,
        ),
        Command::Path {
            file,
            limits,
            timeout,
            record,
            plot,
        } => {
            let text = std::fs::read_to_string(file)
                .map_err(|e| Error::Usage(format!("cannot read {}: {e}", file.display())))?;
            let f = path::parse_csv(&text)?;
            path::run_path(
                ctx,
                &f,
                path_limits(limits),
                *timeout,
                record.as_deref(),
                plot.as_deref(),
            )
        }
        Command::Run { axis, speed } => motion::run_at(ctx, *axis, *speed),
        Command::Stop { axes } => motion::stop(ctx, axes),
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
        Command::Home { axis, wait } => motion::home(ctx, *axis, wait),
        Command::Settings(s) => settings_cmd::settings_cmd(ctx, s),
        Command::Watch {
            axes,
            interval_ms,
            count,
        } => live::watch(ctx, axes, *interval_ms, *count),
        Command::Record {
            axis,
            seconds,
            plot,
            csv,
            move_to,
            xy,
        } => live::record(
            ctx,
            *axis,
            *seconds,
            plot.as_deref(),
            csv.as_deref(),
            *move_to,
            *xy,
        ),
        Command::Raw {
            axis,
            command,
            values,
            count,
        } => report::raw(ctx, *axis, *command, values, *count),
        Command::Doctor {
            expect_axes,
            supply,
            loopback,
            seconds,
            tick_tolerance,
        } => report::doctor(
            ctx,
            *expect_axes,
            *supply,
            *loopback,
            *seconds,
            *tick_tolerance,
        ),
    }
}

fn path_limits(l: &crate::cli::PathLimits) -> path::PathLimits {
    path::PathLimits {
        speed: l.speed.unwrap_or(0),
        acc: l.acc.unwrap_or(0),
        dec: l.dec.unwrap_or(0),
    }
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

fn table(header: &[&str]) -> Table {
    let mut t = Table::new();
    t.load_preset(presets::ASCII_BORDERS_ONLY_CONDENSED);
    t.set_header(header.to_vec());
    t
}

pub fn is_terminal() -> bool {
    std::io::stderr().is_terminal()
}

/// What the commands' tests share: a parsed command line run against a
/// scripted Modbus link, and the motion block's reply.
#[cfg(test)]
mod test_util {
    use super::*;
    use crate::cli::Cli;
    pub(crate) use crate::modbus::fake::{fixed, framed, rtu};
    use clap::Parser;

    pub(crate) fn command(args: &[&str]) -> Command {
        Cli::try_parse_from(std::iter::once("stepctl").chain(args.iter().copied()))
            .unwrap()
            .command
    }

    pub(crate) fn run_on(
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
    pub(crate) fn motion(
        id: u8,
        speed: i32,
        pos: i32,
        target: i32,
        state: u16,
        faults: u16,
    ) -> String {
        let mut b = vec![id, 0x03, 20];
        for v in [speed as u32, pos as u32, target as u32] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        for v in [state, 0, faults, 0] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        framed(&b)
    }

    pub(crate) const MOTION_1: &str = "01 03 06 00 00 0A C5 45";
}
