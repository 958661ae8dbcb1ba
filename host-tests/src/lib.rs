//! Simulated hardware for scenario tests: see `bridge_logic::sim` for the
//! powerSTEP01 model; this crate adds test harnesses around it.
