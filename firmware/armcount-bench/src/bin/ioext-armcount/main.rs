//! The I/O extension's CPU work for one 256-bit transfer, region by region,
//! between marker functions that `cargo xtask ioext-cpu` hands to the
//! armcount plugin (tools/armcount): counter 1 `IoExtension::tick` (plan,
//! 24 lamps), 2 the SPI engine's byte packing and unpacking, 3
//! `IoExtension::complete` (32 debounced inputs), 4 the timer engine's
//! BSRR table and port samples, 5 an empty marker pair (calibration). 8
//! axes, every input and lamp mapped.
//!
//! The image is `image.rs`, built for the target only (`cargo xtask
//! ioext-cpu`); on the host this bin is an empty `main`.
#![cfg_attr(target_os = "none", no_std, no_main)]

/// The I/O extension's settings, its markers and the measured loop (the
/// panic handler and `__pre_init` are the library's, src/lib.rs).
#[cfg(target_os = "none")]
mod image;

#[cfg(not(target_os = "none"))]
fn main() {}
