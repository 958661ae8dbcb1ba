//! The QEMU runner of `cargo qemu` and `cargo qemu-test` (cargo's `runner`
//! for the thumbv7em target when they run):
//!
//! ```text
//! cargo xtask qemu-run ELF          the firmware image: Modbus on TCP, log on stdout
//! cargo xtask qemu-run --test ELF   an on-target test (firmware/tests/): no Modbus,
//!                                   a fresh settings flash, QEMU's exit status
//! ```
//!
//! Boots ELF on QEMU's `netduinoplus2` (STM32F405) and prints its defmt log,
//! decoded by defmt-print, on stdout. Stop the image with Ctrl-C. QEMU 7.x
//! and defmt-print are found or set up first (`setup`).
//!
//! Modbus RTU (USART2) is QEMU's second `-serial`: by default a TCP server on
//! 127.0.0.1:5020 (one client at a time; RTU frames over the socket, no MBAP
//! header), with nodelay=on: QEMU's TCP chardev otherwise leaves Nagle on,
//! and every reply byte after the first waits for the client's delayed ACK
//! (~40 ms per request). `QEMU_MODBUS=<any QEMU chardev spec>` overrides it:
//! `pty` (a pseudo-terminal, named on stderr as "char device redirected to
//! /dev/pts/N (label serial1)") or e.g.
//! `tcp:127.0.0.1:15020,server=on,wait=off,nodelay=on`. The first `-serial`
//! (USART1) is the QEMU image's I/O-extension console (platform/qemu.rs):
//! lines "press N" / "release N" close / open input N of the simulated
//! 74HC165s; `QEMU_CONSOLE=<chardev spec>` connects it (default: null;
//! tests always get null).
//!
//! Settings flash: the image keeps the settings store's flash in a host
//! file (semihosting), `target/qemu-flash.bin` by default, so "write
//! settings" survives a restart. `QEMU_FLASH=<path>` uses another file;
//! `QEMU_FRESH=1` deletes it first (factory settings). Tests always get a
//! fresh file. `QEMU_RAW=1` skips defmt-print and writes the raw defmt
//! frames instead. `QEMU=<path>` runs another QEMU 7.x.
//!
//! Exit status: QEMU's (1 after a panic or HardFault in the image, which
//! ends QEMU through semihosting; 0 when a test binary passes), or
//! defmt-print's when QEMU's is 0.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use crate::setup;
use crate::util::{self, bail, say, Error, Result};

const P: &str = "qemu-run";
pub const DEFAULT_MODBUS: &str = "tcp:127.0.0.1:5020,server=on,wait=off,nodelay=on";

/// The `-semihosting-config` value: the image's command line names the
/// settings flash file. A comma inside a QEMU option value is written as two.
pub fn semihosting_config(flash: &str) -> String {
    format!(
        "enable=on,target=native,arg=stepbridge,arg=flash={}",
        flash.replace(',', ",,")
    )
}

/// The settings flash path the image can take: the semihosting command
/// line is split at spaces, and its buffer holds 255 bytes.
pub fn check_flash_path(flash: &str) -> Result {
    if flash.chars().any(char::is_whitespace) {
        bail!("the settings flash path must not contain spaces: '{flash}' (set QEMU_FLASH)");
    }
    if flash.len() > 255 {
        bail!("the settings flash path is longer than 255 bytes: '{flash}' (set QEMU_FLASH)");
    }
    Ok(())
}

/// QEMU's arguments for the image.
pub fn qemu_args(elf: &Path, flash: &str, console: &str, modbus: &str) -> Vec<String> {
    // -nographic without a monitor: the monitor's banner and prompt would
    // land in the defmt stream on stdout (and Ctrl-C stops QEMU directly).
    vec![
        "-machine".into(),
        "netduinoplus2".into(),
        "-nographic".into(),
        "-monitor".into(),
        "none".into(),
        "-semihosting-config".into(),
        semihosting_config(flash),
        "-serial".into(),
        console.into(),
        "-serial".into(),
        modbus.into(),
        "-kernel".into(),
        elf.display().to_string(),
    ]
}

/// A test binary's name from its file name ("usart-0123abcd" → "usart").
pub fn test_name(elf: &Path) -> String {
    let file = elf
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    match file.rsplit_once('-') {
        Some((name, _)) => name.to_owned(),
        None => file,
    }
}

/// A test's verdict from QEMU's and defmt-print's statuses and the log:
/// `Ok(message)` passed, `Err(message)` failed.
pub fn verdict(
    name: &str,
    qemu: i32,
    decoder: i32,
    log: &str,
) -> std::result::Result<String, String> {
    if name == "panic_path" {
        // This test passes by panicking: the panic handler's message, then
        // the HardFault handler's exit status 1.
        let said = log.matches("on purpose: the panic path under test").count();
        return if qemu == 1 && said > 0 {
            Ok(format!(
                "test {name}: passed (1 test: the panic ended QEMU with status 1 after its message)"
            ))
        } else {
            Err(format!(
                "test {name}: FAILED (QEMU status {qemu}; panic message {said} times)"
            ))
        };
    }
    if qemu == 0 && decoder == 0 && log.contains("all tests passed!") {
        Ok(format!(
            "test {name}: passed ({} tests)",
            log.lines().filter(|l| l.contains("running `")).count()
        ))
    } else {
        Err(format!("test {name}: FAILED (QEMU status {qemu})"))
    }
}

