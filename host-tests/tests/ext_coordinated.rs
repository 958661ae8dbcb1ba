//! Extension 0x08nn over Modbus RTU: a coordinated move described, started,
//! watched and stopped by a master, and the single-axis commands its
//! members refuse while it runs.

use bridge_logic::postep60::Settings;
use host_tests::modbus_bench::ModbusBench;

const CMD: u16 = 0x0800;
const ABORT: u16 = 0x0801;
const MEMBERS: u16 = 0x0802;
const REFUSAL: u16 = 0x0803;
const PATH: u16 = 0x0804;
const TICKS: u16 = 0x080A;
const QUEUE_FREE: u16 = 0x080C;
const PASSED: u16 = 0x080D;
const TARGETS: u16 = 0x0810;
const QUEUE: u16 = 0x080E;
const WAYPOINT: u16 = 0x0820;

const DONE: u16 = 5;
const ABORTED: u16 = 6;
/// Modbus exceptions.
const ILLEGAL_ADDRESS: u8 = 0x02;
const SERVER_FAILURE: u8 = 0x04;

/// Three axes in 1/16 (the factory step mode) at 2 000 steps/s, 20 000
/// steps/s².
fn bench() -> ModbusBench {
    let mut s = Settings::FACTORY;
    for a in s.axes.iter_mut() {
        a.max_speed = 2_000;
        a.acc = 20_000;
        a.dec = 20_000;
    }
    ModbusBench::new(3, s)
}

fn words(v: i32) -> [u16; 2] {
    let v = v as u32;
    [(v >> 16) as u16, v as u16]
}

/// Members `mask`, no path limit, targets of axes 0..3.
fn describe(b: &mut ModbusBench, mask: u16, targets: [i32; 3]) {
    b.write_multiple(1, MEMBERS, &[mask]).unwrap();
    b.write_multiple(1, PATH, &[0; 6]).unwrap();
    let regs: Vec<u16> = targets.iter().flat_map(|t| words(*t)).collect();
    b.write_multiple(1, TARGETS, &regs).unwrap();
}

fn state(b: &mut ModbusBench) -> u16 {
    b.read(1, CMD, 1).unwrap()[0]
}

/// Poll the state every 10 ms until it is `want` (panics after `cap_ms`).
fn wait_for(b: &mut ModbusBench, want: u16, cap_ms: u64) {
    for _ in 0..cap_ms / 10 {
        if state(b) == want {
            return;
        }
        b.run(10);
    }
    panic!("state {} after {cap_ms} ms, not {want}", state(b));
}

#[test]
fn a_move_written_over_modbus_arrives_on_every_member() {
    let mut b = bench();
    describe(&mut b, 0b111, [3000, -1500, 10]);
    assert_eq!(
        b.read(1, TARGETS, 6).unwrap(),
        [0, 3000, 0xFFFF, 0xFA24, 0, 10]
    );
    b.write(1, CMD, 1).unwrap();
    wait_for(&mut b, DONE, 5_000);
    assert_eq!(
        (b.position(1), b.position(2), b.position(3)),
        (3000, -1500, 10)
    );
    assert_eq!(b.read(1, ABORT, 1).unwrap(), [0]);
    let ticks = b.read(1, TICKS, 2).unwrap();
    assert!(ticks[1] > 1000, "the line ran {ticks:?} ticks");
}

#[test]
fn a_member_refuses_a_move_of_its_own_while_the_group_runs_and_says_why() {
    let mut b = bench();
    describe(&mut b, 0b011, [3000, 3000, 0]);
    b.write(1, CMD, 1).unwrap();
    b.run(20);
    assert_eq!(b.set_position(2, 0), Err(SERVER_FAILURE));
    // Diagnostics 0x0349: axis 1 · 256 + 14 (in a coordinated move).
    assert_eq!(b.read(1, 0x0349, 1).unwrap(), [0x010E]);
    // Not a member: moves as usual.
    assert_eq!(b.set_position(3, 50), Ok(()));
    wait_for(&mut b, DONE, 5_000);
    assert_eq!(b.position(2), 3000);
    assert_eq!(b.set_position(2, 0), Ok(()));
}

