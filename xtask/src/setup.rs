//! What the firmware's builds and the QEMU image need besides Rust itself,
//! checked on every use and installed on the first: the Cortex-M target of
//! the toolchain, llvm-tools (sizes, benchmarks), QEMU 7.x and defmt-print.
//! Nothing here removes or replaces a package the machine already has.
//!
//! The decisions are pure functions of what was found (`target_step`,
//! `qemu_plan`, `library_step`, and the parsers they take their facts
//! from), tested below; the rest runs the programs that find and install.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::util::{self, bail, cmd, say, Result};

/// The firmware's target (STM32F405: Cortex-M4F).
pub const TARGET: &str = "thumbv7em-none-eabihf";
/// The defmt-print the image's log is decoded with.
pub const DEFMT_PRINT_VERSION: &str = "1.2.0";
/// Debian bookworm's QEMU: what `cargo qemu` runs (QEMU 10.0.2 from
/// bookworm-backports segfaults when the HAL resets an APB2 peripheral).
pub const QEMU_PACKAGES: [&str; 3] = ["qemu-system-arm", "qemu-system-common", "qemu-system-data"];

const P: &str = "setup";

// --- the Rust target -------------------------------------------------------

/// What to do about the firmware's target.
#[derive(Debug, PartialEq, Eq)]
pub enum TargetStep {
    Ready,
    /// `rustup target add` it.
    Add,
    /// No rustup, and the toolchain lacks it.
    Refuse,
}

/// `rustup_list`: the output of `rustup target list --installed` (None
/// without rustup); `in_sysroot`: the toolchain's sysroot has the target's
/// library directory.
pub fn target_step(rustup_list: Option<&str>, in_sysroot: bool) -> TargetStep {
    match rustup_list {
        Some(list) if list.lines().any(|l| l.trim() == TARGET) => TargetStep::Ready,
        Some(_) => TargetStep::Add,
        None if in_sysroot => TargetStep::Ready,
        None => TargetStep::Refuse,
    }
}

fn sysroot() -> Option<PathBuf> {
    util::stdout_of(cmd("rustc", ["--print", "sysroot"]).current_dir(util::root()))
        .map(|s| PathBuf::from(s.trim()))
}

/// Make sure the toolchain `rust-toolchain.toml` selects has the firmware's
/// target. rustup installs a toolchain file's `targets` only when it
/// installs the toolchain itself, so an already installed stable lacks it.
pub fn ensure_target() -> Result {
    let root = util::root();
    let list = util::stdout_of(cmd("rustup", ["target", "list", "--installed"]).current_dir(&root));
    let in_sysroot = sysroot().is_some_and(|s| s.join("lib/rustlib").join(TARGET).is_dir());
    match target_step(list.as_deref(), in_sysroot) {
        TargetStep::Ready => Ok(()),
        TargetStep::Add => {
            say(
                P,
                format!("first use: the toolchain has no {TARGET} target (the firmware's); running rustup target add {TARGET}"),
            );
            util::run_or_say(cmd("rustup", ["target", "add", TARGET]).current_dir(&root))
        }
        TargetStep::Refuse => bail!(
            "the Rust toolchain has no {TARGET} target and there is no rustup to add it: install Rust with rustup (https://rustup.rs), or add the target to this toolchain"
        ),
    }
}

/// An llvm-tools binary (`llvm-size`, `llvm-objdump`, ...) of the active
/// toolchain, installing the component if it is missing.
pub fn llvm_tool(name: &str) -> Result<PathBuf> {
    let find = || -> Option<PathBuf> {
        let rustlib = sysroot()?.join("lib/rustlib");
        std::fs::read_dir(rustlib)
            .ok()?
            .filter_map(|e| e.ok())
            .map(|e| e.path().join("bin").join(name))
            .find(|p| util::is_executable(p))
    };
    if let Some(p) = find() {
        return Ok(p);
    }
    say(
        P,
        format!("first use: {name} is missing; running rustup component add llvm-tools"),
    );
    util::run_or_say(cmd("rustup", ["component", "add", "llvm-tools"]).current_dir(util::root()))?;
    find().ok_or_else(|| format!("{name} not found after rustup component add llvm-tools").into())
}

// --- QEMU 7.x --------------------------------------------------------------