fn flag(name: &str) -> bool {
    std::env::var(name).is_ok_and(|v| v == "1")
}

fn env_or(name: &str, default: &str) -> String {
    std::env::var(name)
        .ok()
        .filter(|v| !v.is_empty())
        .unwrap_or_else(|| default.to_owned())
}

pub fn main(args: &[String]) -> Result {
    let (test, elf) = match args {
        [t, elf] if t == "--test" => (true, PathBuf::from(elf)),
        [elf] if elf != "--test" => (false, PathBuf::from(elf)),
        _ => {
            say(P, "usage: cargo xtask qemu-run [--test] ELF");
            return Err(Error::Exit(2));
        }
    };
    let qemu = setup::qemu()?;
    let decoder = if flag("QEMU_RAW") {
        None
    } else {
        Some(setup::defmt_print()?)
    };
    let root = util::root();

    // --- settings flash (host file) ---
    let test_dir = if test {
        Some(util::TempDir::new("stepbridge-test-flash")?)
    } else {
        None
    };
    let flash: PathBuf = match &test_dir {
        Some(d) => d.path().join("flash.bin"),
        None => user_flash()?,
    };
    let flash_s = flash.display().to_string();
    check_flash_path(&flash_s)?;

    // --- QEMU ---
    let (mut q, modbus) = qemu_command(&qemu, &elf, &flash_s, test);
    announce(test, &qemu, &elf, &flash, &root, &modbus);
    let Some(decoder) = decoder else {
        use std::os::unix::process::CommandExt;
        let e = q.exec();
        bail!("cannot run {}: {e}", qemu.bin.display());
    };

    let mut qemu_child = q
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot run {}: {e}", qemu.bin.display()))?;
    let qemu_out = qemu_child.stdout.take().ok_or("no QEMU stdout")?;
    let (mut dec_child, copier) = spawn_decoder(&decoder, &elf, test, &modbus, qemu_out)?;
    let log = tee_log(&mut dec_child);
    let qemu_status = util::code(
        qemu_child
            .wait()
            .map_err(|e| format!("waiting for QEMU: {e}"))?,
    );
    if let Some(c) = copier {
        let _ = c.join();
    }
    let dec_status = util::code(
        dec_child
            .wait()
            .map_err(|e| format!("waiting for defmt-print: {e}"))?,
    );
    let test_name = test.then(|| test_name(&elf));
    drop(test_dir);
    outcome(test_name.as_deref(), qemu_status, dec_status, &log)
}

/// A test's verdict (from its log), or QEMU's status; the decoder's only if
/// QEMU's is 0.
fn outcome(test: Option<&str>, qemu_status: i32, dec_status: i32, log: &str) -> Result {
    if let Some(name) = test {
        return match verdict(name, qemu_status, dec_status, log) {
            Ok(m) => {
                say(P, m);
                Ok(())
            }
            Err(m) => {
                say(P, m);
                Err(Error::Exit(1))
            }
        };
    }
    match (qemu_status, dec_status) {
        (0, 0) => Ok(()),
        (0, d) => Err(Error::Exit(d)),
        (q, _) => Err(Error::Exit(q)),
    }
}

/// The QEMU command line for `elf` and where its Modbus goes (a test:
/// nowhere, and no console).
fn qemu_command(qemu: &setup::Qemu, elf: &Path, flash: &str, test: bool) -> (Command, String) {
    let modbus = if test {
        env_or("QEMU_MODBUS", "null")
    } else {
        env_or("QEMU_MODBUS", DEFAULT_MODBUS)
    };
    let console = if test {
        "null".to_owned()
    } else {
        env_or("QEMU_CONSOLE", "null")
    };
    let mut q = Command::new(&qemu.bin);
    q.args(qemu_args(elf, flash, &console, &modbus));
    if let Some(d) = &qemu.data_dir {
        q.arg("-L").arg(d);
    }
    (q, modbus)
}

/// The image's settings flash file: `QEMU_FLASH` (relative to the current
/// directory) or target/qemu-flash.bin, its directory made, deleted first
/// with `QEMU_FRESH=1`.
fn user_flash() -> Result<PathBuf> {
    let f = std::env::var_os("QEMU_FLASH")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .unwrap_or_else(|| util::target_dir().join("qemu-flash.bin"));
    let f = if f.is_absolute() {
        f
    } else {
        std::env::current_dir()
            .map_err(|e| format!("no current directory: {e}"))?
            .join(f)
    };
    if let Some(d) = f.parent() {
        std::fs::create_dir_all(d).map_err(|e| format!("cannot create {}: {e}", d.display()))?;
    }
    if flag("QEMU_FRESH") {
        let _ = std::fs::remove_file(&f);
    }
    Ok(f)
}

