//! Transports: bytes ↔ PoStep60 commands for each bus (I2C, Modbus RTU, USB
//! HID). Know nothing of
//! hardware registers.

pub mod i2c;
pub mod modbus;
pub mod usb;
