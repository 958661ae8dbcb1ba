//! The control-tick rate, a build-time setting.
//!
//! `STEPBRIDGE_TICK_HZ` in the environment of the build (e.g.
//! `STEPBRIDGE_TICK_HZ=5000 cargo fw`) sets the rate the firmware ticks the
//! bridge at; without it the rate is 1 kHz. The rate must divide 10⁶ (the
//! tick period is a whole number of µs) and lie in 500..=10 000 Hz; anything
//! else fails the build. Everything below the firmware takes the period as a
//! parameter (the motion tests run at 1, 2 and 5 kHz whatever this says).

/// Ticks per second (build setting `STEPBRIDGE_TICK_HZ`, default 1000).
pub const TICK_HZ: u32 = match option_env!("STEPBRIDGE_TICK_HZ") {
    Some(s) => parse(s),
    None => 1000,
};

/// The tick period, µs.
pub const TICK_US: u32 = 1_000_000 / TICK_HZ;

const _: () = assert!(
    TICK_HZ >= 500 && TICK_HZ <= 10_000 && 1_000_000 % TICK_HZ == 0,
    "STEPBRIDGE_TICK_HZ must divide 1 000 000 and lie in 500..=10000"
);

/// Decimal digits → u32 at compile time (anything else fails the build).
const fn parse(s: &str) -> u32 {
    let b = s.as_bytes();
    assert!(
        !b.is_empty() && b.len() <= 6,
        "STEPBRIDGE_TICK_HZ: 1 to 6 digits"
    );
    let mut i = 0;
    let mut v = 0u32;
    while i < b.len() {
        assert!(b[i].is_ascii_digit(), "STEPBRIDGE_TICK_HZ: digits only");
        v = v * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_period_is_a_whole_number_of_microseconds() {
        assert_eq!(TICK_US * TICK_HZ, 1_000_000);
    }

    #[test]
    fn digits_parse_as_decimal() {
        assert_eq!(parse("5000"), 5000);
        assert_eq!(parse("1000"), 1000);
    }
}
