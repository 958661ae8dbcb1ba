//! PoStep60 device model per axis: settings, modes, faults, currents, step
//! modes, persistence image. Knows nothing of which bus a command came on.

pub mod analog;
