//! Put the workspace's `memory.x` where cortex-m-rt's `link.x` finds it.
//!
//! The linker flags themselves (`-Tlink.x`, `-Tdefmt.x`, `--nmagic`) live in
//! `.cargo/config.toml`, scoped to the ARM target, so host builds never see
//! them.

use std::env;
use std::error::Error;
use std::fs;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn Error>> {
    let manifest = PathBuf::from(env::var("CARGO_MANIFEST_DIR")?);
    let memory_x = manifest.join("..").join("memory.x");
    let out = PathBuf::from(env::var("OUT_DIR")?);
    fs::copy(&memory_x, out.join("memory.x"))
        .map_err(|e| format!("copying {}: {e}", memory_x.display()))?;
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}
