//! Bad input on the I2C bus: random transactions never panic and never move
//! a motor unless they contain a valid motion command.

use bridge_logic::postep60::Settings;
use host_tests::i2c_bench::I2cBench;
use proptest::prelude::*;

/// Command bytes that may legitimately start motion or change what moves:
/// Set position, Set requested speed, Set driver mode (auto run), invert,
/// soft stop (changes the target), set zero, select axis, extension
/// writes (homing).
const MOTION: [u8; 8] = [0x50, 0x54, 0x05, 0x55, 0x71, 0x5E, 0x70, 0x73];

#[derive(Clone, Debug)]
enum Op {
    Write(u8, Vec<u8>),
    Read(u8, usize),
    BusError,
    Tick(u8),
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        (0u8..4, proptest::collection::vec(any::<u8>(), 0..24)).prop_map(|(a, b)| Op::Write(a, b)),
        (0u8..4, 0usize..12).prop_map(|(a, n)| Op::Read(a, n)),
        Just(Op::BusError),
        (1u8..20).prop_map(Op::Tick),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, ..ProptestConfig::default() })]

    #[test]
    fn random_transactions_never_panic_and_move_nothing_without_a_motion_command(
        ops in proptest::collection::vec(op(), 1..40)
    ) {
        let mut b = I2cBench::new(2, Settings::FACTORY);
        let mut motion = false;
        for op in ops {
            match op {
                Op::Write(addr, bytes) => {
                    if bytes.first().is_some_and(|c| MOTION.contains(c)) {
                        motion = true;
                    }
                    // 0x04 may move the addresses: keep talking to whatever answers.
                    let (a0, _) = b.bridge.i2c_addresses();
                    b.write(a0.wrapping_add(addr % 2), &bytes);
                    b.write(addr, &bytes);
                }
                Op::Read(addr, n) => {
                    let _ = b.read(addr, n);
                }
                Op::BusError => b.slave.on_bus_error(),
                Op::Tick(ms) => b.run(u64::from(ms)),
            }
        }
        b.run(50);
        if !motion {
            for k in 0..2 {
                prop_assert_eq!(b.chip(k).abs_pos(), 0, "chip {} moved", k);
            }
        }
    }
}
