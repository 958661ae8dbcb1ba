//! Installing a Debian package a task needs (valgrind, mbpoll), only as
//! root, and only when apt-get would remove nothing for it; otherwise the
//! one command to run.

use crate::setup::parse_removals;
use crate::util::{self, bail, say, Result};

pub fn install(who: &str, packages: &[&str]) -> Result {
    let list = packages.join(" ");
    if util::which("apt-get").is_none() {
        bail!("{list} is missing: install it with your package manager");
    }
    if !util::is_root() {
        bail!("{list} is missing; install it, then run this again:\n    sudo apt-get install --no-install-recommends {list}");
    }
    let mut sim = util::cmd("apt-get", ["install", "-s", "--no-install-recommends"]);
    sim.args(packages);
    let mut plan = util::capture(&mut sim)?;
    if !plan.status.success() {
        util::run_or_say(
            util::cmd("apt-get", ["update", "-q"]).env("DEBIAN_FRONTEND", "noninteractive"),
        )?;
        plan = util::capture(&mut sim)?;
    }
    let removals = parse_removals(&String::from_utf8_lossy(&plan.stdout));
    if !removals.is_empty() {
        bail!(
            "installing {list} would remove {}: not done; install {list} yourself",
            removals.join(", ")
        );
    }
    say(
        who,
        format!("first use: apt-get install --no-install-recommends {list} (removes nothing)"),
    );
    util::run_or_say(
        util::cmd(
            "apt-get",
            ["install", "-y", "-q", "--no-install-recommends"],
        )
        .args(packages)
        .env("DEBIAN_FRONTEND", "noninteractive"),
    )
}
