//! Harnesses around the simulated hardware of `stepbridge_sim`, shared by
//! the scenario tests in `tests/`, the plot and the benchmark binaries.

pub mod clock;
pub mod ext_fuzz;
pub mod i2c_bench;
pub mod ioext_fuzz;
pub mod ioext_wire;
pub mod modbus_bench;
pub mod rig;
pub mod rm0090;
pub mod rng;
pub mod sim_bridge;
pub mod svg;
pub mod usb_bench;
pub mod usb_manual;
