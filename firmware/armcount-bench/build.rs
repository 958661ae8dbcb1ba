//! cortex-m-rt's link.x includes memory.x: use the firmware's.
fn main() {
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR").unwrap_or_default());
    let _ = std::fs::copy("../../memory.x", out.join("memory.x"));
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=../../memory.x");
}