#[test]
fn the_group_stop_brakes_every_member_and_reports_it() {
    let mut b = bench();
    describe(&mut b, 0b111, [6000, 3000, -6000]);
    b.write(1, CMD, 1).unwrap();
    b.run(300);
    b.write(1, CMD, 0).unwrap();
    wait_for(&mut b, ABORTED, 2_000);
    assert_eq!(b.read(1, ABORT, 1).unwrap(), [0xFF01]);
    let p = [b.position(1), b.position(2), b.position(3)];
    assert!(p[0] > 0 && p[0] < 6000, "{p:?}");
    // On the line: axis 1 half of axis 0, axis 2 its mirror (±1 step).
    assert!(
        (p[1] * 2 - p[0]).abs() <= 2 && (p[2] + p[0]).abs() <= 1,
        "{p:?}"
    );
    b.run(200);
    assert_eq!([b.position(1), b.position(2), b.position(3)], p, "rests");
}

#[test]
fn a_soft_stop_of_one_member_stops_the_whole_group() {
    let mut b = bench();
    describe(&mut b, 0b111, [6000, 3000, -6000]);
    b.write(1, CMD, 1).unwrap();
    b.run(300);
    // A soft stop of axis 2 (I2C's extension 0x71 and the watchdog's
    // soft stop reach the axis as this request).
    b.bridge
        .request(2, bridge_logic::postep60::Request::SoftStop)
        .unwrap();
    wait_for(&mut b, ABORTED, 2_000);
    assert_eq!(b.read(1, ABORT, 1).unwrap(), [0x0201]);
}

#[test]
fn a_stop_of_one_member_stops_every_member_at_once() {
    let mut b = bench();
    describe(&mut b, 0b111, [6000, 3000, -6000]);
    b.write(1, CMD, 1).unwrap();
    b.run(300);
    // 0x5F Stop to axis 1 (id 2): taken, not refused.
    b.write(2, 0x5F, 1).unwrap();
    wait_for(&mut b, ABORTED, 2_000);
    assert_eq!(b.read(1, ABORT, 1).unwrap(), [0x0102]);
}

#[test]
fn a_start_is_refused_while_a_move_runs_or_a_member_is_not_ready() {
    let mut b = bench();
    describe(&mut b, 0b011, [3000, 3000, 0]);
    b.write(1, CMD, 1).unwrap();
    b.run(20);
    assert_eq!(b.write(1, CMD, 1), Err(SERVER_FAILURE));
    assert_eq!(b.read(1, REFUSAL, 1).unwrap(), [1]);
    // The description is fixed while the move is under way.
    assert_eq!(b.write_multiple(1, MEMBERS, &[1]), Err(SERVER_FAILURE));
    wait_for(&mut b, DONE, 5_000);
    // Axis 2 asleep (0x03 0x0F): not ready.
    b.write(3, 0x03, 0x0F).unwrap();
    b.run(20);
    describe(&mut b, 0b111, [0, 0, 100]);
    assert_eq!(b.write(1, CMD, 1), Err(SERVER_FAILURE));
    assert_eq!(b.read(1, REFUSAL, 1).unwrap(), [0x0203]);
    // A member past the chain.
    b.write_multiple(1, MEMBERS, &[0b1001]).unwrap();
    assert_eq!(b.write(1, CMD, 1), Err(SERVER_FAILURE));
    assert_eq!(b.read(1, REFUSAL, 1).unwrap(), [2]);
}

#[test]
fn half_a_32_bit_value_and_the_read_only_words_are_illegal_addresses() {
    let mut b = bench();
    assert_eq!(b.write(1, TARGETS + 1, 5), Err(ILLEGAL_ADDRESS));
    assert_eq!(b.write_multiple(1, TARGETS, &[5]), Err(ILLEGAL_ADDRESS));
    assert_eq!(b.write(1, ABORT, 0), Err(ILLEGAL_ADDRESS));
    assert_eq!(b.write(1, TICKS, 0), Err(ILLEGAL_ADDRESS));
    assert_eq!(b.write_multiple(1, CMD, &[1, 0]), Err(ILLEGAL_ADDRESS));
    assert_eq!(b.read(1, 0x0830, 1), Err(ILLEGAL_ADDRESS));
    assert_eq!(b.write(1, QUEUE_FREE, 0), Err(ILLEGAL_ADDRESS));
    assert_eq!(b.write(1, PASSED, 0), Err(ILLEGAL_ADDRESS));
    assert_eq!(b.write(1, CMD, 2), Err(0x03));
}

