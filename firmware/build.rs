//! Put the workspace's `memory.x` where cortex-m-rt's `link.x` finds it, and
//! hand the firmware its build id.
//!
//! The linker flags themselves (`-Tlink.x`, `-Tdefmt.x`, `--nmagic`) live in
//! `.cargo/config.toml`, scoped to the ARM target, so host builds never see
//! them.
//!
//! Build id (`STEPBRIDGE_BUILD_ID`, 8 hex digits, read by `firmware::BUILD_ID`):
//! the first 32 bits of the git commit the sources are checked out at
//! (`git rev-parse HEAD`), uncommitted changes or not; `0` when the sources
//! are not a git checkout or git is missing, so a build never fails for it.

use std::env;
use std::error::Error;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

fn main() -> Result<(), Box<dyn Error>> {
    let manifest = PathBuf::from(env::var("CARGO_MANIFEST_DIR")?);
    let memory_x = manifest.join("..").join("memory.x");
    let out = PathBuf::from(env::var("OUT_DIR")?);
    fs::copy(&memory_x, out.join("memory.x"))
        .map_err(|e| format!("copying {}: {e}", memory_x.display()))?;
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");

    println!(
        "cargo:rustc-env=STEPBRIDGE_BUILD_ID={}",
        build_id(&manifest)
    );
    // Build again when HEAD moves: HEAD itself (a branch switch), the branch
    // it points to (a commit), packed refs. Only files that exist: cargo
    // reruns a build script on every build for a missing one.
    let mut watched = vec!["HEAD".to_string(), "packed-refs".to_string()];
    if let Some(branch) = git(&manifest, &["rev-parse", "--symbolic-full-name", "HEAD"]) {
        if branch.starts_with("refs/") {
            watched.push(branch);
        }
    }
    for name in watched {
        if let Some(path) = git(&manifest, &["rev-parse", "--git-path", &name]) {
            let path = manifest.join(path);
            if path.is_file() {
                println!("cargo:rerun-if-changed={}", path.display());
            }
        }
    }
    Ok(())
}

/// The first 8 hex digits of HEAD's commit, or "0".
fn build_id(dir: &Path) -> String {
    git(dir, &["rev-parse", "HEAD"])
        .and_then(|hash| hash.get(..8).map(str::to_owned))
        .filter(|id| id.chars().all(|c| c.is_ascii_hexdigit()))
        .unwrap_or_else(|| "0".to_owned())
}

/// `git ARGS` in `dir`: its first line of output, if it succeeded.
fn git(dir: &Path, args: &[&str]) -> Option<String> {
    let out = Command::new("git")
        .args(args)
        .current_dir(dir)
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let text = String::from_utf8(out.stdout).ok()?;
    let line = text.lines().next()?.trim();
    (!line.is_empty()).then(|| line.to_owned())
}
