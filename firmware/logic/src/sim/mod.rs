//! Byte-accurate powerSTEP01 simulator (feature `sim`). Filled in by the
//! simulator work; see `device.rs` and `chain.rs`.