/// The same block over I2C (0x73 writes, 0x72 reads: address and words
/// MSB first, the read's first byte its status).
#[test]
fn i2c_0x73_starts_a_coordinated_move_and_0x72_reads_its_state() {
    use host_tests::i2c_bench::I2cBench;
    let mut b = I2cBench::new(2, Settings::FACTORY);
    assert!(b.write(1, &[0x73, 0x08, 0x02, 0x00, 0x03]));
    assert_eq!(b.read(1, 1).unwrap(), [0], "members written");
    // Targets 400 and −200 (i32, high word first; I2C carries at most
    // three registers a write: one target each).
    assert!(b.write(1, &[0x73, 0x08, 0x10, 0, 0, 0x01, 0x90]));
    assert_eq!(b.read(1, 1).unwrap(), [0]);
    assert!(b.write(1, &[0x73, 0x08, 0x12, 0xFF, 0xFF, 0xFF, 0x38]));
    assert_eq!(b.read(1, 1).unwrap(), [0]);
    assert!(b.write(1, &[0x73, 0x08, 0x00, 0x00, 0x01]));
    assert_eq!(b.read(1, 1).unwrap(), [0], "started");
    b.run(3000);
    assert!(b.write(1, &[0x72, 0x08, 0x00, 1]));
    assert_eq!(b.read(1, 3).unwrap(), [0, 0, DONE as u8]);
    assert_eq!(b.bridge.axis(0).unwrap().actual_position(), 400);
    assert_eq!(b.bridge.axis(1).unwrap().actual_position(), -200);
}

/// And over USB (0xE1 writes, 0xE0 reads; `InDATA[14]` the outcome).
#[test]
fn usb_0xe1_starts_a_coordinated_move_and_0xe0_reads_its_state() {
    use host_tests::i2c_bench::I2cBench;
    let mut b = I2cBench::new(2, Settings::FACTORY);
    let write = |b: &mut I2cBench, address: u16, words: &[u16]| -> u8 {
        let mut w = [0u8; 64];
        w[1] = 0xE1;
        w[20..22].copy_from_slice(&address.to_be_bytes());
        w[22] = words.len() as u8;
        for (i, v) in words.iter().enumerate() {
            w[24 + 2 * i..26 + 2 * i].copy_from_slice(&v.to_be_bytes());
        }
        let now = b.clock.now_ms();
        b.bridge.on_usb_report(&w, now);
        let r = *b.bridge.usb_next(now).expect("a response");
        b.bridge.usb_sent();
        r.0[14]
    };
    assert_eq!(write(&mut b, MEMBERS, &[0b11]), 0);
    assert_eq!(write(&mut b, TARGETS, &[0, 100, 0, 300]), 0);
    assert_eq!(write(&mut b, CMD, &[1]), 0);
    // Refused while the move runs: 12 (the extension's refusal).
    assert_eq!(write(&mut b, MEMBERS, &[0b01]), 12);
    b.run(3000);
    let mut rd = [0u8; 64];
    rd[1] = 0xE0;
    rd[20..22].copy_from_slice(&CMD.to_be_bytes());
    rd[22] = 1;
    let now = b.clock.now_ms();
    b.bridge.on_usb_report(&rd, now);
    let r = *b.bridge.usb_next(now).expect("a response");
    b.bridge.usb_sent();
    assert_eq!((r.0[14], &r.0[16..18]), (0, &[0, DONE as u8][..]));
    assert_eq!(b.bridge.axis(1).unwrap().actual_position(), 300);
}

#[test]
fn a_stop_of_a_member_with_no_distance_to_go_stops_the_group() {
    let mut b = bench();
    describe(&mut b, 0b111, [6000, 3000, 0]);
    b.write(1, CMD, 1).unwrap();
    b.run(300);
    // Axis 2 rests through the move; its Stop is the group's all the same.
    b.write(3, 0x5F, 1).unwrap();
    wait_for(&mut b, ABORTED, 2_000);
    assert_eq!(b.read(1, ABORT, 1).unwrap(), [0x0202]);
    let p = b.position(1);
    assert!(p > 0 && p < 6000, "axis 0 stopped on the way: {p}");
}

