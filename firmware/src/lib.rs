//! The stepbridge firmware's hardware side, shared by the RTIC app
//! (`main.rs`) and the on-target tests (`tests/`):
//!
//! * [`pins`]: every pin and peripheral assignment;
//! * [`platform`]: the one seam between the board and QEMU — the same names
//!   (clocks, chain driver, settings flash, analog, I2C, control timer,
//!   watchdog, reset cause, fault handler, log transport) from
//!   `platform/stm32f405.rs` or `platform/qemu.rs`;
//! * [`drivers`]: one module per peripheral driver (chain SPI, I2C slave,
//!   RS-485, flash, analog, SysTick clock, I/O-extension SPI);
//! * [`failsafe`]: the panic handler and the STBY switch-off it shares with
//!   the fault handlers;
//! * [`startup`] and [`handoff`]: the app's start-up steps and its
//!   task-to-bridge hand-offs that need no RTIC resource.
//!
//! Every decision about what goes on a bus belongs to the logic crate
//! (`bridge_logic`); this crate only moves bytes.
//!
//! The firmware is built only for `thumbv7em-none-eabihf`; on any other
//! target this library is empty, so a host-side `cargo check --workspace`
//! still works.
#![cfg(target_os = "none")]
#![no_std]
#![deny(unsafe_code)]

pub mod drivers;
pub mod failsafe;
pub mod handoff;
pub mod pins;
pub mod platform;
mod ramtext;
pub mod startup;

/// The firmware's build id (diagnostics register 0x0344–45, boot log): the
/// first 32 bits of the git commit it was built from, 0 when it was not
/// built from a git checkout (`build.rs`).
pub const BUILD_ID: u32 = match u32::from_str_radix(env!("STEPBRIDGE_BUILD_ID"), 16) {
    Ok(id) => id,
    Err(_) => 0,
};
