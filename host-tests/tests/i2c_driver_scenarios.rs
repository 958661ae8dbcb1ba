//! Every PoStep60 I2C transaction type on the wire: a simulated I2C master
//! drives the firmware's I2C1 driver (`drivers_core::i2c_slave`) on the
//! RM0090 I2C model, the PoStep60 framing and the bridge on simulated chips
//! — the whole path the board runs from SDA to the motors. Each transaction
//! is checked against the same transaction on the protocol-only bench
//! (`I2cBench`, which `tests/i2c_commands.rs` checks byte by byte against
//! the manual), so what the wire adds is exactly nothing: same bytes back,
//! same motion.

use bridge_logic::bridge::Bridge;
use bridge_logic::postep60::{PowerStage, Settings};
use host_tests::clock::SimClock;
use host_tests::i2c_bench::{le_i32, I2cBench};
use host_tests::rm0090::i2c_rig::I2cRig;
use host_tests::sim_bridge::{new_bridge, TICK_US};
use stepbridge_sim::SimChain;

const A0: u8 = 1; // factory address of axis 0 (OAR1)
const A1: u8 = 2; // axis 1 (OAR2)

/// The bridge behind the driver and the model, on the virtual clock.
struct WireBench {
    rig: I2cRig<Bridge<SimChain>>,
    clock: SimClock,
}

impl WireBench {
    fn new(latency: usize) -> WireBench {
        let bridge = new_bridge(2, Settings::FACTORY, PowerStage::REFERENCE);
        let (p, s) = bridge.i2c_addresses();
        let mut rig = I2cRig::new(bridge, p, s);
        rig.latency = latency;
        let mut b = WireBench {
            rig,
            clock: SimClock::new(TICK_US),
        };
        b.run(20);
        b
    }

    fn run(&mut self, ms: u64) {
        self.clock
            .run(&mut self.rig.target, ms * 1000 / u64::from(TICK_US));
    }

    fn write(&mut self, addr: u8, bytes: &[u8]) -> bool {
        self.rig.write(addr, bytes).iter().all(|&a| a)
    }

    /// Write the command, STOP, then read `n` bytes.
    fn query(&mut self, addr: u8, cmd: u8, n: usize) -> Vec<u8> {
        assert!(self.write(addr, &[cmd]), "address {addr} not ACKed");
        self.rig.read(addr, n).expect("read ACKed")
    }

    /// Every query of [`QUERIES`] at `addr` answers what the protocol
    /// bench answers (`when` names the moment in a failure).
    fn queries_match(&mut self, proto: &mut I2cBench, addr: u8, when: &str) {
        for (cmd, n) in QUERIES {
            assert_eq!(
                self.query(addr, cmd, n),
                proto.query(addr, cmd, n),
                "0x{cmd:02X} {when}"
            );
        }
    }

    fn clean(&self) {
        let m = self.rig.model();
        assert_eq!(m.violations(), &[], "{}", m.trace());
        assert!(!m.event_irq() && !m.error_irq(), "{m:?}");
    }
}

fn reference() -> I2cBench {
    I2cBench::new(2, Settings::FACTORY)
}

/// Every read command of manual §8.3 with the length it returns.
const QUERIES: [(u8, usize); 20] = [
    (0x0A, 5),
    (0x10, 2),
    (0x11, 2),
    (0x12, 1),
    (0x13, 1),
    (0x14, 1),
    (0x20, 2),
    (0x21, 2),
    (0x22, 2),
    (0x23, 1),
    (0x24, 1),
    (0x25, 1),
    (0x40, 4),
    (0x41, 2),
    (0x42, 2),
    (0x43, 2),
    (0x44, 2),
    (0x45, 2),
    (0x46, 1),
    (0x70, 2),
];

/// Write commands of manual §8.3 and the extensions, with data (no 0x04,
/// 0x3F, 0x60: address change, flash save and reset have their own tests).
const WRITES: [&[u8]; 21] = [
    &[0x01, 0xDE, 0xAD, 0xBE, 0xEF],
    &[0x03, 1],
    &[0x05, 4],
    &[0x06, 0, 0, 0, 0, 0, 0],
    &[0x30, 20, 10],
    &[0x31, 10, 5],
    &[0x32, 15, 7],
    &[0x33, 5],
    &[0x34, 80],
    &[0x35],
    &[0x50, 0x10, 0x27, 0, 0],
    &[0x51, 0xE8, 0x03],
    &[0x52, 0xD0, 0x07],
    &[0x53, 0xD0, 0x07],
    &[0x54, 0x64, 0x00],
    &[0x55, 1],
    &[0x5E],
    &[0x5F],
    &[0x70, 1],
    &[0x71],
    &[0x72, 0x03, 0x40, 2],
];

