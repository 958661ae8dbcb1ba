//! Motion: the trapezoidal profile generator ([`profile`]), the axis output
//! stage that turns its setpoints into chain commands ([`axis`]), homing
//! ([`homing`]), the group of axes ticked together ([`group`]), the
//! shared profile of a coordinated straight-line move ([`coord`]) and the
//! move running through the group's axes ([`coordinated`]). Knows nothing
//! of bytes on any bus.

pub mod axis;
pub mod coord;
pub mod coordinated;
pub mod divisor;
pub mod group;
pub mod homing;
pub mod profile;
pub mod units;

pub use axis::{Axis, AxisConfig, AxisFault, AxisState, ChipImage};
pub use coordinated::{AbortReason, CoordRun, CoordState, StartError};
pub use group::{AxisGroup, TickReport};
pub use homing::{HomingError, HomingParams, HomingState};
pub use profile::{Limits, Mode, Profile};
