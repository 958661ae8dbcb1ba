//! `usbip-box [--listen ADDR] [--axes N] [--trace] [--quiet]`: the bridge's USB
//! device (PoStep60 HID class, bridge, simulated chips) exported over
//! USB/IP, bus id "1-1", on ADDR (127.0.0.1:3240, the usbip port), its
//! virtual clock following real time. `--trace` logs every control
//! transfer (SETUP, status, length) and unlink. Import it with vhci-hcd (the
//! `usbip-kernel-check` binary, or `usbip attach -r 127.0.0.1 -b 1-1`).

use std::time::{Duration, Instant};

use usbip_box::postep_box::{PoStepBox, Restart};
use usbip_box::server::{Event, Server};

/// Ticks one loop turn may run before the network gets its turn again.
const MAX_TICKS_PER_TURN: u32 = 20;
/// How far behind real time the virtual clock may fall before the box
/// says so (a slow host, e.g. a guest under TCG).
const LAG_WARN_MS: u64 = 100;

struct Args {
    listen: String,
    axes: usize,
    trace: bool,
    quiet: bool,
}

fn args() -> Result<Args, String> {
    let mut a = Args {
        listen: "127.0.0.1:3240".into(),
        axes: 4,
        trace: false,
        quiet: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--listen" => a.listen = it.next().ok_or("--listen needs ADDR")?,
            "--axes" => {
                a.axes = it
                    .next()
                    .and_then(|s| s.parse().ok())
                    .filter(|n| (1..=8).contains(n))
                    .ok_or("--axes needs 1..=8")?
            }
            "--trace" => a.trace = true,
            "--quiet" => a.quiet = true,
            "-h" | "--help" => {
                println!("usbip-box [--listen 127.0.0.1:3240] [--axes 4] [--trace] [--quiet]");
                std::process::exit(0);
            }
            other => return Err(format!("unknown argument {other}")),
        }
    }
    Ok(a)
}

fn main() {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("usbip-box: {e}");
            std::process::exit(1);
        }
    };
    let mut server = match Server::bind(&a.listen, PoStepBox::device_info()) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("usbip-box: cannot listen on {}: {e}", a.listen);
            std::process::exit(2);
        }
    };
    let log = |s: String| {
        if !a.quiet {
            eprintln!("usbip-box: {s}");
        }
    };
    let mut pbox = PoStepBox::power_up(a.axes);
    log(format!(
        "{} axes, bus id 1-1, listening on {}",
        pbox.bridge.axes(),
        server
            .local_addr()
            .map_or(a.listen.clone(), |s| s.to_string())
    ));
    // Real time at the current run's virtual time 0.
    let mut epoch = Instant::now();
    let mut warned_at = 0u64;
    loop {
        let port = pbox.port().clone();
        port.set_tracing(a.trace);
        for e in server.poll(&port) {
            match e {
                Event::Listed => log("device list sent".into()),
                Event::Imported(peer) => log(format!("imported by {peer}")),
                Event::Refused(id) => log(format!("import of bus id {id:?} refused")),
                Event::Detached(why) => log(format!("detached: {why}")),
            }
        }
        // Host traffic first, then the control ticks that are due.
        pbox.usb_task();
        let now_us = u64::try_from(epoch.elapsed().as_micros()).unwrap_or(u64::MAX);
        let (ticks, restart) = pbox.run_until(now_us, MAX_TICKS_PER_TURN);
        if let Some(Restart::Into(mode)) = restart {
            server.unplug(&port);
            epoch = Instant::now();
            log(format!(
                "restarted (run {}) into {mode:?}: unplugged, waiting for an import",
                pbox.runs
            ));
            continue;
        }
        for t in port.take_trace() {
            log(format!("{t}"));
        }
        if let Some(Event::Detached(why)) = server.flush(pbox.port()) {
            log(format!("detached: {why}"));
        }
        server.info_mut().configuration_value = u8::from(pbox.configured());
        let now_ms = now_us / 1000;
        let lag_ms = now_ms.saturating_sub(pbox.clock.now_ms());
        if lag_ms > LAG_WARN_MS && now_ms >= warned_at.saturating_add(1000) {
            warned_at = now_ms;
            log(format!("the control loop is {lag_ms} ms behind real time"));
        }
        if ticks < MAX_TICKS_PER_TURN {
            std::thread::sleep(Duration::from_micros(250));
        }
    }
}