/// One FC 0x10 write of a waypoint for members 0..3.
fn waypoint(b: &mut ModbusBench, p: [i32; 3]) -> Result<(), u8> {
    let regs: Vec<u16> = p.iter().flat_map(|t| words(*t)).collect();
    b.write_multiple(1, WAYPOINT, &regs)
}

#[test]
fn a_path_written_over_modbus_runs_through_its_waypoints_and_stops_on_the_last() {
    let mut b = bench();
    describe(&mut b, 0b111, [1000, 500, -200]);
    b.write(1, CMD, 1).unwrap();
    assert_eq!(b.read(1, QUEUE_FREE, 1).unwrap(), [16]);
    let path = [[2000, 500, -400], [2000, 1500, -600], [1000, 1500, -800]];
    for (i, p) in path.iter().enumerate() {
        waypoint(&mut b, *p).unwrap();
        assert_eq!(b.read(1, QUEUE_FREE, 1).unwrap(), [15 - i as u16]);
    }
    // The last waypoint reads back (the path's end).
    assert_eq!(
        b.read(1, WAYPOINT, 6).unwrap(),
        [0, 1000, 0, 1500, 0xFFFF, 0xFCE0]
    );
    wait_for(&mut b, DONE, 10_000);
    assert_eq!(
        (b.position(1), b.position(2), b.position(3)),
        (1000, 1500, -800)
    );
    assert_eq!(b.read(1, PASSED, 1).unwrap(), [3]);
    assert_eq!(b.read(1, ABORT, 1).unwrap(), [0]);
    assert_eq!(b.read(1, QUEUE_FREE, 1).unwrap(), [0], "no move runs");
}

#[test]
fn a_waypoint_is_refused_with_its_reason_when_it_cannot_be_queued() {
    let mut b = bench();
    // No move runs: 6.
    assert_eq!(waypoint(&mut b, [1, 2, 3]), Err(SERVER_FAILURE));
    assert_eq!(b.read(1, REFUSAL, 1).unwrap(), [6]);
    describe(&mut b, 0b011, [4000, 4000, 0]);
    b.write(1, CMD, 1).unwrap();
    // Half of a pair.
    assert_eq!(
        b.write_multiple(1, WAYPOINT, &[0, 1, 0]),
        Err(ILLEGAL_ADDRESS)
    );
    // A write that misses a member's pair is kept, not queued; 1 to 0x0E
    // queues what was written.
    assert_eq!(b.write_multiple(1, WAYPOINT + 2, &[0, 4100]), Ok(()));
    assert_eq!(b.write_multiple(1, WAYPOINT, &[0, 4100]), Ok(()));
    assert_eq!(b.read(1, QUEUE_FREE, 1).unwrap(), [16]);
    assert_eq!(b.write(1, QUEUE, 1), Ok(()));
    assert_eq!(b.read(1, QUEUE_FREE, 1).unwrap(), [15]);
    for k in 1..16 {
        let v = 4100 + 10 * k;
        assert_eq!(
            b.write_multiple(1, WAYPOINT, &[0, v, 0, v]),
            Ok(()),
            "waypoint {k}"
        );
    }
    assert_eq!(b.read(1, QUEUE_FREE, 1).unwrap(), [0]);
    assert_eq!(
        b.write_multiple(1, WAYPOINT, &[0, 9000, 0, 9000]),
        Err(SERVER_FAILURE)
    );
    assert_eq!(b.read(1, REFUSAL, 1).unwrap(), [5], "the queue is full");
    wait_for(&mut b, DONE, 20_000);
    assert_eq!((b.position(1), b.position(2)), (4250, 4250));
}

#[test]
fn a_member_with_no_distance_to_go_at_the_start_moves_in_a_later_segment() {
    let mut b = bench();
    describe(&mut b, 0b111, [3000, 3000, 0]);
    b.write(1, CMD, 1).unwrap();
    assert_eq!(waypoint(&mut b, [3000, 3500, 400]), Ok(()));
    wait_for(&mut b, DONE, 10_000);
    assert_eq!(
        (b.position(1), b.position(2), b.position(3)),
        (3000, 3500, 400)
    );
}

