//! `cargo xtask readme-examples`: run the README's code examples as
//! written. A runnable example is a fenced block right after a marker
//! line:
//!
//! ```text
//! <!-- example: python; against cargo qemu; prints [65, 256, 265] -->
//! <!-- example: sh; against cargo qemu -->
//! ```
//!
//! `python` blocks run with `python3`, `sh` blocks with `bash -e`, each in
//! a directory of its own. `against cargo qemu`: before the block, the
//! runner starts the README's `cargo qemu` itself (in the background, on a
//! fresh settings flash of its own: `QEMU_FLASH`, `QEMU_FRESH=1`), waits
//! for its Modbus line and stops it after the block; a line of the block
//! that starts with `cargo qemu` (the README's "in another terminal") is
//! that run and is skipped. `prints TEXT`: the block's output must contain
//! TEXT. `stepctl` is the workspace's debug build (on PATH for the block),
//! not an installed one. Port 5020 (the examples' address) must be free.

use std::io::Read as _;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::util::{self, bail, say, Result, TempDir};

const P: &str = "readme-examples";
const READY: &str = "modbus: RTU on USART2";

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Example {
    /// README line of the marker.
    pub line: usize,
    pub lang: String,
    pub against_qemu: bool,
    pub prints: Option<String>,
    pub code: String,
}

/// The marked examples of a Markdown text.
pub fn parse(readme: &str) -> std::result::Result<Vec<Example>, String> {
    let lines: Vec<&str> = readme.lines().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let t = lines.get(i).map_or("", |l| l.trim());
        let Some(spec) = t
            .strip_prefix("<!-- example:")
            .and_then(|s| s.strip_suffix("-->"))
        else {
            i += 1;
            continue;
        };
        let marker = i + 1;
        let mut items = spec.split(';').map(str::trim);
        let lang = items.next().unwrap_or("").to_owned();
        let mut ex = Example {
            line: marker,
            lang,
            against_qemu: false,
            prints: None,
            code: String::new(),
        };
        for item in items {
            if item == "against cargo qemu" {
                ex.against_qemu = true;
            } else if let Some(p) = item.strip_prefix("prints ") {
                ex.prints = Some(p.to_owned());
            } else if !item.is_empty() {
                return Err(format!("README.md:{marker}: unknown example item '{item}'"));
            }
        }
        if ex.lang != "python" && ex.lang != "sh" {
            return Err(format!(
                "README.md:{marker}: example language '{}' (python or sh)",
                ex.lang
            ));
        }
        let fence = lines.get(i + 1).map_or("", |l| l.trim());
        if fence != format!("```{}", ex.lang) {
            return Err(format!(
                "README.md:{marker}: the marker must be followed by a ```{} block",
                ex.lang
            ));
        }
        let mut j = i + 2;
        loop {
            match lines.get(j) {
                None => return Err(format!("README.md:{marker}: the block never ends")),
                Some(l) if l.trim() == "```" => break,
                Some(l) => {
                    ex.code.push_str(l);
                    ex.code.push('\n');
                }
            }
            j += 1;
        }
        out.push(ex);
        i = j + 1;
    }
    Ok(out)
}

/// The block as the runner runs it: without the `cargo qemu` it started.
pub fn runnable(ex: &Example) -> String {
    if !ex.against_qemu {
        return ex.code.clone();
    }
    ex.code
        .lines()
        .filter(|l| {
            let t = l.trim_start();
            !(t == "cargo qemu" || t.starts_with("cargo qemu ") || t.starts_with("cargo qemu\t"))
        })
        .map(|l| format!("{l}\n"))
        .collect()
}

