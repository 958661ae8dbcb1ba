//! `cargo xtask bench`: instruction counts of the control tick under
//! callgrind (deterministic; not a timed test): per tick for the profile
//! generator of one axis and for the bridge's whole tick of 8 axes (plan +
//! schedule + decode + absorb; the simulated SPI transfer and chip physics
//! excluded), plus the CS windows and bytes per tick
//! (host-tests/src/bin/bench-tick.rs).

use std::path::Path;

use crate::util::{self, bail, cmd, Result};

const N: u64 = 20_000;

/// The total of a callgrind output file (`summary:` or `totals:` line).
pub fn parse_total(callgrind_out: &str) -> Option<u64> {
    callgrind_out.lines().find_map(|l| {
        l.strip_prefix("summary:")
            .or_else(|| l.strip_prefix("totals:"))
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse().ok())
    })
}

fn valgrind() -> Result {
    if util::which("valgrind").is_some() {
        return Ok(());
    }
    crate::apt::install("bench", &["valgrind"])
}

fn count(bin: &Path, dir: &Path, mode: &str, toggles: &[&str]) -> Result<(u64, String)> {
    let out = dir.join(format!("cg.{mode}"));
    let mut c = cmd("valgrind", ["--tool=callgrind"]);
    c.arg(format!("--callgrind-out-file={}", out.display()));
    for t in toggles {
        c.arg(format!("--toggle-collect={t}"));
    }
    c.arg(bin).args([mode, &N.to_string()]);
    let o = util::capture(&mut c)?;
    if !o.status.success() {
        bail!(
            "{} failed:\n{}",
            util::show(&c),
            String::from_utf8_lossy(&o.stderr)
        );
    }
    let text = std::fs::read_to_string(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    let total = parse_total(&text).ok_or_else(|| format!("no total in {}", out.display()))?;
    Ok((total, String::from_utf8_lossy(&o.stdout).into_owned()))
}

pub fn main(_args: &[String]) -> Result {
    valgrind()?;
    util::run(util::cargo().args([
        "build",
        "-q",
        "--release",
        "-p",
        "host-tests",
        "--bin",
        "bench-tick",
    ]))?;
    let bin = util::target_dir().join("release/bench-tick");
    let tmp = util::TempDir::new("stepbridge-bench")?;
    let (p, _) = count(&bin, tmp.path(), "profile", &["*bench_profile_tick*"])?;
    let (g, out) = count(
        &bin,
        tmp.path(),
        "group",
        &["*bench_prepare*", "*bench_finish*"],
    )?;
    print!("{out}");
    println!(
        "profile generator: {} instructions per axis-tick ({p} over {N} ticks)",
        p / N
    );
    println!(
        "whole tick, 8 axes: {} instructions per tick, {} per axis-tick ({g} over {N} ticks)",
        g / N,
        g / N / 8
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn callgrind_totals() {
        let out = "version: 1\ncmd: x\nevents: Ir\nfn=(1) a\n3 5\nsummary: 123456\ntotals: 99\n";
        assert_eq!(super::parse_total(out), Some(123456));
        assert_eq!(super::parse_total("totals: 42\n"), Some(42));
        assert_eq!(super::parse_total("events: Ir\n"), None);
    }
}
