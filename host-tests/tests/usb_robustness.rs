//! Bad input on USB: random OUT reports (any length, any bytes, with and
//! without the manual's framing) never panic and never move a motor unless a
//! well-formed report carries a motion command.

use host_tests::usb_bench::{check_usb_stream, MOTION};
use proptest::prelude::*;

/// An op stream for `check_usb_stream`: mostly 64-byte reports with a
/// zero last byte and a known command (so the fuzzer's structure is
/// reached), some arbitrary ones.
fn stream() -> impl Strategy<Value = Vec<u8>> {
    let report = prop_oneof![
        // well formed, any command but the motion ones
        (any::<u8>(), proptest::collection::vec(any::<u8>(), 62)).prop_map(|(cmd, body)| {
            let cmd = if MOTION.contains(&cmd) { 0x88 } else { cmd };
            let mut r = vec![0u8, 64, 0, cmd];
            r.extend_from_slice(&body[..61]);
            r.push(0);
            r
        }),
        // anything
        proptest::collection::vec(any::<u8>(), 0..80).prop_map(|b| {
            let mut r = vec![0u8, b.len() as u8];
            r.extend(b);
            r
        }),
        (1u8..30).prop_map(|ms| vec![1, ms]),
    ];
    proptest::collection::vec(report, 1..30).prop_map(|ops| ops.concat())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, ..ProptestConfig::default() })]

    #[test]
    fn random_reports_never_panic_and_move_nothing_without_a_motion_command(data in stream()) {
        check_usb_stream(&data);
    }
}

#[test]
fn every_command_byte_with_random_data_never_panics() {
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    for cmd in 0..=255u8 {
        for _ in 0..8 {
            let mut r = vec![0u8, 64, 0, cmd];
            for _ in 0..61 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                r.push(x as u8);
            }
            r.push(0);
            r.extend_from_slice(&[1, 25]);
            check_usb_stream(&r);
        }
    }
}