/// What runs, on stderr: the test's name, or where Modbus and the flash are.
fn announce(test: bool, qemu: &setup::Qemu, elf: &Path, flash: &Path, root: &Path, modbus: &str) {
    let flash_s = flash.display().to_string();
    if test {
        say(
            P,
            format!(
                "QEMU {}, test {}",
                qemu.version,
                elf.file_name().unwrap_or_default().to_string_lossy()
            ),
        );
    } else {
        let shown = flash
            .strip_prefix(root)
            .map(|p| p.display().to_string())
            .unwrap_or_else(|_| flash_s.clone());
        say(
            P,
            format!(
                "QEMU {}, Modbus on {modbus}, settings flash {shown} (QEMU_FRESH=1: factory-fresh)",
                qemu.version
            ),
        );
    }
}

/// defmt-print on QEMU's stdout (through a thread that first passes QEMU's
/// pty line to stderr when Modbus is a pty); the child and that thread.
fn spawn_decoder(
    decoder: &Path,
    elf: &Path,
    test: bool,
    modbus: &str,
    qemu_out: std::process::ChildStdout,
) -> Result<(std::process::Child, Option<std::thread::JoinHandle<()>>)> {
    let pty = modbus.starts_with("pty");
    let mut d = Command::new(decoder);
    d.arg("-e").arg(elf);
    d.stdout(if test {
        Stdio::piped()
    } else {
        Stdio::inherit()
    });
    let spawned = if pty {
        // QEMU 7.2 prints "char device redirected to /dev/pts/N (label
        // serial1)" on stdout, ahead of the defmt stream: that line goes to
        // stderr, the rest to defmt-print.
        let mut child = d
            .stdin(Stdio::piped())
            .spawn()
            .map_err(|e| format!("cannot run {}: {e}", decoder.display()))?;
        let mut dec_in = child.stdin.take().ok_or("no defmt-print stdin")?;
        let copier = std::thread::spawn(move || {
            let mut r = BufReader::new(qemu_out);
            let mut line = Vec::new();
            if r.read_until(b'\n', &mut line).is_ok() {
                let _ = std::io::stderr().write_all(&line);
            }
            let _ = std::io::copy(&mut r, &mut dec_in);
        });
        (child, Some(copier))
    } else {
        let child = d
            .stdin(Stdio::from(qemu_out))
            .spawn()
            .map_err(|e| format!("cannot run {}: {e}", decoder.display()))?;
        (child, None)
    };
    Ok(spawned)
}

/// The decoded log to stdout as it comes and, for a test's verdict, into
/// memory.
fn tee_log(dec_child: &mut std::process::Child) -> String {
    let mut log = String::new();
    if let Some(out) = dec_child.stdout.take() {
        let mut r = BufReader::new(out);
        let mut line = Vec::new();
        let stdout = std::io::stdout();
        loop {
            line.clear();
            match r.read_until(b'\n', &mut line) {
                Ok(0) | Err(_) => break,
                Ok(_) => {
                    let mut o = stdout.lock();
                    let _ = o.write_all(&line);
                    let _ = o.flush();
                    log.push_str(&String::from_utf8_lossy(&line));
                }
            }
        }
    }
    log
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arguments_as_the_runner_always_gave_them() {
        let a = qemu_args(
            Path::new("/w/target/stepbridge"),
            "/w/target/qemu-flash.bin",
            "null",
            DEFAULT_MODBUS,
        );
        assert_eq!(
            a.join(" "),
            "-machine netduinoplus2 -nographic -monitor none -semihosting-config enable=on,target=native,arg=stepbridge,arg=flash=/w/target/qemu-flash.bin -serial null -serial tcp:127.0.0.1:5020,server=on,wait=off,nodelay=on -kernel /w/target/stepbridge"
        );
        assert_eq!(
            semihosting_config("/a,b/f"),
            "enable=on,target=native,arg=stepbridge,arg=flash=/a,,b/f"
        );
    }

    #[test]
    fn flash_paths() {
        assert!(check_flash_path("/tmp/x/flash.bin").is_ok());
        assert!(check_flash_path("/tmp/my dir/flash.bin").is_err());
        assert!(check_flash_path(&format!("/{}", "a".repeat(255))).is_err());
    }

    #[test]
    fn test_verdicts() {
        assert_eq!(
            test_name(Path::new("/t/deps/settings_flash-0a1b2c3d")),
            "settings_flash"
        );
        let log = "(1/2) running `a`...\n(2/2) running `b`...\nall tests passed!\n";
        assert_eq!(
            verdict("usart", 0, 0, log),
            Ok("test usart: passed (2 tests)".into())
        );
        assert!(verdict("usart", 1, 0, log).is_err());
        assert!(verdict("usart", 0, 0, "(1/2) running `a`...\n").is_err());
        let panic = "ERROR panicked: on purpose: the panic path under test\n";
        assert!(verdict("panic_path", 1, 0, panic).is_ok());
        assert!(verdict("panic_path", 0, 0, panic).is_err());
        assert!(verdict("panic_path", 1, 0, "").is_err());
    }
}
