//! stepctl: commission and drive a stepbridge box from a PC (issue 14).
//!
//! Layers: [`modbus`] and [`usb`] carry registers of the box's Modbus map
//! ([`bus::Bus`]); [`ops`] and [`settings`] know what the registers mean;
//! [`doctor`] judges a box for bring-up; [`app`] is every command; [`cli`] the command line. `main.rs` only opens
//! the transport, runs the command and maps errors to exit codes.

// Tests are not bus input: they may index, unwrap and panic.
#![cfg_attr(test, allow(clippy::indexing_slicing, clippy::arithmetic_side_effects))]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod app;
pub mod bus;
pub mod cli;
pub mod doctor;
pub mod error;
pub mod modbus;
pub mod ops;
pub mod plot;
pub mod settings;
pub mod usb;
