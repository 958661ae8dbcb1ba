//! PoStep60 device model per axis: settings, modes, faults, currents, step
//! modes, persistence image. Knows nothing of which bus a command came on.

pub mod analog;
pub mod board;
pub mod current;
pub mod device;
pub mod drv8711;
pub mod settings;

pub use board::Board;
pub use current::Current;
pub use device::{CommandError, Device, DriverStatus, Effect, Inputs, Query, Request, Value};
pub use settings::{AxisSettings, DriverMode, Settings};
