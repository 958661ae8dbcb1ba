//! What `stepctl doctor` reads: the configured-register block (0x07nn)
//! against the chip (0x01nn), the diagnostics it judges (chain state, tick
//! period and count, supply and temperature), and a box whose chain was
//! not found still answering on its first id (Modbus) and axis 0 (USB).

use bridge_logic::bridge::{Bridge, SettingsSource};
use bridge_logic::postep60::{PowerStage, Settings};
use bridge_logic::powerstep::registers::Register;
use bridge_logic::transport::usb::codec::{cmd, status, IN_STATUS_BYTE};
use host_tests::modbus_bench::ModbusBench;
use host_tests::sim_bridge::factory_bridge_on;
use host_tests::sim_bridge::Breakable;
use stepbridge_sim::{Fault, SimChain};

fn line(n: usize) -> ModbusBench {
    let mut b = ModbusBench::new(n, Settings::FACTORY);
    b.settle(2000);
    b
}

fn u32_of(r: &[u16]) -> u32 {
    u32::from(r[0]) << 16 | u32::from(r[1])
}

/// The chip's register `reg` of server `id` through 0x01nn.
fn chip_value(b: &mut ModbusBench, id: u8, reg: Register) -> u32 {
    let width = if reg.bytes() == 3 { 2 } else { 1 };
    let r = b
        .read(id, 0x0100 | u16::from(reg.address()), width)
        .unwrap();
    if width == 2 {
        u32_of(&r)
    } else {
        u32::from(r[0])
    }
}

/// (mask, values 0x01..=0x1B, pending, set up) of server `id`.
fn configured(b: &mut ModbusBench, id: u8) -> (u32, Vec<u16>, u16, u16) {
    let r = b.read(id, 0x0700, 0x24).unwrap();
    (u32_of(&r[0x20..0x22]), r[..0x1C].to_vec(), r[0x22], r[0x23])
}

#[test]
fn every_register_the_bridge_configures_is_what_the_chip_holds() {
    let mut b = line(2);
    for id in [1, 2] {
        let (mask, values, pending, set_up) = configured(&mut b, id);
        assert_eq!((pending, set_up), (0, 1), "configured and written");
        let want = [
            Register::Acc,
            Register::Dec,
            Register::MaxSpeed,
            Register::MinSpeed,
            Register::KvalHold,
            Register::KvalRun,
            Register::KvalAcc,
            Register::KvalDec,
            Register::StepMode,
            Register::Config,
        ];
        for r in want {
            assert_ne!(mask & 1 << r.address(), 0, "{r:?} configured");
        }
        for r in [
            Register::AbsPos,
            Register::ElPos,
            Register::Mark,
            Register::Speed,
            Register::AdcOut,
            Register::Status,
        ] {
            assert_eq!(mask & 1 << r.address(), 0, "{r:?} is not configuration");
        }
        for r in Register::all().filter(|r| mask & 1 << r.address() != 0) {
            let v = u32::from(values[usize::from(r.address())]);
            assert_eq!(chip_value(&mut b, id, r), v & r.mask(), "{r:?} on id {id}");
        }
        // The block's values are the bridge's, not a copy of the chip's.
        assert_eq!(
            u32::from(values[usize::from(Register::Config.address())]),
            u32::from(PowerStage::REFERENCE.config_register())
        );
    }
}

#[test]
fn a_tuning_write_shows_at_once_and_a_chip_reset_is_configured_again() {
    let mut b = line(2);
    let ocd = 0x0700 | u16::from(Register::OcdTh.address());
    b.write(1, 0x0100 | u16::from(Register::OcdTh.address()), 12)
        .unwrap();
    assert_eq!(b.read(1, ocd, 1), Ok(vec![12]), "what the bridge wants");
    b.run(5);
    assert_eq!(chip_value(&mut b, 1, Register::OcdTh), 12);
    // A power cycle: the chip is back at its reset values until the bridge
    // has written the image again; then the two agree again.
    b.chip_mut(1).inject(Fault::PowerCycle);
    b.run(50);
    let (mask, values, pending, _) = configured(&mut b, 2);
    assert_eq!(pending, 0);
    for r in Register::all().filter(|r| mask & 1 << r.address() != 0) {
        let v = u32::from(values[usize::from(r.address())]);
        assert_eq!(
            chip_value(&mut b, 2, r),
            v & r.mask(),
            "{r:?} after the reset"
        );
    }
    assert_eq!(b.read(2, 0x0331, 1), Ok(vec![1]), "the reset is counted");
}

#[test]
fn the_block_is_read_only_and_an_axis_beyond_the_chain_has_none() {
    let mut b = line(2);
    assert_eq!(b.write(1, 0x0713, 3), Err(2));
    assert_eq!(b.read(1, 0x0724, 1), Err(2), "past the block");
    assert_eq!(b.read(1, 0x0701, 0x24), Err(2), "past the block");
}

