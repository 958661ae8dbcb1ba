//! The firmware's cargo commands (`cargo fw`, `cargo qemu`, ... in
//! .cargo/config.toml), each after the set-up it needs. Arguments after
//! the command go to cargo (`cargo fw --features x`).

use std::path::PathBuf;
use std::process::Command;

use crate::setup::{self, TARGET};
use crate::util::{self, bail, Result};

/// The on-target tests QEMU models (firmware/tests/; `cargo qemu-test`).
pub const QEMU_TESTS: [&str; 7] = [
    "systick",
    "usart",
    "settings_flash",
    "handoff",
    "panic_path",
    "ioext_abort",
    "chain_abort",
];

/// cargo's runner for the thumbv7em target, for one command: this
/// program's `qemu-run` (an environment variable, so it needs no TOML
/// quoting; cargo splits it at spaces).
fn runner(c: &mut Command, test: bool) -> Result {
    let exe = std::env::current_exe().map_err(|e| format!("where is xtask? {e}"))?;
    let exe = exe.display().to_string();
    if exe.chars().any(char::is_whitespace) {
        bail!("the workspace path has a space ({exe}): cargo cannot run a runner there");
    }
    let r = if test {
        format!("{exe} qemu-run --test")
    } else {
        format!("{exe} qemu-run")
    };
    c.env("CARGO_TARGET_THUMBV7EM_NONE_EABIHF_RUNNER", r);
    Ok(())
}

fn firmware(verb: &str, extra: &[String]) -> Command {
    let mut c = util::cargo();
    c.args([verb, "-p", "firmware", "--target", TARGET]);
    if verb != "test" {
        c.arg("--release");
    }
    c.args(extra);
    c
}

/// `cargo fw`: the board image, `target/thumbv7em-none-eabihf/release/stepbridge`.
pub fn fw(extra: &[String]) -> Result {
    setup::ensure_target()?;
    util::run(&mut firmware("build", extra))
}

/// `cargo fw-run`: build, flash and run on a probe-attached board (the
/// probe-rs runner of .cargo/config.toml).
pub fn fw_run(extra: &[String]) -> Result {
    setup::ensure_target()?;
    util::run(&mut firmware("run", extra))
}

/// `cargo fw-test`: the on-target tests on a board (profile fw-test: the
/// release build's optimisation with overflow checks on).
pub fn fw_test(extra: &[String]) -> Result {
    setup::ensure_target()?;
    let mut c = firmware("test", &[]);
    c.args(["--profile", "fw-test"]).args(extra);
    util::run(&mut c)
}

/// `cargo qemu-build`: the QEMU image (feature `qemu`), on the board
/// image's path.
pub fn qemu_build(extra: &[String]) -> Result {
    setup::ensure_target()?;
    let mut c = firmware("build", &[]);
    c.args(["--features", "qemu"]).args(extra);
    util::run(&mut c)
}

/// The QEMU image's path after `qemu_build`.
pub fn image() -> PathBuf {
    util::target_dir().join(TARGET).join("release/stepbridge")
}

/// `cargo qemu`: set up (target, QEMU 7.x, defmt-print), build the QEMU
/// image and boot it (`qemu-run`). A defmt-print that must be installed
/// first builds while the firmware does.
pub fn qemu(extra: &[String]) -> Result {
    setup::ensure_target()?;
    setup::qemu()?;
    let decoder = if std::env::var("QEMU_RAW").map_or(true, |v| v != "1") {
        Some(setup::defmt_print_begin()?)
    } else {
        None
    };
    if let Some(d @ setup::DefmtPrint::Installing { .. }) = decoder {
        let mut b = firmware("build", &[]);
        b.args(["--features", "qemu"]).args(extra);
        let built = util::run(&mut b);
        let installed = d.wait();
        built?;
        installed?;
    }
    let mut c = firmware("run", &[]);
    c.args(["--features", "qemu"]).args(extra);
    runner(&mut c, false)?;
    util::run(&mut c)
}

/// `cargo qemu-test`: the on-target tests QEMU models, each booted by
/// `qemu-run --test` on a fresh settings flash.
pub fn qemu_test(extra: &[String]) -> Result {
    setup::ensure_target()?;
    setup::qemu()?;
    setup::defmt_print()?;
    let mut c = firmware("test", &[]);
    c.args(["--profile", "fw-test", "--features", "qemu"]);
    for t in QEMU_TESTS {
        c.args(["--test", t]);
    }
    c.args(extra);
    runner(&mut c, true)?;
    util::run(&mut c)
}
