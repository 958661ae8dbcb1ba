//! Extension 0x03nn (diagnostics), 0x05nn (communication watchdog) and
//! 0x06nn (axis state) over Modbus, I2C and USB, on the simulated chain.

use bridge_logic::bridge::{ResetCause, SettingsSource};
use bridge_logic::postep60::settings::IMAGE_LEN;
use bridge_logic::postep60::Settings;
use host_tests::i2c_bench::I2cBench;
use host_tests::modbus_bench::{adu, ModbusBench};
use stepbridge_sim::Fault;

fn line() -> ModbusBench {
    ModbusBench::new(2, Settings::FACTORY)
}

/// A u32 counter of the diagnostics block at offset `at`.
fn counter(b: &mut ModbusBench, at: u16) -> u32 {
    let r = b.read(1, 0x0300 | at, 2).expect("diagnostics");
    u32::from(r[0]) << 16 | u32::from(r[1])
}

// ------------------------------------------------------------ diagnostics ----

#[test]
fn modbus_counters_count_frames_crc_errors_and_exceptions_per_code() {
    let mut b = line();
    b.read(1, 0x40, 2).unwrap();
    let mut bad = adu(&[1, 0x03, 0x00, 0x40, 0x00, 0x02]);
    *bad.last_mut().unwrap() ^= 0xFF;
    b.put(&bad);
    assert!(b.collect().is_empty(), "a bad CRC gets no answer");
    assert_eq!(b.read(1, 0x0099, 1), Err(2));
    assert_eq!(b.write(1, 0x05, 3), Err(4), "DC motor mode");
    // Frames so far: the read, the two exceptions (the CRC error is no frame).
    assert_eq!(counter(&mut b, 0x00), 3);
    assert_eq!(counter(&mut b, 0x02), 1, "CRC errors");
    assert_eq!(counter(&mut b, 0x06), 2, "exceptions");
    assert_eq!(counter(&mut b, 0x0A), 1, "exception 02");
    assert_eq!(counter(&mut b, 0x0E), 1, "exception 04");
}

#[test]
fn bridge_counters_count_chain_errors_refusals_saves_clamps_and_chip_resets() {
    let mut b = line();
    b.write(1, 0x33, 0).unwrap(); // full steps: the factory 1000 steps/s is fine …
    b.write(1, 0x51, 0xFFFF).unwrap(); // … 65 535 is not: clamped
    assert_eq!(b.write(1, 0x05, 3), Err(4), "DC motor: refused");
    b.write(1, 0x3F, 0).unwrap();
    let mut img = [0u8; IMAGE_LEN];
    assert!(b.bridge.take_save(&mut img));
    b.bridge.saved(true);
    b.chip_mut(1).inject(Fault::PowerCycle);
    b.run(20);
    assert_eq!(counter(&mut b, 0x22), 1, "limit clamps");
    assert!(counter(&mut b, 0x1C) >= 1, "refused");
    assert_eq!(counter(&mut b, 0x1E), 1, "saves");
    assert_eq!(counter(&mut b, 0x24), 1, "chip resets");
    assert_eq!(b.read(1, 0x0330, 2), Ok(vec![0, 1]), "resets of axis 0, 1");
    assert_eq!(b.read(1, 0x0346, 1), Ok(vec![1]), "last save succeeded");
}

#[test]
fn i2c_and_usb_errors_are_counted() {
    let mut b = I2cBench::new(2, Settings::FACTORY);
    b.write(1, &[0x99]);
    b.write(1, &[0x50, 1]);
    b.bridge.on_usb_report(&[0u8; 10], 0);
    let mut unknown = [0u8; 64];
    unknown[1] = 0x42;
    b.bridge.on_usb_report(&unknown, 0);
    let mut r = [0u16; 10];
    b.bridge.ext_read(0, 0x0310, &mut r).unwrap();
    assert_eq!(
        r,
        [0, 1, 0, 1, 0, 0, 0, 1, 0, 1],
        "i2c unknown, short, usb reports, bad, unknown"
    );
}

