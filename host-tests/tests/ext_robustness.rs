//! Random extension-space traffic never panics, never sends a chip a
//! command it refuses, and never moves a motor without a homing start
//! (`host_tests::ext_fuzz`, also the `ext_space` fuzz target's body).

use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn random_extension_traffic_is_harmless(data in proptest::collection::vec(any::<u8>(), 0..400)) {
        host_tests::ext_fuzz::check_ext_stream(&data);
    }
}

#[test]
fn a_write_of_every_chip_register_at_rest_is_never_refused_by_the_chip() {
    // 0x0101..=0x011B, every value pattern a register can take.
    let mut data = Vec::new();
    for reg in 1u8..=0x1B {
        for v in [0u16, 1, 0x7F, 0xFFFF] {
            data.extend_from_slice(&[1, 0, reg, 1]);
            data.extend_from_slice(&v.to_be_bytes());
            data.extend_from_slice(&[3, 5, 0]);
        }
    }
    assert!(host_tests::ext_fuzz::check_ext_stream(&data) > 100);
}
