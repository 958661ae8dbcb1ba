//! `usbip-kernel-check --box PATH --stepctl PATH [--work DIR]`: the bridge's
//! USB device through a real Linux kernel. Run as root on a Linux with the
//! modules usbip-core, vhci-hcd, usbhid and hid-generic loaded and hidraw
//! built in (`scripts/usbip-kernel` boots Debian's kernel so, under QEMU).
//!
//! It starts the box (`usbip-box`, 4 axes, 127.0.0.1:3240), lists and
//! imports it over USB/IP, attaches the connection to vhci-hcd, and checks
//! what the kernel made of it and what the box answers through hidraw:
//!
//! 1. **Kernel**: the modules are there; the device enumerates at full
//!    speed; usbhid binds its interface and hid-generic its HID device; a
//!    hidraw node appears.
//! 2. **Descriptors** as the kernel read them (sysfs `descriptors`, the
//!    string attributes, the HID `report_descriptor`): the manual's device
//!    descriptor and 41-byte configuration byte for byte.
//! 3. **Every USB command of manual §10** (and the extensions 0xA2, 0xE0)
//!    through hidapi on `/dev/hidraw*`: OUT reports written byte by byte from
//!    the manual's tables, IN reports checked at the tables' offsets (the
//!    expectations of `host-tests/tests/usb_commands.rs`); a 0xB1 move
//!    checked on the simulated chip's ABS_POS; the 0xA0 stream's cadence and
//!    what hidraw queues for a reader that stops reading; 0x02 twice (the
//!    device restarts into boot mode and back, re-attached each time).
//! 4. **stepctl `--usb`** end to end: scan, status, move, settings export →
//!    import → read back.
//!
//! Prints one `ok:` / `FAIL:` / `xfail:` line per check and a `SUMMARY:`
//! line; exits 0 when no check failed.

// This program is a test (CI runs it in a guest against the box): like the
// crate's tests it indexes the reports it checks and counts freely, and a
// panic fails the run. The box it checks (the library) keeps the strict set.
#![allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used
)]
#![allow(clippy::expect_used, clippy::panic)]

#[cfg(target_os = "linux")]
mod commands;
#[cfg(target_os = "linux")]
mod device;
#[cfg(target_os = "linux")]
mod hid;
#[cfg(target_os = "linux")]
mod stepctl;

use std::fmt::{Debug, Display};
use std::time::Instant;

/// The record of every check.
#[derive(Debug)]
pub struct Checks {
    pub ok: u32,
    pub failed: Vec<String>,
    pub xfailed: Vec<String>,
    start: Instant,
}

impl Checks {
    fn new() -> Checks {
        Checks {
            ok: 0,
            failed: Vec::new(),
            xfailed: Vec::new(),
            start: Instant::now(),
        }
    }

    fn stamp(&self) -> String {
        format!("{:6.2}s", self.start.elapsed().as_secs_f64())
    }

    /// One check: `pass` with `detail` for the log.
    pub fn check(&mut self, name: &str, pass: bool, detail: impl Display) -> bool {
        if pass {
            self.ok += 1;
            println!("ok: [{}] {name}: {detail}", self.stamp());
        } else {
            println!("FAIL: [{}] {name}: {detail}", self.stamp());
            self.failed.push(name.to_string());
        }
        pass
    }

    /// `got == want`.
    pub fn eq<T: PartialEq + Debug>(&mut self, name: &str, got: T, want: T) -> bool {
        let pass = got == want;
        let detail = if pass {
            format!("{got:?}")
        } else {
            format!("got {got:?}, want {want:?}")
        };
        self.check(name, pass, detail)
    }

    /// A check known to fail until a change lands elsewhere (`why`): a
    /// failure is recorded as expected; a pass is a failure too ("strict"),
    /// so the marker is removed when the change lands.
    pub fn xfail(&mut self, name: &str, pass: bool, detail: impl Display, why: &str) {
        if pass {
            println!(
                "FAIL: [{}] {name}: passes now ({detail}): make it a plain check (it was marked: {why})",
                self.stamp()
            );
            self.failed.push(name.to_string());
        } else {
            println!(
                "xfail: [{}] {name}: {detail} (expected until: {why})",
                self.stamp()
            );
            self.xfailed.push(name.to_string());
        }
    }
}

#[cfg(target_os = "linux")]
fn main() {
    let args = match Args::parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("usbip-kernel-check: {e}");
            std::process::exit(1);
        }
    };
    let mut c = Checks::new();
    let result = run(&args, &mut c);
    if let Err(e) = &result {
        println!("FAIL: [{}] fatal: {e}", c.stamp());
        c.failed.push("fatal".into());
    }
    println!(
        "SUMMARY: {} checks, {} passed, {} failed, {} expected failures, {:.1} s{}",
        c.ok as usize + c.failed.len() + c.xfailed.len(),
        c.ok,
        c.failed.len(),
        c.xfailed.len(),
        c.start.elapsed().as_secs_f64(),
        if c.failed.is_empty() {
            String::new()
        } else {
            format!(" (failed: {})", c.failed.join(", "))
        }
    );
    std::process::exit(i32::from(!c.failed.is_empty()));
}

#[cfg(not(target_os = "linux"))]
fn main() {
    eprintln!("usbip-kernel-check needs Linux (vhci-hcd, hidraw)");
    std::process::exit(1);
}

/// Command line.
#[derive(Debug)]
pub struct Args {
    pub box_bin: String,
    pub stepctl: String,
    pub work: String,
    pub listen: String,
}

impl Args {
    fn parse() -> Result<Args, String> {
        let mut a = Args {
            box_bin: String::new(),
            stepctl: String::new(),
            work: "/tmp".into(),
            listen: "127.0.0.1:3240".into(),
        };
        let mut it = std::env::args().skip(1);
        while let Some(arg) = it.next() {
            let mut val = || it.next().ok_or(format!("{arg} needs a value"));
            match arg.as_str() {
                "--box" => a.box_bin = val()?,
                "--stepctl" => a.stepctl = val()?,
                "--work" => a.work = val()?,
                "--listen" => a.listen = val()?,
                other => return Err(format!("unknown argument {other}")),
            }
        }
        if a.box_bin.is_empty() || a.stepctl.is_empty() {
            return Err("usage: usbip-kernel-check --box PATH --stepctl PATH [--work DIR]".into());
        }
        Ok(a)
    }
}

#[cfg(target_os = "linux")]
fn run(args: &Args, c: &mut Checks) -> Result<(), String> {
    device::modules(c);
    let mut boxed = device::BoxProcess::start(args)?;
    device::devlist(c, &args.listen)?;
    let mut att = device::Attached::attach(&args.listen)?;
    c.check(
        "attach: the kernel enumerated the device",
        true,
        format!("{} on vhci port {}", att.usb.display(), att.port),
    );
    device::kernel_view(c, &att)?;
    let mut hid = hid::Hid::open(c, &att)?;
    commands::run(c, &mut hid)?;
    // 0x02 twice: the device restarts into boot mode and back.
    let (next_att, next_hid) = commands::system_reset(c, att, hid, &args.listen)?;
    att = next_att;
    hid = next_hid;
    commands::erase(c, &mut hid)?;
    drop(hid);
    stepctl::run(c, args)?;
    att.detach_check(c);
    boxed.stop();
    Ok(())
}