/// The QEMU to run.
#[derive(Debug, Clone)]
pub struct Qemu {
    pub bin: PathBuf,
    pub version: String,
    /// `-L` for a QEMU unpacked into our cache (its firmware and data files).
    pub data_dir: Option<PathBuf>,
}

/// "QEMU emulator version 7.2.22 (Debian 1:7.2+dfsg-7+deb12u18+b3)" → "7.2.22".
pub fn parse_qemu_version(text: &str) -> Option<String> {
    let rest = text
        .lines()
        .next()?
        .strip_prefix("QEMU emulator version ")?;
    let v: String = rest
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.')
        .collect();
    (!v.is_empty()).then_some(v)
}

pub fn is_7x(version: &str) -> bool {
    version.starts_with("7.")
}

fn qemu_version(bin: &Path) -> Option<String> {
    util::stdout_of(&mut cmd(bin, ["--version"])).and_then(|t| parse_qemu_version(&t))
}

/// `/etc/os-release` says Debian bookworm.
pub fn is_bookworm(os_release: &str) -> bool {
    os_release
        .lines()
        .any(|l| l.trim() == "VERSION_CODENAME=bookworm")
}

/// What was found about QEMU and the machine.
#[derive(Debug, Default, Clone)]
pub struct QemuFacts {
    /// `QEMU=PATH` was set: PATH and its version (None: it does not run).
    pub env: Option<(String, Option<String>)>,
    /// Version of `qemu-system-arm` on PATH, if there is one that runs.
    pub on_path: Option<String>,
    /// Our unpacked QEMU is complete and runs (version 7.x).
    pub private_ready: bool,
    pub bookworm: bool,
    /// apt-get, apt-cache and dpkg are there.
    pub apt: bool,
}

/// What to do about QEMU.
#[derive(Debug, PartialEq, Eq)]
pub enum QemuPlan {
    /// The `QEMU=` one.
    UseEnv,
    /// `qemu-system-arm` on PATH.
    UsePath,
    /// The one unpacked into our cache.
    UsePrivate,
    /// Download Debian bookworm's packages and unpack them into our cache
    /// (no package is installed or removed; missing shared libraries are
    /// handled by `library_step`).
    Unpack,
    /// Stop with this message (the one thing the user should do).
    Refuse(String),
}

pub fn qemu_plan(f: &QemuFacts) -> QemuPlan {
    match &f.env {
        Some((_, Some(v))) if is_7x(v) => return QemuPlan::UseEnv,
        Some((path, Some(v))) => {
            return QemuPlan::Refuse(format!(
                "QEMU={path} is QEMU {v}; QEMU 7.x is needed (Debian bookworm's 7.2): unset QEMU or point it at a QEMU 7.x"
            ))
        }
        Some((path, None)) => {
            return QemuPlan::Refuse(format!(
                "QEMU={path} does not run: unset QEMU or point it at a QEMU 7.x qemu-system-arm"
            ))
        }
        None => {}
    }
    if f.on_path.as_deref().is_some_and(is_7x) {
        return QemuPlan::UsePath;
    }
    if f.private_ready {
        return QemuPlan::UsePrivate;
    }
    if f.bookworm && f.apt {
        return QemuPlan::Unpack;
    }
    let found = match &f.on_path {
        Some(v) => format!(
            "qemu-system-arm on PATH is QEMU {v}, and QEMU 7.x is needed (QEMU 10.0.2 from bookworm-backports segfaults when the HAL resets an APB2 peripheral)"
        ),
        None => "qemu-system-arm (QEMU 7.x) is not installed".to_owned(),
    };
    QemuPlan::Refuse(format!(
        "{found}; on Debian bookworm `cargo qemu` unpacks QEMU 7.2 into its cache by itself, elsewhere install QEMU 7.x and run:\n    QEMU=/path/to/qemu-system-arm cargo qemu"
    ))
}

/// Lines "Remv PACKAGE [...]" of `apt-get install -s`: what it would remove.
pub fn parse_removals(simulation: &str) -> Vec<String> {
    simulation
        .lines()
        .filter_map(|l| l.strip_prefix("Remv "))
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_owned)
        .collect()
}

/// The shared-library packages among `apt-cache depends` lines
/// ("  Depends: libfdt1", "  |Depends: ..."), without QEMU's own packages
/// and virtual ones ("<...>").
pub fn parse_library_depends(depends: &str) -> Vec<String> {
    let mut libs: Vec<String> = depends
        .lines()
        .filter_map(|l| {
            let l = l.trim_start();
            let l = l.strip_prefix('|').unwrap_or(l);
            l.strip_prefix("Depends: ")
        })
        .map(str::trim)
        .filter(|p| !p.starts_with('<') && (p.starts_with("lib") || *p == "zlib1g"))
        .map(str::to_owned)
        .collect();
    libs.sort();
    libs.dedup();
    libs
}