#[test]
fn uptime_tick_timing_chain_length_versions_and_reset_cause_are_readable() {
    let mut b = line();
    b.bridge
        .set_reset_cause(ResetCause::from_rcc_csr(1 << 29 | 1 << 26));
    b.bridge.set_build_id(0xC0FF_EE42);
    b.bridge.tick_timing(180, 1000);
    b.bridge.tick_timing(1200, 1000);
    b.run(2000);
    assert!(counter(&mut b, 0x28) >= 2, "uptime s");
    assert_eq!(counter(&mut b, 0x2A), 1200, "last tick µs");
    assert_eq!(counter(&mut b, 0x2C), 1200, "max tick µs");
    assert_eq!(counter(&mut b, 0x2E), 1, "overruns");
    assert_eq!(
        b.read(1, 0x0340, 4),
        Ok(vec![2, 3, SettingsSource::Stored as u16, 0x0001])
    );
    assert_eq!(b.read(1, 0x0344, 2), Ok(vec![0xC0FF, 0xEE42]));
}

#[test]
fn reset_causes_decode_from_rcc_csr() {
    // RM0090 7.3.21: a power-on sets POR, PIN and BOR together.
    assert_eq!(
        ResetCause::from_rcc_csr(1 << 27 | 1 << 26 | 1 << 25),
        ResetCause::PowerOn
    );
    assert_eq!(ResetCause::from_rcc_csr(1 << 26), ResetCause::Pin);
    assert_eq!(
        ResetCause::from_rcc_csr(1 << 31 | 1 << 26),
        ResetCause::LowPower
    );
    assert_eq!(
        ResetCause::from_rcc_csr(1 << 30 | 1 << 26),
        ResetCause::Watchdog,
        "the window watchdog too"
    );
    assert_eq!(
        ResetCause::from_rcc_csr(1 << 29 | 1 << 26),
        ResetCause::Watchdog
    );
    assert_eq!(
        ResetCause::from_rcc_csr(1 << 28 | 1 << 26),
        ResetCause::Software
    );
    assert_eq!(
        ResetCause::from_rcc_csr(1 << 25 | 1 << 26),
        ResetCause::Brownout
    );
    assert_eq!(ResetCause::from_rcc_csr(0), ResetCause::Unknown);
}

#[test]
fn a_write_to_0x0300_clears_the_counters() {
    let mut b = line();
    assert_eq!(b.read(1, 0x0099, 1), Err(2));
    b.chip_mut(0).inject(Fault::PowerCycle);
    b.run(20);
    assert_eq!(counter(&mut b, 0x24), 1);
    assert_eq!(b.write(1, 0x0300, 0), Ok(()));
    b.run(2);
    assert_eq!(counter(&mut b, 0x24), 0, "chip resets");
    assert_eq!(counter(&mut b, 0x06), 0, "exceptions");
    assert_eq!(b.read(1, 0x0330, 1), Ok(vec![0]));
    // Frames since the clear: the clear's own and the reads after it.
    assert!(counter(&mut b, 0x00) <= 5);
}

#[test]
fn diagnostics_are_read_only_except_the_clear() {
    let mut b = line();
    assert_eq!(b.write(1, 0x0302, 0), Err(2));
    assert_eq!(b.read(1, 0x0350, 1), Err(2), "past the block");
}

// -------------------------------------------------------------- watchdog ----

#[test]
fn the_watchdog_is_off_by_default() {
    let mut b = line();
    assert_eq!(b.read(1, 0x0500, 6), Ok(vec![0, 1, 0, 1, 0, 1]));
    b.set_position(1, 5000).unwrap();
    b.run(2000);
    assert!(
        b.bridge.axis(0).unwrap().profile().velocity() > 0,
        "still moving"
    );
}

#[test]
fn a_silent_modbus_master_gets_its_axes_soft_stopped() {
    let mut b = line();
    b.write_multiple(1, 0x0500, &[200, 1]).unwrap(); // 200 ms, soft stop
    b.set_position(1, 50_000).unwrap();
    b.run(150);
    b.read(1, 0x40, 2).unwrap(); // a read keeps it alive
    b.run(150);
    assert!(b.bridge.axis(0).unwrap().profile().velocity() > 0);
    b.run(300);
    let a = b.bridge.axis(0).unwrap();
    assert!(a.profile().velocity() < 1000, "braking");
    b.settle(10_000);
    assert!(
        b.chip(0).abs_pos() < 50_000 * 8,
        "stopped short of the target"
    );
    assert_eq!(
        b.read(1, 0x0506, 4),
        Ok(vec![1, 0, 0, 0b000]),
        "one Modbus trip, heard again"
    );
    assert_eq!(b.bridge.diag.watchdog_trips, 1);
}

