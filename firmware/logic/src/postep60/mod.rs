//! PoStep60 device model per axis: settings, modes, faults, currents, step
//! modes, persistence image. Knows nothing of which bus a command came on.

pub mod analog;
pub mod command;
pub mod current;
pub mod device;
pub mod drv8711;
pub mod power_stage;
pub mod settings;

pub use current::Current;
pub use device::{CommandError, Device, DriverStatus, Effect, Inputs, Query, Request, Value};
pub use power_stage::PowerStage;
pub use settings::{AxisSettings, DriverMode, Settings};
