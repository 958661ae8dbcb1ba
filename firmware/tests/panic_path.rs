//! The panic path under QEMU: a panic goes through the firmware's panic
//! handler (`failsafe`: interrupts off, STBY low, the message through defmt,
//! `udf`) into the platform's HardFault handler, which ends QEMU with exit
//! status 1 — what makes a crashed image fail a test run instead of hanging
//! it. QEMU only (feature `qemu`): `cargo xtask qemu-run --test` passes this
//! binary exactly when QEMU exits with status 1 after the panic message.
//! On the board, `failsafe` checks the STBY pin itself.
#![cfg_attr(target_os = "none", no_std, no_main)]
// An on-target test, not bus input: it may index, unwrap, panic and (like
// the drivers) touch registers in `unsafe` blocks.
#![allow(unsafe_code, clippy::indexing_slicing, clippy::arithmetic_side_effects)]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#[cfg(not(target_os = "none"))]
fn main() {}

#[cfg(target_os = "none")]
mod common;

#[cfg(target_os = "none")]
#[cortex_m_rt::entry]
fn main() -> ! {
    let mut t = common::setup();
    t.pins.chain_stby.set_high();
    defmt::info!("panic_path: STBY released, panicking on purpose");
    panic!("on purpose: the panic path under test");
}
