//! Running programs, paths, messages.

use std::ffi::OsStr;
use std::fmt;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Output, Stdio};

/// Why a task stopped.
#[derive(Debug)]
pub enum Error {
    /// Something to tell the user (printed as `xtask: MESSAGE`, exit 1).
    Msg(String),
    /// A program we ran failed and said so itself: exit with its status.
    Exit(i32),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Msg(m) => f.write_str(m),
            Error::Exit(c) => write!(f, "exit status {c}"),
        }
    }
}

impl From<String> for Error {
    fn from(m: String) -> Self {
        Error::Msg(m)
    }
}

impl From<&str> for Error {
    fn from(m: &str) -> Self {
        Error::Msg(m.to_owned())
    }
}

pub type Result<T = ()> = std::result::Result<T, Error>;

/// `Err(Error::Msg(..))` from a format string.
macro_rules! bail {
    ($($t:tt)*) => { return Err($crate::util::Error::Msg(format!($($t)*))) };
}
pub(crate) use bail;

/// A message on stderr, `PREFIX: TEXT`.
pub fn say(prefix: &str, text: impl fmt::Display) {
    eprintln!("{prefix}: {text}");
}

/// The workspace root (this crate's parent directory).
pub fn root() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest.parent().unwrap_or(manifest).to_path_buf()
}

/// Cargo's target directory: `CARGO_TARGET_DIR` (relative to the root) or
/// `target/`.
pub fn target_dir() -> PathBuf {
    match std::env::var_os("CARGO_TARGET_DIR") {
        Some(d) if !d.is_empty() => root().join(d),
        _ => root().join("target"),
    }
}

/// `cargo`: the one that runs us (`CARGO`), else the one on PATH, in the
/// workspace root.
pub fn cargo() -> Command {
    let mut c = Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()));
    c.current_dir(root());
    c
}

/// `$HOME`.
pub fn home() -> Result<PathBuf> {
    match std::env::var_os("HOME") {
        Some(h) if !h.is_empty() => Ok(PathBuf::from(h)),
        _ => bail!("HOME is not set"),
    }
}

/// Our cache: `$STEPBRIDGE_CACHE`, else `~/.cache/stepbridge` (shared with
/// scripts/usbip-kernel).
pub fn cache_dir() -> Result<PathBuf> {
    match std::env::var_os("STEPBRIDGE_CACHE") {
        Some(d) if !d.is_empty() => Ok(PathBuf::from(d)),
        _ => Ok(home()?.join(".cache").join("stepbridge")),
    }
}

/// `$CARGO_HOME`, else `~/.cargo`.
pub fn cargo_home() -> Result<PathBuf> {
    match std::env::var_os("CARGO_HOME") {
        Some(d) if !d.is_empty() => Ok(PathBuf::from(d)),
        _ => Ok(home()?.join(".cargo")),
    }
}

/// The first executable `name` on PATH.
pub fn which(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join(name))
        .find(|p| is_executable(p))
}

pub fn is_executable(p: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt;
    p.metadata()
        .map(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
        .unwrap_or(false)
}

/// A shell-like rendering of a command, for messages.
pub fn show(c: &Command) -> String {
    let mut s = c.get_program().to_string_lossy().into_owned();
    for a in c.get_args() {
        s.push(' ');
        s.push_str(&a.to_string_lossy());
    }
    s
}

/// The exit code of a finished process; 128 + N when signal N ended it
/// (what a shell reports).
pub fn code(status: ExitStatus) -> i32 {
    use std::os::unix::process::ExitStatusExt;
    status
        .code()
        .or_else(|| status.signal().map(|s| 128 + s))
        .unwrap_or(1)
}

/// Run `c` (inheriting stdio); a failure is `Error::Exit` with its status
/// (the program has said why itself).
pub fn run(c: &mut Command) -> Result {
    let status = c
        .status()
        .map_err(|e| format!("cannot run {}: {e}", show(c)))?;
    if status.success() {
        Ok(())
    } else {
        Err(Error::Exit(code(status)))
    }
}

/// Run `c` and fail with a message naming it when it fails.
pub fn run_or_say(c: &mut Command) -> Result {
    match run(c) {
        Err(Error::Exit(code)) => bail!("{} failed (exit status {code})", show(c)),
        r => r,
    }
}

/// Run `c` with stdout and stderr captured.
pub fn capture(c: &mut Command) -> Result<Output> {
    c.stdin(Stdio::null())
        .output()
        .map_err(|e| format!("cannot run {}: {e}", show(c)).into())
}

/// Run `c`; its stdout as text if it succeeded, `None` if it could not run
/// or failed.
pub fn stdout_of(c: &mut Command) -> Option<String> {
    let o = c.stdin(Stdio::null()).stderr(Stdio::null()).output().ok()?;
    o.status
        .success()
        .then(|| String::from_utf8_lossy(&o.stdout).into_owned())
}

/// `program args...` as a Command.
pub fn cmd<I, S>(program: impl AsRef<OsStr>, args: I) -> Command
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    let mut c = Command::new(program);
    c.args(args);
    c
}

/// Are we root? (`id -u`; std has no getuid without unsafe.)
pub fn is_root() -> bool {
    stdout_of(&mut cmd("id", ["-u"])).is_some_and(|s| s.trim() == "0")
}

/// A directory of our own under the system's temporary directory, removed
/// when dropped.
#[derive(Debug)]
pub struct TempDir(PathBuf);

impl TempDir {
    pub fn new(prefix: &str) -> Result<Self> {
        let base = std::env::temp_dir();
        let pid = std::process::id();
        for n in 0..1000u32 {
            let p = base.join(format!("{prefix}.{pid}.{n}"));
            match std::fs::create_dir(&p) {
                Ok(()) => return Ok(TempDir(p)),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => bail!("cannot create {}: {e}", p.display()),
            }
        }
        bail!("cannot create a temporary directory in {}", base.display())
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Seconds since `t`, one decimal.
pub fn secs(t: std::time::Instant) -> String {
    format!("{:.1}", t.elapsed().as_secs_f64())
}