#[test]
fn the_watchdog_only_stops_axes_its_bus_moved() {
    let mut b = I2cBench::new(2, Settings::FACTORY);
    b.bridge.ext_write(0, 0x0500, &[100, 0]).unwrap(); // Modbus: 100 ms, hold
    b.write(1, &[0x50, 0x10, 0x27, 0, 0]); // I2C moves axis 0
    b.run(500);
    assert!(
        b.bridge.axis(0).unwrap().profile().velocity() > 0,
        "not Modbus's axis"
    );
    assert_eq!(b.bridge.diag.watchdog_trips, 0);
}

#[test]
fn the_hiz_action_switches_the_bridges_off() {
    let mut b = I2cBench::new(2, Settings::FACTORY);
    b.bridge.ext_write(0, 0x0502, &[100, 2]).unwrap(); // I2C: 100 ms, bridges off
    b.write(1, &[0x50, 0x10, 0x27, 0, 0]);
    b.run(300);
    assert!(b.chip(0).is_hiz());
    assert_eq!(b.query(1, 0x13, 1), [1], "driver status: sleep");
}

#[test]
fn watchdog_settings_persist_and_bad_actions_are_refused() {
    let mut b = line();
    assert_eq!(b.write(1, 0x0501, 3), Err(3));
    b.write_multiple(1, 0x0504, &[750, 0]).unwrap();
    b.write(1, 0x3F, 0).unwrap();
    let mut img = [0u8; IMAGE_LEN];
    assert!(b.bridge.take_save(&mut img));
    let s = Settings::from_image(&img).unwrap();
    assert_eq!(s.watchdog[2].timeout_ms, 750);
}

// ------------------------------------------------------------ axis state ----

#[test]
fn the_signed_speed_and_the_state_are_in_0x06nn() {
    let mut b = line();
    b.set_position(1, -20_000).unwrap();
    b.run(1500);
    let r = b.read(1, 0x0600, 10).unwrap();
    let speed = (u32::from(r[0]) << 16 | u32::from(r[1])) as i32;
    assert_eq!(speed, -1000, "reverse at the factory 1000 steps/s");
    assert_eq!(
        (u32::from(r[4]) << 16 | u32::from(r[5])) as i32,
        -20_000,
        "target"
    );
    assert_eq!(r[6], 2, "streaming");
    // 0x44 reads the magnitude.
    assert_eq!(b.read(1, 0x44, 1), Ok(vec![1000]));
}

#[test]
fn usb_0xe0_reads_and_0xe1_writes_the_extension_space() {
    let mut b = I2cBench::new(2, Settings::FACTORY);
    let mut w = [0u8; 64];
    w[1] = 0xE1;
    w[20..22].copy_from_slice(&0x0113u16.to_be_bytes());
    w[22] = 1;
    w[24..26].copy_from_slice(&0x0012u16.to_be_bytes());
    b.bridge.on_usb_report(&w, 0);
    let r = *b.bridge.usb_next(0).unwrap();
    b.bridge.usb_sent();
    assert_eq!((r.0[15], r.0[14]), (0xE1, 0));
    let mut rd = [0u8; 64];
    rd[1] = 0xE0;
    rd[20..22].copy_from_slice(&0x0113u16.to_be_bytes());
    rd[22] = 1;
    b.bridge.on_usb_report(&rd, 0);
    assert!(b.bridge.usb_next(0).is_none(), "waits for the chip");
    b.run(3);
    let now = b.clock.now_ms();
    let r = *b.bridge.usb_next(now).unwrap();
    assert_eq!((r.0[15], r.0[14]), (0xE0, 0));
    assert_eq!(&r.0[16..18], &[0x00, 0x12]);
    // A missing register: status 10.
    rd[20..22].copy_from_slice(&0x0150u16.to_be_bytes());
    b.bridge.usb_sent();
    b.bridge.on_usb_report(&rd, now);
    let r = *b.bridge.usb_next(now).unwrap();
    assert_eq!(r.0[14], 10);
}