/// Libraries `ldd` did not find ("\tlibfdt.so.1 => not found").
pub fn parse_ldd_missing(ldd: &str) -> Vec<String> {
    ldd.lines()
        .filter(|l| l.contains("=> not found"))
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_owned)
        .collect()
}

/// What to do about QEMU's shared libraries.
#[derive(Debug, PartialEq, Eq)]
pub enum LibraryStep {
    Ready,
    /// `apt-get install --no-install-recommends` these (it removes nothing).
    Install(Vec<String>),
    Refuse(String),
}

pub fn library_step(
    missing: &[String],
    packages: &[String],
    removals: &[String],
    root: bool,
) -> LibraryStep {
    if missing.is_empty() {
        return LibraryStep::Ready;
    }
    let install = format!(
        "apt-get install --no-install-recommends {}",
        packages.join(" ")
    );
    if !removals.is_empty() {
        return LibraryStep::Refuse(format!(
            "QEMU 7.2 misses {} shared libraries, and installing them ({install}) would remove {}: not done. Install QEMU 7.x some other way and run:\n    QEMU=/path/to/qemu-system-arm cargo qemu",
            missing.len(),
            removals.join(", ")
        ));
    }
    if !root {
        return LibraryStep::Refuse(format!(
            "QEMU 7.2 (unpacked into the cache) misses {} shared libraries ({}); install them (this removes nothing), then run cargo qemu again:\n    sudo {install}",
            missing.len(),
            missing.join(", ")
        ));
    }
    LibraryStep::Install(packages.to_vec())
}

fn private_prefix() -> Result<PathBuf> {
    Ok(util::cache_dir()?.join("qemu-7.2"))
}

fn private_bin(prefix: &Path) -> PathBuf {
    prefix.join("usr/bin/qemu-system-arm")
}

fn ldd_missing(bin: &Path) -> Vec<String> {
    util::stdout_of(&mut cmd("ldd", [bin]))
        .map(|t| parse_ldd_missing(&t))
        .unwrap_or_default()
}

/// Find QEMU 7.x, or set Debian bookworm's up in our cache (never through
/// apt-get install of QEMU itself: its qemu-system-common breaks and
/// removes a newer qemu-utils).
pub fn qemu() -> Result<Qemu> {
    let mut facts = QemuFacts::default();
    let env_bin = std::env::var_os("QEMU")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from);
    if let Some(b) = &env_bin {
        facts.env = Some((b.display().to_string(), qemu_version(b)));
    }
    let path_bin = util::which("qemu-system-arm");
    facts.on_path = path_bin.as_deref().and_then(qemu_version);
    let prefix = private_prefix()?;
    let pbin = private_bin(&prefix);
    facts.private_ready = prefix.join(".unpacked").is_file()
        && qemu_version(&pbin).is_some_and(|v| is_7x(&v))
        && ldd_missing(&pbin).is_empty();
    facts.bookworm = std::fs::read_to_string("/etc/os-release").is_ok_and(|t| is_bookworm(&t));
    facts.apt = ["apt-get", "apt-cache", "dpkg"]
        .iter()
        .all(|p| util::which(p).is_some());
    let plan = qemu_plan(&facts);
    let found = |bin: PathBuf, version: Option<String>, data_dir| {
        Ok(Qemu {
            bin,
            version: version.unwrap_or_default(),
            data_dir,
        })
    };
    match plan {
        QemuPlan::UseEnv => found(
            env_bin.unwrap_or_default(),
            facts.env.and_then(|(_, v)| v),
            None,
        ),
        QemuPlan::UsePath => found(path_bin.unwrap_or_default(), facts.on_path, None),
        QemuPlan::UsePrivate => {
            let v = qemu_version(&pbin);
            found(pbin, v, Some(prefix.join("usr/share/qemu")))
        }
        QemuPlan::Refuse(m) => Err(m.into()),
        QemuPlan::Unpack => {
            unpack_qemu(&prefix, facts.on_path.as_deref())?;
            let v = qemu_version(&pbin);
            match &v {
                Some(v) if is_7x(v) => {}
                _ => bail!(
                    "the unpacked {} does not run as QEMU 7.x ({v:?})",
                    pbin.display()
                ),
            }
            say(
                P,
                format!(
                    "QEMU {} ready in {}",
                    v.as_deref().unwrap_or("?"),
                    prefix.display()
                ),
            );
            found(pbin, v, Some(prefix.join("usr/share/qemu")))
        }
    }
}

