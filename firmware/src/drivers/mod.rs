//! One module per peripheral driver. Each owns its peripheral and pins,
//! moves bytes, and decides nothing about their meaning (that is the logic
//! crate's job). `unsafe` appears only here and in `failsafe`/`platform`,
//! each block with a `// SAFETY:` comment.
//!
//! The QEMU platform does not use every driver (QEMU models no I2C, ADC
//! calibration, flash controller, USB, unique id or ROM bootloader): all of
//! them are still built in both configurations, so a QEMU build checks that
//! they compile.

pub mod analog;
pub mod chain_spi;
pub mod clock;
pub mod dma;
pub mod flash;
pub mod i2c_slave;
pub mod ioext_spi;
pub mod iwdg;
pub mod mcu;
pub mod rs485;
pub mod usb;
