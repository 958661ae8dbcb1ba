//! Bad input on the RS-485 line: arbitrary bytes at arbitrary times never
//! panic, only intact frames for our ids (or broadcast) execute requests —
//! and only the request their command address names —, only intact unicast
//! frames for our ids are answered, and no motor moves without a motion
//! request. The same check runs under cargo-fuzz (`fuzz/`, target
//! `modbus_stream`); see `host_tests::modbus_bench::check_stream`.

use host_tests::modbus_bench::{adu, check_stream};
use proptest::prelude::*;

/// One character at 9600 baud, µs.
const CHAR: u64 = 1146;

/// Command addresses worth hitting: all of 9.3 plus neighbours.
const COMMANDS: [u8; 20] = [
    0x01, 0x03, 0x04, 0x05, 0x06, 0x0A, 0x14, 0x20, 0x30, 0x33, 0x35, 0x3F, 0x40, 0x50, 0x51, 0x54,
    0x55, 0x5E, 0x5F, 0x60,
];

#[derive(Clone, Debug)]
enum Chunk {
    /// A frame with a right CRC (maybe corrupted afterwards), bytes back to
    /// back, then `silence` µs.
    Frame {
        body: Vec<u8>,
        corrupt: Option<(usize, u8)>,
        silence: u64,
    },
    /// Noise: bytes with arbitrary spacing.
    Noise(Vec<(u8, u64)>),
}

fn frame_body() -> impl Strategy<Value = Vec<u8>> {
    let id = prop_oneof![Just(0u8), Just(1), Just(2), Just(3), Just(248), any::<u8>()];
    let fc = prop_oneof![Just(0x03u8), Just(0x06), Just(0x10), any::<u8>()];
    let hi = prop_oneof![4 => Just(0u8), 1 => any::<u8>()];
    let cmd = prop_oneof![proptest::sample::select(COMMANDS.to_vec()), any::<u8>()];
    let regs = proptest::collection::vec(any::<u16>(), 0..4);
    (id, fc, hi, cmd, regs, any::<bool>()).prop_map(|(id, fc, hi, cmd, regs, honest)| {
        let mut b = vec![id, fc, hi, cmd];
        match fc {
            0x03 => b.extend_from_slice(&[0, regs.len() as u8]),
            0x06 => b.extend_from_slice(&regs.first().copied().unwrap_or(0).to_be_bytes()),
            0x10 => {
                let n = regs.len() as u8;
                b.extend_from_slice(&[0, n, if honest { 2 * n } else { n }]);
                for r in &regs {
                    b.extend_from_slice(&r.to_be_bytes());
                }
            }
            _ => b.extend(regs.iter().flat_map(|r| r.to_be_bytes())),
        }
        b
    })
}

/// Set position (FC 0x10, 2 registers) or Stop for id 0, 1 or 2.
fn motion_body() -> impl Strategy<Value = Vec<u8>> {
    (0u8..3, -5000i32..5000, any::<bool>()).prop_map(|(id, pos, stop)| {
        if stop {
            vec![id, 0x06, 0x00, 0x5F, 0, 0]
        } else {
            let [a, b, c, d] = pos.to_be_bytes();
            vec![id, 0x10, 0x00, 0x50, 0, 2, 4, a, b, c, d]
        }
    })
}

fn chunk() -> impl Strategy<Value = Chunk> {
    prop_oneof![
        3 => (
            prop_oneof![3 => frame_body(), 1 => motion_body()],
            proptest::option::weighted(0.2, (0usize..16, 1u8..=255)),
            prop_oneof![Just(4100u64), 0u64..6000, Just(300_000)],
        )
            .prop_map(|(body, corrupt, silence)| Chunk::Frame { body, corrupt, silence }),
        1 => proptest::collection::vec((any::<u8>(), 0u64..6000), 0..12).prop_map(Chunk::Noise),
    ]
}

fn records(chunks: &[Chunk]) -> Vec<(u8, u64)> {
    let mut out = Vec::new();
    let mut pending = 0u64;
    for c in chunks {
        match c {
            Chunk::Frame {
                body,
                corrupt,
                silence,
            } => {
                let mut f = adu(body);
                if let Some((i, x)) = corrupt {
                    let n = f.len();
                    f[i % n] ^= x;
                }
                for (k, b) in f.iter().enumerate() {
                    let dt = if k == 0 { pending + CHAR } else { CHAR };
                    out.push((*b, dt));
                }
                pending = *silence;
            }
            Chunk::Noise(bytes) => {
                for (k, (b, dt)) in bytes.iter().enumerate() {
                    out.push((*b, if k == 0 { pending + dt } else { *dt }));
                }
                pending = 4100;
            }
        }
    }
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn frames_and_noise_never_panic_and_only_intact_frames_act(
        chunks in proptest::collection::vec(chunk(), 1..24)
    ) {
        check_stream(&records(&chunks), false);
    }

    #[test]
    fn arbitrary_timed_bytes_with_fixed_up_crcs_only_act_through_intact_frames(
        recs in proptest::collection::vec((any::<u8>(), prop_oneof![0u64..6000, Just(4011), Just(2865), Just(2866)]), 0..200)
    ) {
        check_stream(&recs, true);
    }
}

#[test]
fn the_stream_check_sees_requests_and_motion() {
    // Set position 1000 on id 1, then nothing: the check accepts the motion.
    let f = adu(&[1, 0x10, 0x00, 0x50, 0, 2, 4, 0, 0, 0x03, 0xE8]);
    let recs: Vec<(u8, u64)> = f.iter().map(|b| (*b, CHAR)).collect();
    let r = check_stream(&recs, false);
    assert_eq!((r.intact_frames, r.requests, r.responses), (1, 1, 1));
    assert!(r.moved);
}

#[test]
fn a_motion_frame_broken_by_a_gap_does_nothing() {
    let f = adu(&[1, 0x10, 0x00, 0x50, 0, 2, 4, 0, 0, 0x03, 0xE8]);
    let mut recs: Vec<(u8, u64)> = f.iter().map(|b| (*b, CHAR)).collect();
    recs[5].1 = 2866; // one µs over a character + t1.5
    let r = check_stream(&recs, false);
    assert_eq!((r.intact_frames, r.requests, r.responses), (0, 0, 0));
    assert!(!r.moved);
}