fn apt_get() -> Command {
    let mut c = Command::new("apt-get");
    c.env("DEBIAN_FRONTEND", "noninteractive");
    c
}

/// Debian bookworm's QEMU 7.2, downloaded (`apt-get download`, no root
/// needed) and unpacked (`dpkg -x`) into `prefix`; its shared libraries
/// installed only if some are missing, only as root, and only if apt
/// removes nothing for them.
fn unpack_qemu(prefix: &Path, on_path: Option<&str>) -> Result {
    let root_user = util::is_root();
    match on_path {
        Some(v) => say(P, format!("first use: qemu-system-arm on PATH is QEMU {v}, not 7.x; leaving it alone and unpacking Debian bookworm's QEMU 7.2 into {}", prefix.display())),
        None => say(P, format!("first use: no qemu-system-arm; unpacking Debian bookworm's QEMU 7.2 (apt-get download, dpkg -x; nothing is installed) into {}", prefix.display())),
    }
    ensure_package_lists(root_user)?;
    let cache = prefix
        .parent()
        .ok_or("the QEMU cache directory has no parent")?
        .to_path_buf();
    std::fs::create_dir_all(&cache)
        .map_err(|e| format!("cannot create {}: {e}", cache.display()))?;
    let debs = cache.join("qemu-7.2.debs");
    let staging = cache.join("qemu-7.2.new");
    for d in [&debs, &staging] {
        let _ = std::fs::remove_dir_all(d);
        std::fs::create_dir_all(d).map_err(|e| format!("cannot create {}: {e}", d.display()))?;
    }
    let files = download_debs(&debs, root_user)?;
    for f in &files {
        util::run_or_say(&mut cmd(
            "dpkg",
            ["-x".as_ref(), f.as_os_str(), staging.as_os_str()],
        ))?;
    }
    let _ = std::fs::remove_dir_all(&debs);
    let _ = std::fs::remove_dir_all(prefix);
    std::fs::rename(&staging, prefix).map_err(|e| {
        format!(
            "cannot move {} to {}: {e}",
            staging.display(),
            prefix.display()
        )
    })?;

    let bin = private_bin(prefix);
    install_missing_libraries(&bin, root_user)?;
    std::fs::write(prefix.join(".unpacked"), "")
        .map_err(|e| format!("cannot write {}: {e}", prefix.display()))?;
    Ok(())
}

/// Package lists: a fresh container has none (only root may fetch them).
fn ensure_package_lists(root_user: bool) -> Result {
    let listed = || util::stdout_of(&mut cmd("apt-cache", ["show", "qemu-system-arm"])).is_some();
    if !listed() {
        if !root_user {
            bail!("apt knows no qemu-system-arm (no package lists yet); run this, then cargo qemu again:\n    sudo apt-get update");
        }
        util::run_or_say(apt_get().args(["update", "-q"]))?;
    }
    Ok(())
}