/// Whether 127.0.0.1:5020 can be listened on, trying for up to `timeout`.
fn port_free_within(timeout: Duration) -> bool {
    let t0 = Instant::now();
    loop {
        if std::net::TcpListener::bind("127.0.0.1:5020").is_ok() {
            return true;
        }
        if t0.elapsed() > timeout {
            return false;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// `cargo qemu`, as the README says, in a process group of its own.
struct Booted {
    child: Child,
    log: PathBuf,
}

impl Booted {
    fn start(dir: &Path) -> Result<Self> {
        use std::os::unix::process::CommandExt;
        // The previous example's QEMU may still be closing its socket.
        if !port_free_within(Duration::from_secs(10)) {
            bail!("127.0.0.1:5020 is in use: the examples talk to cargo qemu there (stop what listens on it)");
        }
        let log = dir.join("qemu.log");
        let err = dir.join("qemu.err");
        let open = |p: &Path| std::fs::File::create(p).map_err(|e| format!("{}: {e}", p.display()));
        let mut c = util::cargo();
        c.arg("qemu")
            .env("QEMU_FLASH", dir.join("flash.bin"))
            .env("QEMU_FRESH", "1")
            .stdin(Stdio::null())
            .stdout(open(&log)?)
            .stderr(open(&err)?)
            .process_group(0);
        let child = c
            .spawn()
            .map_err(|e| format!("cannot run cargo qemu: {e}"))?;
        let mut b = Booted { child, log };
        let t0 = Instant::now();
        let timeout = Duration::from_secs(
            std::env::var("BOOT_TIMEOUT")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(600),
        );
        loop {
            let text = std::fs::read_to_string(&b.log).unwrap_or_default();
            if text.contains(READY) {
                say(
                    P,
                    format!("cargo qemu: Modbus ready after {} s", util::secs(t0)),
                );
                return Ok(b);
            }
            if let Ok(Some(s)) = b.child.try_wait() {
                let mut e = String::new();
                let _ = std::fs::File::open(&err).and_then(|mut f| f.read_to_string(&mut e));
                bail!("cargo qemu exited ({s}) before '{READY}':\n{text}{e}");
            }
            if t0.elapsed() > timeout {
                b.stop();
                bail!(
                    "no '{READY}' from cargo qemu within {} s",
                    timeout.as_secs()
                );
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn stop(&mut self) {
        // The group: cargo, the runner, QEMU and defmt-print. Wait until
        // the whole group is gone (QEMU may outlive cargo a moment).
        let group = format!("-{}", self.child.id());
        let _ = Command::new("kill").args(["-TERM", "--", &group]).status();
        let _ = self.child.wait();
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(10) {
            let alive = Command::new("kill")
                .args(["-0", "--", &group])
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success());
            if !alive {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Booted {
    fn drop(&mut self) {
        self.stop();
    }
}

pub fn main(_args: &[String]) -> Result {
    let root = util::root();
    let readme =
        std::fs::read_to_string(root.join("README.md")).map_err(|e| format!("README.md: {e}"))?;
    let examples = parse(&readme).map_err(util::Error::Msg)?;
    if examples.is_empty() {
        bail!("README.md marks no example (<!-- example: ... -->)");
    }
    let t0 = Instant::now();
    if examples.iter().any(|e| e.against_qemu) {
        // The image `cargo qemu` runs, built before the clock starts.
        crate::cargo_tasks::qemu_build(&[])?;
    }
    if examples.iter().any(|e| e.code.contains("stepctl")) {
        util::run(util::cargo().args(["build", "-q", "-p", "stepctl"]))?;
    }
    let path = search_path()?;
    let tmp = TempDir::new("stepbridge-readme")?;
    for (n, ex) in examples.iter().enumerate() {
        let dir = tmp.path().join(format!("example-{}", n + 1));
        run_example(ex, &dir, &path)?;
    }
    say(
        P,
        format!(
            "{} README examples passed ({} s)",
            examples.len(),
            util::secs(t0)
        ),
    );
    Ok(())
}

/// PATH with the workspace's target/debug first (the stepctl just built).
fn search_path() -> Result<std::ffi::OsString> {
    let bin = util::target_dir().join("debug");
    Ok(match std::env::var_os("PATH") {
        Some(p) => {
            let mut v = vec![bin];
            v.extend(std::env::split_paths(&p));
            std::env::join_paths(v).map_err(|e| format!("PATH: {e}"))?
        }
        None => bin.into_os_string(),
    })
}

/// One example in its own directory `dir` (with `cargo qemu` running when it
/// is against it): it must exit 0 and print what it says it prints.
fn run_example(ex: &Example, dir: &Path, path: &std::ffi::OsStr) -> Result {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    say(
        P,
        format!(
            "README.md:{}: {} example{}",
            ex.line,
            ex.lang,
            if ex.against_qemu {
                " against cargo qemu"
            } else {
                ""
            }
        ),
    );
    let qemu = if ex.against_qemu {
        Some(Booted::start(dir)?)
    } else {
        None
    };
    let (file, mut c) = match ex.lang.as_str() {
        "python" => ("example.py", Command::new("python3")),
        _ => {
            let mut c = Command::new("bash");
            c.arg("-e");
            ("example.sh", c)
        }
    };
    let script = dir.join(file);
    std::fs::write(&script, runnable(ex)).map_err(|e| format!("{}: {e}", script.display()))?;
    let t = Instant::now();
    let out = util::capture(c.arg(&script).current_dir(dir).env("PATH", path))?;
    drop(qemu);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    print!("{stdout}");
    eprint!("{stderr}");
    if !out.status.success() {
        bail!(
            "README.md:{}: the {} example failed (exit status {})",
            ex.line,
            ex.lang,
            util::code(out.status)
        );
    }
    if let Some(p) = &ex.prints {
        if !stdout.contains(p.as_str()) {
            bail!("README.md:{}: the example did not print {p}", ex.line);
        }
    }
    say(
        P,
        format!("README.md:{}: passed in {} s", ex.line, util::secs(t)),
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const MD: &str = "# x

<!-- example: python; against cargo qemu; prints [65, 256, 265] -->
```python
print([65, 256, 265])
```

```sh
not marked
```

<!-- example: sh; against cargo qemu -->
```sh
cargo qemu                               # in another terminal
stepctl scan
```
";

    #[test]
    fn marked_blocks_only() {
        let e = parse(MD).unwrap_or_else(|m| panic!("{m}"));
        assert_eq!(e.len(), 2);
        assert_eq!(e[0].lang, "python");
        assert_eq!(e[0].line, 3);
        assert_eq!(e[0].prints.as_deref(), Some("[65, 256, 265]"));
        assert_eq!(e[0].code, "print([65, 256, 265])\n");
        assert!(e[1].against_qemu);
        assert_eq!(runnable(&e[1]), "stepctl scan\n");
    }

    #[test]
    fn bad_markers() {
        assert!(parse("<!-- example: rust -->\n```rust\n```\n").is_err());
        assert!(parse("<!-- example: sh -->\ntext\n").is_err());
        assert!(parse("<!-- example: sh; frob -->\n```sh\n```\n").is_err());
        assert!(parse("<!-- example: sh -->\n```sh\nls\n").is_err());
    }
}
