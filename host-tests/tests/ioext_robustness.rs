//! The I/O extension's fuzz body (`host_tests::ioext_fuzz`, also the
//! `ioext_registers` fuzz target): a fixed corpus and random inputs.

use host_tests::ioext_fuzz as exercise;
use proptest::prelude::*;

#[test]
fn the_fuzz_body_holds_on_a_fixed_corpus() {
    let mut corpus: Vec<Vec<u8>> = vec![
        vec![],
        vec![0xFF; 64],
        // configure 256 bits auto-restart, enable, tick, complete, read rx.
        vec![6, 0x10, 0x00, 0x02, 0xFF, 1, 2, 0, 3, 0, 0x20, 0, 16],
        // write tx while disabled, enable via config op, write, tick twice.
        vec![
            1, 0x10, 0, 2, 0xAB, 0xCD, 6, 0, 0, 0, 7, 1, 1, 0x10, 0, 1, 1, 2, 2, 0, 2, 0, 3,
        ],
        // hold CS, change CPOL, fail, persist.
        vec![
            6, 0x10, 0x00, 0x04, 0x07, 1, 1, 0x10, 0, 1, 0, 1, 2, 0, 4, 6, 0x10, 0, 0x14, 7, 1, 7,
        ],
    ];
    let mut x = 0x1234_5678_u32;
    for len in 0..400 {
        let v: Vec<u8> = (0..len % 97 + len / 4)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                x as u8
            })
            .collect();
        corpus.push(v);
    }
    for input in &corpus {
        exercise::run(input);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn arbitrary_fuzz_inputs_never_panic(data in proptest::collection::vec(any::<u8>(), 0..300)) {
        exercise::run(&data);
    }
}