#[test]
fn every_query_returns_the_protocol_benchs_bytes_at_both_addresses() {
    let (mut wire, mut proto) = (WireBench::new(0), reference());
    for addr in [A0, A1] {
        wire.queries_match(&mut proto, addr, &format!("at {addr}"));
    }
    wire.clean();
}

#[test]
fn every_write_then_its_read_back_matches_the_protocol_bench() {
    let (mut wire, mut proto) = (WireBench::new(0), reference());
    for bytes in WRITES {
        assert!(wire.write(A0, bytes), "{bytes:02X?}");
        assert!(proto.write(A0, bytes));
        wire.run(5);
        proto.run(5);
        assert_eq!(
            wire.rig.read(A0, 6),
            proto.read(A0, 6),
            "read after {bytes:02X?}"
        );
        wire.queries_match(&mut proto, A0, &format!("after {bytes:02X?}"));
    }
    wire.clean();
}

#[test]
fn read_after_write_with_a_repeated_start_matches_write_stop_read() {
    let (mut wire, mut proto) = (WireBench::new(0), reference());
    for (cmd, n) in QUERIES {
        let got = wire.rig.write_read(A1, &[cmd], n).expect("ACKed");
        assert_eq!(got, proto.query(A1, cmd, n), "0x{cmd:02X}");
    }
    wire.clean();
}

#[test]
fn a_move_over_the_wire_lands_like_one_over_the_protocol_bench() {
    let (mut wire, mut proto) = (WireBench::new(2), reference());
    for b in [&[0x05u8, 4][..], &[0x03, 1], &[0x50, 0x10, 0x27, 0, 0]] {
        assert!(wire.write(A0, b));
        assert!(proto.write(A0, b));
    }
    for _ in 0..40 {
        wire.run(50);
        proto.run(50);
    }
    let (w, p) = (wire.query(A0, 0x40, 4), proto.query(A0, 0x40, 4));
    assert_eq!(w, p);
    assert!(le_i32(&w) > 0, "axis 0 moved");
    assert_eq!(
        host_tests::sim_bridge::chip(&wire.rig.target, 0).abs_pos(),
        proto.chip(0).abs_pos()
    );
    wire.clean();
}

#[test]
fn every_transaction_survives_slow_interrupts() {
    for latency in [1, 3, 6] {
        let (mut wire, mut proto) = (WireBench::new(latency), reference());
        for bytes in WRITES.iter().take(8) {
            assert!(wire.write(A1, bytes), "latency {latency}");
            assert!(proto.write(A1, bytes));
        }
        wire.queries_match(&mut proto, A1, &format!("with latency {latency}"));
        wire.clean();
    }
}

#[test]
fn address_change_0x04_moves_oar1_and_oar2_and_the_old_addresses_go_silent() {
    let mut wire = WireBench::new(0);
    assert!(wire.write(A0, &[0x04, 1, 0x20]));
    assert_eq!(wire.rig.driver.addresses(), (0x20, Some(0x21)));
    assert!(!wire.write(A0, &[0x14]), "old primary NACKed");
    assert!(!wire.write(A1, &[0x14]), "old secondary NACKed");
    assert_eq!(wire.query(0x20, 0x0A, 1), [0x41]);
    assert_eq!(wire.query(0x21, 0x0A, 1), [0x41]);
    wire.clean();
}

#[test]
fn unknown_and_short_writes_are_counted_as_on_the_protocol_bench() {
    let mut wire = WireBench::new(0);
    assert!(wire.write(A0, &[0x99, 1, 2]));
    assert!(wire.write(A0, &[0x50, 0x10]));
    wire.run(2);
    assert_eq!(wire.rig.read(A0, 3), Some(vec![0, 0, 0]));
    assert_eq!(wire.rig.target.diag.i2c_unknown, 1);
    assert_eq!(wire.rig.target.diag.i2c_short, 1);
    wire.clean();
}

#[test]
fn a_bus_error_mid_command_executes_nothing_and_the_next_command_works() {
    let mut wire = WireBench::new(0);
    wire.rig.write_open(A0, &[0x50, 0x10, 0x27]);
    wire.rig.model_mut().abandon_mid_byte();
    wire.rig.step("STOP", |m| m.stop());
    wire.rig.settle();
    wire.run(50);
    assert_eq!(
        wire.query(A0, 0x40, 4),
        [0, 0, 0, 0],
        "no move from the broken write"
    );
    assert_eq!(wire.rig.slave.bus_errors, 1);
    assert!(wire.write(A0, &[0x01, 1, 2, 3, 4]));
    assert_eq!(wire.rig.read(A0, 4), Some(vec![1, 2, 3, 4]));
    wire.clean();
}