#[test]
fn a_stop_during_a_path_brakes_along_it_and_the_group_rests() {
    let mut b = bench();
    describe(&mut b, 0b111, [3000, 10, 10]);
    b.write(1, CMD, 1).unwrap();
    waypoint(&mut b, [3000, 3000, 20]).unwrap();
    waypoint(&mut b, [0, 3000, 30]).unwrap();
    b.run(2_000);
    b.write(1, CMD, 0).unwrap();
    wait_for(&mut b, ABORTED, 3_000);
    assert_eq!(b.read(1, ABORT, 1).unwrap(), [0xFF01]);
    let p = [b.position(1), b.position(2), b.position(3)];
    // On the path: one of its three segments (±1 step).
    let on = |a: [i32; 3], d: [i32; 3]| -> bool {
        let k = if d[0] != 0 { 0 } else { 1 };
        let f = f64::from(p[k] - a[k]) / f64::from(d[k]);
        (0.0..=1.0).contains(&f)
            && (0..3)
                .all(|i| (f64::from(a[i]) + f * f64::from(d[i]) - f64::from(p[i])).abs() <= 1.5)
    };
    assert!(
        on([0, 0, 0], [3000, 10, 10])
            || on([3000, 10, 10], [0, 2990, 10])
            || on([3000, 3000, 20], [-3000, 0, 10]),
        "stopped off the path: {p:?}"
    );
    b.run(300);
    assert_eq!([b.position(1), b.position(2), b.position(3)], p, "rests");
}

#[test]
fn a_broadcast_start_starts_the_move_once_and_records_no_refusal() {
    let mut b = bench();
    describe(&mut b, 0b011, [2000, 2000, 0]);
    let req = host_tests::modbus_bench::adu(&[0, 0x06, 0x08, 0x00, 0, 1]);
    assert_eq!(b.transact(&req), None, "a broadcast is never answered");
    b.run(20);
    assert_eq!(b.read(1, REFUSAL, 1).unwrap(), [0]);
    wait_for(&mut b, DONE, 5_000);
    assert_eq!((b.position(1), b.position(2)), (2000, 2000));
}

/// Over I2C a write carries three registers: the waypoint's pairs one by
/// one, then 1 to 0x080E queues it.
#[test]
fn i2c_writes_a_waypoint_pair_by_pair_and_queues_it() {
    use host_tests::i2c_bench::I2cBench;
    let mut b = I2cBench::new(2, Settings::FACTORY);
    assert!(b.write(1, &[0x73, 0x08, 0x02, 0x00, 0x03]));
    assert!(b.write(1, &[0x73, 0x08, 0x10, 0, 0, 0x01, 0x90]));
    assert!(b.write(1, &[0x73, 0x08, 0x12, 0, 0, 0x00, 0xC8]));
    assert!(b.write(1, &[0x73, 0x08, 0x00, 0x00, 0x01]));
    assert_eq!(b.read(1, 1).unwrap(), [0], "started");
    // Waypoint (800, −100): axis 0's pair, axis 1's pair, then queue.
    assert!(b.write(1, &[0x73, 0x08, 0x20, 0, 0, 0x03, 0x20]));
    assert_eq!(b.read(1, 1).unwrap(), [0]);
    assert!(b.write(1, &[0x73, 0x08, 0x22, 0xFF, 0xFF, 0xFF, 0x9C]));
    assert_eq!(b.read(1, 1).unwrap(), [0]);
    assert!(b.write(1, &[0x73, 0x08, 0x0E, 0x00, 0x01]));
    assert_eq!(b.read(1, 1).unwrap(), [0], "queued");
    b.run(4000);
    assert!(b.write(1, &[0x72, 0x08, 0x00, 1]));
    assert_eq!(b.read(1, 3).unwrap(), [0, 0, DONE as u8]);
    assert_eq!(b.bridge.axis(0).unwrap().actual_position(), 800);
    assert_eq!(b.bridge.axis(1).unwrap().actual_position(), -100);
}