/// `apt-get download` of every QEMU package into `debs` (as root, once
/// more after `apt-get update` when stale lists name versions the mirror
/// no longer has); the .deb files, sorted, each package among them.
fn download_debs(debs: &Path, root_user: bool) -> Result<Vec<PathBuf>> {
    let download = || {
        util::capture(
            apt_get()
                .arg("download")
                .arg("-q")
                .args(QEMU_PACKAGES)
                .current_dir(debs),
        )
    };
    let mut out = download()?;
    if !out.status.success() && root_user {
        // Stale lists name versions the mirror no longer has.
        util::run_or_say(apt_get().args(["update", "-q"]))?;
        out = download()?;
    }
    if !out.status.success() {
        bail!(
            "apt-get download {} failed:\n{}",
            QEMU_PACKAGES.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(debs)
        .map_err(|e| format!("cannot read {}: {e}", debs.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "deb"))
        .collect();
    files.sort();
    for p in QEMU_PACKAGES {
        let have = files.iter().any(|f| {
            f.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with(&format!("{p}_")))
        });
        if !have {
            bail!("apt-get download did not fetch {p}");
        }
    }
    Ok(files)
}

/// The shared libraries QEMU misses (ldd), installed by apt only as root and
/// only if apt removes nothing for them; else what to do is the error.
fn install_missing_libraries(bin: &Path, root_user: bool) -> Result {
    let missing = ldd_missing(bin);
    let (packages, removals) = if missing.is_empty() {
        (Vec::new(), Vec::new())
    } else {
        let depends = util::stdout_of(&mut cmd(
            "apt-cache",
            [
                "depends",
                "--no-recommends",
                "--no-suggests",
                "qemu-system-arm",
            ],
        ))
        .unwrap_or_default();
        let packages = parse_library_depends(&depends);
        let sim = util::capture(
            apt_get()
                .args(["install", "-s", "--no-install-recommends"])
                .args(&packages),
        )?;
        (
            packages,
            parse_removals(&String::from_utf8_lossy(&sim.stdout)),
        )
    };
    match library_step(&missing, &packages, &removals, root_user) {
        LibraryStep::Ready => {}
        LibraryStep::Refuse(m) => bail!("{m}"),
        LibraryStep::Install(pkgs) => {
            say(
                P,
                format!(
                    "QEMU misses {} shared libraries; apt-get install --no-install-recommends {} (removes nothing)",
                    missing.len(),
                    pkgs.join(" ")
                ),
            );
            util::run_or_say(
                apt_get()
                    .args(["install", "-y", "-q", "--no-install-recommends"])
                    .args(&pkgs),
            )?;
            let still = ldd_missing(bin);
            if !still.is_empty() {
                bail!("QEMU still misses {}", still.join(", "));
            }
        }
    }
    Ok(())
}

// --- defmt-print -----------------------------------------------------------

fn defmt_print_is_1x(bin: &Path) -> bool {
    util::stdout_of(&mut cmd(bin, ["--version"])).is_some_and(|v| v.starts_with("defmt-print 1."))
}

/// Where to install defmt-print when none of 1.x is found.
#[derive(Debug, PartialEq, Eq)]
pub enum DefmtInstall {
    /// `cargo install` into `CARGO_HOME/bin`.
    CargoHome,
    /// Another version is installed there: leave it, install into
    /// `target/tools`.
    Private,
}

pub fn defmt_install(other_version_installed: bool) -> DefmtInstall {
    if other_version_installed {
        DefmtInstall::Private
    } else {
        DefmtInstall::CargoHome
    }
}

/// defmt-print found, or its installation under way.
#[derive(Debug)]
pub enum DefmtPrint {
    Ready(PathBuf),
    /// `cargo install` runs in the background (its output in `log`).
    Installing {
        child: std::process::Child,
        log: PathBuf,
        bin: PathBuf,
    },
}

impl DefmtPrint {
    /// Wait for the installation, if one runs: the binary.
    pub fn wait(self) -> Result<PathBuf> {
        let (mut child, log, bin) = match self {
            DefmtPrint::Ready(p) => return Ok(p),
            DefmtPrint::Installing { child, log, bin } => (child, log, bin),
        };
        let status = child
            .wait()
            .map_err(|e| format!("waiting for cargo install defmt-print: {e}"))?;
        if !status.success() {
            let text = std::fs::read_to_string(&log).unwrap_or_default();
            bail!(
                "cargo install defmt-print failed (exit status {}):\n{text}",
                util::code(status)
            );
        }
        if !defmt_print_is_1x(&bin) {
            bail!(
                "defmt-print was installed but {} does not run",
                bin.display()
            );
        }
        say(
            P,
            format!(
                "defmt-print {DEFMT_PRINT_VERSION} installed: {}",
                bin.display()
            ),
        );
        Ok(bin)
    }
}

/// defmt-print 1.x: on PATH, in `CARGO_HOME/bin` (not necessarily on PATH)
/// or in `target/tools/bin`; if there is none, `cargo install --locked`
/// starts in the background (so the firmware can build meanwhile).
pub fn defmt_print_begin() -> Result<DefmtPrint> {
    let cargo_bin = util::cargo_home()?.join("bin").join("defmt-print");
    let tools = util::target_dir().join("tools");
    let private = tools.join("bin/defmt-print");
    let candidates: Vec<PathBuf> = util::which("defmt-print")
        .into_iter()
        .chain([cargo_bin.clone(), private.clone()])
        .collect();
    if let Some(found) = candidates.iter().find(|c| defmt_print_is_1x(c)) {
        return Ok(DefmtPrint::Ready(found.clone()));
    }
    let other = candidates.iter().take(2).any(|c| util::is_executable(c));
    std::fs::create_dir_all(&tools).map_err(|e| format!("{}: {e}", tools.display()))?;
    let log = tools.join("defmt-print-install.log");
    let mut install = util::cargo();
    install.args([
        "install",
        "defmt-print",
        "--version",
        DEFMT_PRINT_VERSION,
        "--locked",
    ]);
    let bin = match defmt_install(other) {
        DefmtInstall::CargoHome => {
            say(P, format!("first use: installing defmt-print {DEFMT_PRINT_VERSION} (cargo install --locked, ~1-2 min, once; output in {}): it decodes the image's defmt log", log.display()));
            cargo_bin
        }
        DefmtInstall::Private => {
            say(P, format!("first use: installing defmt-print {DEFMT_PRINT_VERSION} into {} (the installed defmt-print is not 1.x; left alone; output in {})", tools.display(), log.display()));
            install.arg("--root").arg(&tools);
            private
        }
    };
    let out = std::fs::File::create(&log).map_err(|e| format!("{}: {e}", log.display()))?;
    let err = out
        .try_clone()
        .map_err(|e| format!("{}: {e}", log.display()))?;
    let child = install
        .stdin(std::process::Stdio::null())
        .stdout(out)
        .stderr(err)
        .spawn()
        .map_err(|e| format!("cannot run {}: {e}", util::show(&install)))?;
    Ok(DefmtPrint::Installing { child, log, bin })
}

/// defmt-print 1.x, installed first if there is none.
pub fn defmt_print() -> Result<PathBuf> {
    defmt_print_begin()?.wait()
}

/// `cargo xtask setup`: everything `cargo qemu` needs, nothing built.
pub fn all() -> Result {
    ensure_target()?;
    let q = qemu()?;
    say(P, format!("QEMU {}: {}", q.version, q.bin.display()));
    let d = defmt_print()?;
    say(P, format!("defmt-print: {}", d.display()));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn target_added_when_rustup_lacks_it() {
        let installed = "x86_64-unknown-linux-gnu\nthumbv7em-none-eabihf\n";
        assert_eq!(target_step(Some(installed), false), TargetStep::Ready);
        assert_eq!(
            target_step(Some("x86_64-unknown-linux-gnu\n"), false),
            TargetStep::Add
        );
        // rustup's list wins over a stale sysroot check.
        assert_eq!(
            target_step(Some("x86_64-unknown-linux-gnu\n"), true),
            TargetStep::Add
        );
        assert_eq!(target_step(None, true), TargetStep::Ready);
        assert_eq!(target_step(None, false), TargetStep::Refuse);
        // A longer name is not the target.
        assert_eq!(
            target_step(Some("thumbv7em-none-eabihf-x\n"), false),
            TargetStep::Add
        );
    }

    #[test]
    fn qemu_version_line() {
        let v = "QEMU emulator version 7.2.22 (Debian 1:7.2+dfsg-7+deb12u18+b3)\nCopyright (c) 2003-2022";
        assert_eq!(parse_qemu_version(v).as_deref(), Some("7.2.22"));
        assert_eq!(
            parse_qemu_version("QEMU emulator version 10.0.2 (Debian)").as_deref(),
            Some("10.0.2")
        );
        assert_eq!(parse_qemu_version("qemu-img version 7.2.0"), None);
        assert!(is_7x("7.2.22"));
        assert!(!is_7x("10.0.2"));
        assert!(!is_7x("17.0"));
    }

    #[test]
    fn bookworm() {
        assert!(is_bookworm(
            "PRETTY_NAME=\"Debian GNU/Linux 12 (bookworm)\"\nVERSION_CODENAME=bookworm\n"
        ));
        assert!(!is_bookworm("VERSION_CODENAME=trixie\n"));
    }

    fn facts() -> QemuFacts {
        QemuFacts {
            bookworm: true,
            apt: true,
            ..QemuFacts::default()
        }
    }

    #[test]
    fn qemu_on_path_or_unpacked_never_installed() {
        let mut f = facts();
        assert_eq!(qemu_plan(&f), QemuPlan::Unpack);
        f.on_path = Some("7.2.22".into());
        assert_eq!(qemu_plan(&f), QemuPlan::UsePath);
        // A QEMU 10 from backports stays; ours is unpacked beside it.
        f.on_path = Some("10.0.2".into());
        assert_eq!(qemu_plan(&f), QemuPlan::Unpack);
        f.private_ready = true;
        assert_eq!(qemu_plan(&f), QemuPlan::UsePrivate);
    }

    #[test]
    fn qemu_refused_off_bookworm_with_one_command() {
        let f = QemuFacts {
            on_path: Some("10.0.2".into()),
            ..QemuFacts::default()
        };
        match qemu_plan(&f) {
            QemuPlan::Refuse(m) => {
                assert!(m.contains("QEMU 10.0.2"), "{m}");
                assert!(
                    m.contains("QEMU=/path/to/qemu-system-arm cargo qemu"),
                    "{m}"
                );
            }
            p => panic!("{p:?}"),
        }
        let f = QemuFacts {
            bookworm: true,
            apt: false,
            ..QemuFacts::default()
        };
        assert!(matches!(qemu_plan(&f), QemuPlan::Refuse(_)));
    }

    #[test]
    fn qemu_env_override() {
        let mut f = facts();
        f.env = Some(("/opt/q".into(), Some("7.2.0".into())));
        f.on_path = Some("10.0.2".into());
        assert_eq!(qemu_plan(&f), QemuPlan::UseEnv);
        f.env = Some(("/opt/q".into(), Some("8.0.0".into())));
        assert!(
            matches!(qemu_plan(&f), QemuPlan::Refuse(m) if m.contains("QEMU=/opt/q is QEMU 8.0.0"))
        );
        f.env = Some(("/opt/q".into(), None));
        assert!(matches!(qemu_plan(&f), QemuPlan::Refuse(_)));
    }

    #[test]
    fn apt_outputs() {
        let sim = "NOTE: This is only a simulation!\nThe following packages will be REMOVED:\n  qemu-utils\nRemv qemu-utils [1:10.0.2+ds-2+deb13u1~bpo12+1]\nInst libfdt1 (1.6.1-4+b1 Debian:12.15/oldstable [amd64])\nConf libfdt1 (1.6.1-4+b1)\n";
        assert_eq!(parse_removals(sim), vec!["qemu-utils".to_owned()]);
        assert!(parse_removals("Inst libfdt1 (1.6.1)\n").is_empty());
        let dep = "qemu-system-arm\n  Depends: libaio1\n  Depends: zlib1g\n |Depends: libfdt1\n  Depends: qemu-system-common\n  Depends: <libc-dev>\n  Depends: libaio1\n";
        assert_eq!(
            parse_library_depends(dep),
            vec!["libaio1".to_owned(), "libfdt1".into(), "zlib1g".into()]
        );
        let ldd = "\tlinux-vdso.so.1 (0x00007ffd)\n\tlibfdt.so.1 => not found\n\tlibz.so.1 => /lib/x86_64-linux-gnu/libz.so.1 (0x00007f)\n";
        assert_eq!(parse_ldd_missing(ldd), vec!["libfdt.so.1".to_owned()]);
    }

    #[test]
    fn libraries_installed_only_as_root_and_only_without_removals() {
        let missing = vec!["libfdt.so.1".to_owned()];
        let pkgs = vec!["libfdt1".to_owned(), "zlib1g".to_owned()];
        assert_eq!(library_step(&[], &pkgs, &[], false), LibraryStep::Ready);
        assert_eq!(
            library_step(&missing, &pkgs, &[], true),
            LibraryStep::Install(pkgs.clone())
        );
        match library_step(&missing, &pkgs, &[], false) {
            LibraryStep::Refuse(m) => assert!(
                m.contains("sudo apt-get install --no-install-recommends libfdt1 zlib1g"),
                "{m}"
            ),
            s => panic!("{s:?}"),
        }
        match library_step(&missing, &pkgs, &["qemu-utils".to_owned()], true) {
            LibraryStep::Refuse(m) => assert!(m.contains("would remove qemu-utils"), "{m}"),
            s => panic!("{s:?}"),
        }
    }

    #[test]
    fn defmt_print_elsewhere_when_another_version_is_installed() {
        assert_eq!(defmt_install(false), DefmtInstall::CargoHome);
        assert_eq!(defmt_install(true), DefmtInstall::Private);
    }
}
