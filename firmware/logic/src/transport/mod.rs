//! Transports: bytes ↔ PoStep60 commands for each bus. Know nothing of
//! hardware registers.

pub mod i2c;
pub mod modbus;