#[test]
fn diagnostics_carry_the_chain_state_tick_period_and_count_supply_and_temperature() {
    let mut b = line(2);
    b.bridge.tick_timing(150, 1000);
    b.bridge.tick_timing(160, 1000);
    let r = b.read(1, 0x034A, 6).unwrap();
    assert_eq!(r[0], 0, "chain works");
    assert_eq!(r[1], 1000, "tick period µs");
    assert_eq!(u32_of(&r[2..4]), 2, "ticks timed");
    assert_eq!(
        (r[4], r[5]),
        (
            b.read(1, 0x10, 1).unwrap()[0],
            b.read(1, 0x11, 1).unwrap()[0]
        ),
        "supply and temperature in 0x10 / 0x11 units"
    );
    assert_eq!(r[4], 333, "24 V");
    // Clearing the counters keeps the period.
    b.write(1, 0x0300, 0).unwrap();
    let r = b.read(1, 0x034B, 3).unwrap();
    assert_eq!((r[0], u32_of(&r[1..3])), (1000, 0));
}

#[test]
fn the_chain_state_says_failing_then_dead_and_a_good_tick_ends_it() {
    let mut b = Bridge::new(
        Breakable::new(2),
        PowerStage::REFERENCE,
        Settings::FACTORY,
        SettingsSource::Stored,
        1000,
    );
    let state = |b: &mut Bridge<Breakable>| {
        let mut r = [0u16; 1];
        b.ext_read(0, 0x034A, &mut r).unwrap();
        r[0]
    };
    for now in 1..=20 {
        b.tick(now);
    }
    assert_eq!(state(&mut b), 0);
    b.chain_mut().bus_mut().broken = true;
    b.tick(21);
    assert_eq!(state(&mut b), 1, "failing");
    for now in 22..=30 {
        b.tick(now);
    }
    assert_eq!(state(&mut b), 2, "dead");
    b.chain_mut().bus_mut().broken = false;
    b.tick(31);
    assert_eq!(state(&mut b), 0);
}

/// A bridge whose chain had a dead chip at detection: no axis.
fn undetected() -> Bridge<SimChain> {
    let mut chain = SimChain::new(4);
    chain.device_mut(1).unwrap().inject(Fault::Dead(0xFF));
    factory_bridge_on(chain)
}

#[test]
fn with_no_chip_detected_the_first_id_still_answers_the_bridge_s_blocks() {
    let mut b = line(2);
    b.bridge = undetected();
    assert_eq!(b.bridge.axes(), 0);
    b.run(5);
    // Chain length 0, reset cause, settings source; chain state 3.
    assert_eq!(
        b.read(1, 0x0340, 3),
        Ok(vec![0, 0, SettingsSource::FactoryEmpty as u16])
    );
    assert_eq!(b.read(1, 0x034A, 1), Ok(vec![3]));
    assert_eq!(b.read(1, 0x034E, 1), Ok(vec![333]), "the supply reads");
    assert!(b.read(1, 0x0500, 10).is_ok(), "watchdog block");
    assert!(b.read(1, 0x0200, 2).is_ok(), "I/O extension block");
    // Nothing of an axis: 04 for the PoStep60 map, 02 for its blocks.
    assert_eq!(b.read(1, 0x0A, 3), Err(4));
    assert_eq!(b.write(1, 0x5F, 0), Err(4));
    assert_eq!(b.read(1, 0x011B, 1), Err(2));
    assert_eq!(b.read(1, 0x0600, 10), Err(2));
    assert_eq!(b.read(1, 0x0701, 1), Err(2));
    // Only the first id.
    b.put(&host_tests::modbus_bench::adu(&[2, 0x03, 0x03, 0x40, 0, 1]));
    assert!(b.collect().is_empty(), "id 2 has no axis and stays silent");
}

#[test]
fn with_no_chip_detected_usb_axis_0_takes_extension_requests() {
    let mut bridge = undetected();
    let ext_read = |axis: u8, address: u16, n: u8| {
        let mut r = [0u8; 64];
        r[1] = cmd::EXT_READ;
        r[20..22].copy_from_slice(&address.to_be_bytes());
        r[22] = n;
        r[62] = axis;
        r
    };
    let answer = |bridge: &mut Bridge<SimChain>, report: [u8; 64]| {
        bridge.on_usb_report(&report, 0);
        let r = bridge.usb_next(0).copied().expect("a response");
        bridge.usb_sent();
        r.0
    };
    let r = answer(&mut bridge, ext_read(0, 0x0340, 1));
    assert_eq!(r[IN_STATUS_BYTE], status::DONE);
    assert_eq!(u16::from_be_bytes([r[16], r[17]]), 0, "chain length 0");
    let r = answer(&mut bridge, ext_read(0, 0x034A, 1));
    assert_eq!(u16::from_be_bytes([r[16], r[17]]), 3, "not detected");
    let r = answer(&mut bridge, ext_read(0, 0x0600, 2));
    assert_eq!(r[IN_STATUS_BYTE], status::ILLEGAL_ADDRESS, "no axis block");
    let r = answer(&mut bridge, ext_read(1, 0x0340, 1));
    assert_eq!(r[IN_STATUS_BYTE], status::NO_AXIS, "axis 1 does not exist");
}
