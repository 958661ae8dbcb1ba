//! Motion: the trapezoidal profile generator ([`profile`]), the axis output
//! stage that turns its setpoints into chain commands ([`axis`]), homing
//! ([`homing`]) and the group of axes ticked together ([`group`]). Knows
//! nothing of bytes on any bus.

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
