//! Motion: the trapezoidal profile generator and (later in this layer) the
//! axis output stage that turns setpoints into chain commands. Knows nothing
//! of bytes on any bus.

pub mod axis;
pub mod divisor;
pub mod group;
pub mod homing;
pub mod profile;
pub mod units;

pub use axis::{Axis, AxisConfig, AxisFault, AxisState, ChipImage};
pub use group::{AxisGroup, TickReport};
pub use homing::{HomingError, HomingParams, HomingState};
pub use profile::{Limits, Mode, Profile};
