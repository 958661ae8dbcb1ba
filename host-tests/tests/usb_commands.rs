//! The PoStep60 USB API (manual §10) against the bridge on simulated chips,
//! through the real `usb-device` stack on an emulated bus: enumeration and
//! descriptors byte for byte, then every command with OUT reports written
//! byte by byte from the manual's tables and IN reports checked at the
//! tables' offsets (never with the project's codec).

use bridge_logic::bridge::{ResetTarget, RunMode};
use bridge_logic::postep60::settings::DriverMode;
use bridge_logic::postep60::Settings;
use host_tests::usb_bench::{read, transact, write, UsbCtx, UID};
use host_tests::usb_manual::{
    be16, be32, le32, out, phys, trajectory, write_driver_settings, MANUAL_CONFIG, MANUAL_DEVICE,
    REPORT_DESCRIPTOR,
};
use stepbridge_sim::Fault;
use usbd_class_tester::prelude::*;

// ---------------------------------------------------------- descriptors ----

#[test]
fn device_descriptor_is_byte_for_byte_the_manual_s() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let d = dev
                .device_get_descriptor(&mut cls, 1, 0, 0, 18)
                .expect("device descriptor");
            assert_eq!(d, MANUAL_DEVICE);
        })
        .expect("with_usb");
}

#[test]
fn configuration_descriptor_is_the_manual_s_41_bytes() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let d = dev
                .device_get_descriptor(&mut cls, 2, 0, 0, 255)
                .expect("configuration");
            assert_eq!(d, MANUAL_CONFIG);
        })
        .expect("with_usb");
}

#[test]
fn strings_are_polabs_postep60_256_the_serial_and_hid() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let mut s = |i| dev.device_get_string(&mut cls, i, 0x0409).expect("string");
            assert_eq!(s(1), "PoLabs");
            assert_eq!(s(2), "PoStep60-256");
            assert_eq!(s(4), "HID");
            let serial = s(3);
            // "XXXXXXXX-XXXXXXXX-XXXXXXXX-XXXXXXXX", the manual's shape.
            assert_eq!(serial.len(), 35);
            let groups: Vec<&str> = serial.split('-').collect();
            assert_eq!(groups.len(), 4);
            assert_eq!(groups[1], format!("{:08X}", UID[0]));
            assert_eq!(groups[2], format!("{:08X}", UID[1]));
            assert_eq!(groups[3], format!("{:08X}", UID[2]));
        })
        .expect("with_usb");
}

#[test]
fn hid_and_report_descriptors_come_from_the_interface() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let to_interface = CtrRequestType::to_host().standard().interface();
            let hid = dev
                .control_read(&mut cls, to_interface, 6, 0x2100, 0, 9)
                .expect("HID descriptor");
            assert_eq!(hid, MANUAL_CONFIG[18..27]);
            let report = dev
                .control_read(&mut cls, to_interface, 6, 0x2200, 0, 0x21)
                .expect("report descriptor");
            assert_eq!(report, REPORT_DESCRIPTOR);
        })
        .expect("with_usb");
}

#[test]
fn set_idle_is_accepted() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let class = CtrRequestType::to_device().class().interface();
            dev.control_write(&mut cls, class, 0x0A, 0, 0, 0, &[])
                .expect("SET_IDLE");
        })
        .expect("with_usb");
}

// ------------------------------------------------------------- commands ----

#[test]
fn device_info_0x01_reports_versions_mode_voltage_uid_temperature_and_status() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let r = transact(&mut cls, &mut dev, &out(0x01));
            assert_eq!(r.len(), 64);
            assert_eq!(r[0], 0x02, "IN_REPORT_ID");
            assert_eq!(
                be16(&r, 1),
                0x0109,
                "bootloader firmware: the PoStep60's 1.9"
            );
            assert_eq!(
                be16(&r, 3),
                0x0109,
                "application firmware: the PoStep60's 1.9"
            );
            assert_eq!(r[5], 0xAB, "DEVICE_MODE: application");
            assert_eq!(r[6] & 1, 1, "bootloader override pin reads high");
            // 24 V at 0.072 V/LSB: the bench's ADC sample gives 333.
            assert_eq!(be16(&r, 8), 333);
            assert_eq!(r[15], 0x00);
            assert_eq!(be32(&r, 24), UID[0]);
            assert_eq!(be32(&r, 28), UID[1]);
            assert_eq!(be32(&r, 32), UID[2]);
            // about 25 °C at 0.125 °C/LSB, MSB first
            let t = f64::from(be16(&r, 44)) * 0.125;
            assert!((24.0..=26.0).contains(&t), "{t} °C");
            assert_eq!(r[46], 0x02, "ACTIVE");
        })
        .expect("with_usb");
}

#[test]
fn a_63_byte_report_is_taken_as_out_data_1_to_63() {
    // What Linux hidraw sends for a 64-byte write whose byte 0 is 0x00 (the
    // manual's OutDATA[0] is "-"): usbhid strips the zero report id.
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let r = transact(&mut cls, &mut dev, &out(0x01)[1..]);
            assert_eq!(r.len(), 64, "answered");
            assert_eq!(r[0], 0x02);
            assert_eq!(be16(&r, 3), 0x0109);
            assert_eq!(r[5], 0xAB, "DEVICE_MODE: application");
            let t = trajectory(0, 4000, 2000, 20_000, 20_000);
            write(&mut cls, &mut dev, &t[1..]);
            cls.settle(30_000);
            assert_eq!(cls.chip(0).abs_pos(), phys(4000), "a 63-byte 0xB1 moves");
        })
        .expect("with_usb");
}

#[test]
fn system_reset_0x02_once_restarts_into_boot_mode() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            cls.bridge
                .request(0, bridge_logic::postep60::Request::SetPosition(100_000))
                .unwrap();
            cls.run(200);
            let r = transact(&mut cls, &mut dev, &out(0x02));
            assert!(r.is_empty(), "no response: the device restarts");
            // Every axis stops first; then the reset is handed out.
            cls.run(20);
            assert!(!cls.chip(0).is_busy());
            assert_eq!(cls.bridge.take_reset(), Some(ResetTarget::BootMode));
        })
        .expect("with_usb");
}

#[test]
fn in_boot_mode_0x01_says_0xb0_nothing_moves_and_0x02_restarts_the_application() {
    UsbCtx {
        run_mode: RunMode::Boot,
        ..UsbCtx::default()
    }
    .with_usb(|mut cls, mut dev| {
        let r = transact(&mut cls, &mut dev, &out(0x01));
        assert_eq!(r[5], 0xB0, "DEVICE_MODE: bootloader");
        assert_eq!(r[46], 0x01, "SLEEP: bridges off");
        cls.run(20);
        assert!(cls.chip(0).is_hiz());
        let r = transact(&mut cls, &mut dev, &trajectory(0, 5000, 1000, 1000, 1000));
        assert_eq!(r[14], 8, "refused: boot mode");
        cls.run(500);
        assert_eq!(cls.chip(0).abs_pos(), 0);
        assert!(transact(&mut cls, &mut dev, &out(0x02)).is_empty());
        cls.run(5);
        assert_eq!(cls.bridge.take_reset(), Some(ResetTarget::Application));
    })
    .expect("with_usb");
}

#[test]
fn write_driver_settings_0x80_reads_back_through_0x81_and_is_stored() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            // CTRL: ENBL, MODE 1/8 (0011), ISGAIN 20 (10), DTIME 650 ns (10);
            // TORQUE 0x0D0 with SMPLTH 3; the rest stored as they are.
            let regs = [
                0x0A19, 0x03D0, 0x0031, 0x0181, 0x0512, 0x0A41, 0x0A5A, 0x0000,
            ];
            let r = transact(
                &mut cls,
                &mut dev,
                &write_driver_settings(regs, 5, 90, 1, 3),
            );
            assert_eq!((r[0], r[1], r[15]), (0x02, 0x00, 0x00));
            assert_eq!(r[14], 0, "done");
            cls.run(50);
            let r = transact(&mut cls, &mut dev, &out(0x81));
            assert_eq!((r[0], r[1], r[15]), (0x02, 0xBA, 0x81));
            let reg = |i: usize| u16::from_le_bytes([r[40 + 2 * i], r[41 + 2 * i]]);
            assert_eq!(reg(0), 0x0A19, "CTRL");
            assert_eq!(reg(1), 0x03D0, "TORQUE");
            for (i, want) in regs.iter().enumerate().take(7).skip(2) {
                assert_eq!(reg(i), *want, "register {i}");
            }
            assert_eq!(reg(7), 0, "STATUS: no fault");
            assert_eq!(r[56], 90);
            assert_eq!((r[57], r[58]), (61, 3));
            assert_eq!((r[59], r[60]), (123, 3));
            assert_eq!(r[61], 1);
            assert_eq!(r[62], 5, "CONFIG_SET: BINx");
            assert_eq!(r[63], 3, "19200 even");
            // The mapped fields took effect: 1/8 steps, 0.065·208/4 = 3.38 A.
            let d = cls.bridge.device(0).unwrap();
            assert_eq!(d.settings.step_mode, 3);
            assert_eq!(d.settings.full_scale.milliamps(), Some(3380));
            assert_eq!(d.settings.mode, DriverMode::BinButtons);
            // ... and everything is in the store (0x84 reads it).
            let stored = cls.stored().expect("stored");
            assert_eq!(stored.axes[0].step_mode, 3);
            assert_eq!(stored.serial.code(), 3);
            let e = transact(&mut cls, &mut dev, &out(0x84));
            assert_eq!((e[0], e[1], e[15]), (0x02, 0x84, 0x00));
            assert_eq!(u16::from_le_bytes([e[42], e[43]]), 0x03D0);
            assert_eq!(e[56], 90);
            assert_eq!(e[63], 3);
        })
        .expect("with_usb");
}

#[test]
fn read_eeprom_0x84_shows_the_store_not_unsaved_changes() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            // 0xB1 changes the limits but does not store them.
            transact(&mut cls, &mut dev, &trajectory(0, 0, 3000, 4000, 5000));
            let mut o = out(0x88);
            let r = transact(&mut cls, &mut dev, &o);
            assert_eq!(le32(&r, 24), 3000);
            o = out(0x84);
            let e = transact(&mut cls, &mut dev, &o);
            // Factory settings in the store: 1.0 A full scale (Tq 123, Ai 3).
            assert_eq!(u16::from_le_bytes([e[42], e[43]]) & 0xFF, 123);
            assert_eq!(e[56], 80);
        })
        .expect("with_usb");
}

#[test]
fn read_driver_registers_0x85_shows_the_live_status_bits() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            cls.bridge
                .chain_mut()
                .bus_mut()
                .device_mut(0)
                .unwrap()
                .inject(Fault::Overcurrent);
            cls.run(20);
            let r = transact(&mut cls, &mut dev, &out(0x85));
            assert_eq!((r[0], r[1], r[15]), (0x02, 0xBC, 0x00));
            // STATUS: AOCP | BOCP
            assert_eq!(u16::from_le_bytes([r[54], r[55]]), 0x06);
            // CTRL MODE = 1/16 (the factory step mode), ENBL
            assert_eq!(u16::from_le_bytes([r[40], r[41]]) & 0x79, (4 << 3) | 1);
            // 0x86 clears them.
            let a = transact(&mut cls, &mut dev, &out(0x86));
            assert_eq!((a[0], a[1], a[15], a[14]), (0x02, 0x00, 0x00, 0));
            let r = transact(&mut cls, &mut dev, &out(0x85));
            assert_eq!(u16::from_le_bytes([r[54], r[55]]), 0);
        })
        .expect("with_usb");
}

#[test]
fn erase_eeprom_0x83_and_its_table_s_0x82_restore_factory_settings() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            for code in [0x83u8, 0x82] {
                transact(&mut cls, &mut dev, &trajectory(1, 0, 3000, 4000, 5000));
                let r = transact(&mut cls, &mut dev, &out(code));
                assert_eq!(
                    (r[0], r[1], r[15], r[14]),
                    (0x02, 0x00, 0x00, 0),
                    "{code:#x}"
                );
                cls.run(50);
                assert_eq!(cls.bridge.settings(), Settings::FACTORY, "{code:#x}");
                assert_eq!(cls.stored(), Some(Settings::FACTORY), "{code:#x}");
            }
        })
        .expect("with_usb");
}

#[test]
fn other_configuration_0x88_reads_what_0xb1_wrote_and_0x87_stores_it() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let mut t = trajectory(1, 0, 100_000, 200_000, 300_000);
            t[36] = 0b011; // end switch on, NC
            t[40..44].copy_from_slice(&250i32.to_le_bytes());
            t[44..48].copy_from_slice(&(-75i32).to_le_bytes());
            let r = transact(&mut cls, &mut dev, &t);
            assert_eq!((r[0], r[1], r[15], r[14]), (0x02, 0x00, 0xB1, 0));
            let r = transact(&mut cls, &mut dev, &out(0x88));
            assert_eq!((r[0], r[1], r[15]), (0x02, 0xCC, 0x87));
            assert_eq!(le32(&r, 24), 100_000);
            assert_eq!(le32(&r, 28), 200_000);
            assert_eq!(le32(&r, 32), 300_000);
            // end switch, NC, BINx enabled (profile 1), no auto run, no invert
            assert_eq!(r[36], 0b00111);
            assert_eq!(le32(&r, 40) as i32, 250);
            assert_eq!(le32(&r, 44) as i32, -75);
            assert_ne!(cls.stored().map(|s| s.axes[0].max_speed), Some(100_000));
            let r = transact(&mut cls, &mut dev, &out(0x87));
            assert_eq!((r[0], r[1], r[15], r[14]), (0x02, 0x00, 0x00, 0));
            cls.run(20);
            assert_eq!(cls.stored().map(|s| s.axes[0].max_speed), Some(100_000));
        })
        .expect("with_usb");
}

#[test]
fn save_other_0x87_while_an_axis_moves_is_done_once_it_rests() {
    // A host that knows only the manual reads [14] = 0 and [15] = 0 as
    // "saved": the save must then happen, deferred until every axis rests.
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let r = transact(
                &mut cls,
                &mut dev,
                &trajectory(0, 40_000, 4000, 20_000, 20_000),
            );
            assert_eq!(r[14], 0);
            cls.run(50);
            let r = transact(&mut cls, &mut dev, &out(0x87));
            assert_eq!(
                (r[0], r[1], r[15], r[14]),
                (0x02, 0x00, 0x00, 0),
                "accepted"
            );
            assert_ne!(cls.stored().map(|s| s.axes[0].max_speed), Some(4000));
            cls.settle(60_000);
            cls.run(20);
            assert_eq!(
                cls.stored().map(|s| s.axes[0].max_speed),
                Some(4000),
                "saved at rest"
            );
        })
        .expect("with_usb");
}

#[test]
fn trajectory_0xb1_moves_to_the_final_position_with_32_bit_limits() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            // 80 000 steps/s at 1/16 = 5000 full steps/s: above any 16-bit value.
            let r = transact(
                &mut cls,
                &mut dev,
                &trajectory(0, 150_000, 80_000, 160_000, 160_000),
            );
            assert_eq!((r[15], r[14]), (0xB1, 0));
            assert_eq!(cls.bridge.device(0).unwrap().settings.max_speed, 80_000);
            cls.settle(60_000);
            assert_eq!(cls.chip(0).abs_pos(), phys(150_000));
        })
        .expect("with_usb");
}

#[test]
fn trajectory_limits_beyond_the_chip_are_clamped_as_on_the_other_buses() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            // 10 000 000 steps/s at 1/16 is 625 000 full steps/s.
            transact(
                &mut cls,
                &mut dev,
                &trajectory(0, 0, 10_000_000, 10_000_000, 10_000_000),
            );
            let r = transact(&mut cls, &mut dev, &out(0x88));
            assert_eq!(le32(&r, 24), 199_697);
            assert_eq!(le32(&r, 28), 635_394);
            assert_eq!(cls.bridge.diag.limit_clamps, 1);
        })
        .expect("with_usb");
}

#[test]
fn trajectory_stop_0xb2_stops_at_once_and_zero_0xb3_reads_zero() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            transact(
                &mut cls,
                &mut dev,
                &trajectory(0, 400_000, 16_000, 16_000, 16_000),
            );
            cls.run(500);
            let r = transact(&mut cls, &mut dev, &out(0xB2));
            assert_eq!((r[0], r[1], r[15], r[14]), (0x02, 0x00, 0x00, 0));
            cls.run(10);
            let p = cls.chip(0).abs_pos();
            cls.run(200);
            assert_eq!(cls.chip(0).abs_pos(), p, "stopped");
            let r = transact(&mut cls, &mut dev, &out(0xB3));
            assert_eq!((r[0], r[1], r[15], r[14]), (0x02, 0x00, 0x00, 0));
            cls.settle(1000);
            assert_eq!(cls.chip(0).abs_pos(), 0);
        })
        .expect("with_usb");
}

#[test]
fn step_dir_0x90_runs_at_480000_over_stepvalue_in_step_control_mode_only() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let mut sd = out(0x90);
            sd[20..24].copy_from_slice(&480u32.to_le_bytes()); // 1000 steps/s
            let r = transact(&mut cls, &mut dev, &sd);
            assert_eq!(
                (r[0], r[1], r[15], r[14]),
                (0x02, 0x00, 0x90, 1),
                "wrong mode"
            );
            // CONFIG_SET 2 (step control) through 0x80.
            let regs = [0x0C21, 0x01FF, 0x0030, 0x0080, 0x0110, 0x0040, 0x0A59, 0];
            transact(
                &mut cls,
                &mut dev,
                &write_driver_settings(regs, 2, 80, 1, 0),
            );
            let r = transact(&mut cls, &mut dev, &sd);
            assert_eq!(r[14], 0);
            cls.run(2000);
            assert_eq!(cls.bridge.axis(0).unwrap().profile().velocity(), 1000);
            sd[24] = 0x01; // invert direction
            transact(&mut cls, &mut dev, &sd);
            cls.run(3000);
            assert_eq!(cls.bridge.axis(0).unwrap().profile().velocity(), -1000);
            sd[20..24].copy_from_slice(&0u32.to_le_bytes()); // 0 stops
            transact(&mut cls, &mut dev, &sd);
            cls.settle(10_000);
        })
        .expect("with_usb");
}

#[test]
fn run_sleep_0xa1_is_0x01_run_and_0x00_sleep() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let mut rs = out(0xA1);
            rs[20] = 0x00;
            let r = transact(&mut cls, &mut dev, &rs);
            assert_eq!((r[0], r[1], r[15], r[14]), (0x02, 0x00, 0x00, 0));
            cls.run(10);
            assert!(cls.chip(0).is_hiz());
            assert_eq!(transact(&mut cls, &mut dev, &out(0x01))[46], 0x01, "SLEEP");
            rs[20] = 0x01;
            transact(&mut cls, &mut dev, &rs);
            cls.run(10);
            assert!(!cls.chip(0).is_hiz());
            // I2C's 0xDA is no run code on USB: ignored.
            rs[20] = 0xDA;
            assert_eq!(transact(&mut cls, &mut dev, &rs)[14], 4);
        })
        .expect("with_usb");
}

#[test]
fn set_pwm_0xb0_is_refused_and_moves_nothing() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let mut p = out(0xB0);
            p[20..24].copy_from_slice(&48u32.to_le_bytes());
            p[24] = 200;
            let r = transact(&mut cls, &mut dev, &p);
            assert_eq!(
                (r[0], r[1], r[15], r[14]),
                (0x02, 0x00, 0xB0, 5),
                "unsupported"
            );
            cls.run(200);
            assert_eq!(cls.chip(0).abs_pos(), 0);
            assert!(cls.bridge.diag.refused >= 1);
        })
        .expect("with_usb");
}

#[test]
fn custom_name_0xc0_is_stored_and_0xc1_reads_it_at_16() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let mut w = out(0xC0);
            w[2..2 + 13].copy_from_slice(b"left gantry X");
            let r = transact(&mut cls, &mut dev, &w);
            assert_eq!((r[0], r[1], r[15], r[14]), (0x02, 0x00, 0x00, 0));
            let r = transact(&mut cls, &mut dev, &out(0xC1));
            assert_eq!((r[0], r[1], r[15]), (0x02, 0x00, 0xC0));
            assert_eq!(&r[16..29], b"left gantry X");
            assert!(r[29..48].iter().all(|b| *b == 0));
            cls.run(20);
            let stored = cls.stored().expect("stored");
            assert_eq!(&stored.axes[0].name[..13], b"left gantry X");
        })
        .expect("with_usb");
}

#[test]
fn the_stream_0xa0_sends_every_10_ms_with_position_and_speed_big_endian() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let r = transact(&mut cls, &mut dev, &out(0xA0));
            assert_eq!((r[0], r[1], r[15]), (0x02, 0x00, 0x00), "acknowledged");
            transact(
                &mut cls,
                &mut dev,
                &trajectory(0, -3000, 16_000, 16_000, 16_000),
            );
            let mut times = Vec::new();
            let mut last = Vec::new();
            for _ in 0..200 {
                cls.run(1);
                let r = read(&mut cls, &mut dev);
                if !r.is_empty() {
                    assert_eq!((r[0], r[1], r[15]), (0x02, 0x00, 0xA0));
                    times.push(cls.clock.now_ms());
                    last = r;
                }
            }
            // 200 ms: 20 reports, 10 ms apart.
            assert_eq!(times.len(), 20, "{times:?}");
            assert!(times.windows(2).all(|w| w[1] - w[0] == 10), "{times:?}");
            let pos = be32(&last, 20) as i32;
            let speed = be32(&last, 24) as i32;
            assert!(
                pos < 0 && speed < 0,
                "moving toward −3000: {pos} at {speed}"
            );
            assert_eq!(be32(&last, 28) as i32, -3000, "final position");
            let t = f64::from(be16(&last, 44)) * 0.125;
            assert!((24.0..=26.0).contains(&t), "{t} °C");
            assert_eq!(last[46], 2, "ACTIVE");
            assert_eq!(last[47], 4, "CONFIG_SET: trajectory");
            // 0xA2 (extension) ends it.
            transact(&mut cls, &mut dev, &out(0xA2));
            cls.run(50);
            assert!(read(&mut cls, &mut dev).is_empty());
        })
        .expect("with_usb");
}

#[test]
fn a_command_response_goes_before_a_due_stream_report() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            transact(&mut cls, &mut dev, &out(0xA0));
            cls.run(9);
            write(&mut cls, &mut dev, &out(0x88));
            cls.run(1); // the stream is due now
            let r = read(&mut cls, &mut dev);
            assert_eq!(r[1], 0xCC, "the response first");
            cls.run(1);
            let r = read(&mut cls, &mut dev);
            assert_eq!(r[15], 0xA0, "then the stream");
        })
        .expect("with_usb");
}

#[test]
fn byte_62_selects_the_axis() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let mut t = trajectory(0, 2000, 16_000, 16_000, 16_000);
            t[62] = 1;
            let r = transact(&mut cls, &mut dev, &t);
            assert_eq!((r[13], r[14]), (1, 0));
            cls.settle(20_000);
            assert_eq!(cls.chip(1).abs_pos(), phys(2000));
            assert_eq!(cls.chip(0).abs_pos(), 0);
            t[62] = 7; // the chain has 2 chips
            let r = transact(&mut cls, &mut dev, &t);
            assert_eq!((r[13], r[14]), (7, 9));
        })
        .expect("with_usb");
}

#[test]
fn bad_reports_are_ignored_counted_and_unanswered() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let mut t = trajectory(0, 5000, 16_000, 16_000, 16_000);
            t[63] = 0x01; // "Must be always 0x00!"
            assert!(transact(&mut cls, &mut dev, &t).is_empty());
            assert!(transact(&mut cls, &mut dev, &out(0x42)).is_empty());
            assert!(transact(&mut cls, &mut dev, &t[..20]).is_empty());
            cls.run(300);
            assert_eq!(cls.chip(0).abs_pos(), 0);
            assert_eq!(cls.bridge.diag.usb_bad, 2);
            assert_eq!(cls.bridge.diag.usb_unknown, 1);
        })
        .expect("with_usb");
}

#[test]
fn an_output_report_by_set_report_is_taken_like_one_on_the_endpoint() {
    UsbCtx::default()
        .with_usb(|mut cls, mut dev| {
            let class = CtrRequestType::to_device().class().interface();
            let mut r = out(0xC1);
            r[0] = 0x02;
            dev.control_write(&mut cls, class, 0x09, 0x0202, 0, 64, &r)
                .expect("SET_REPORT");
            let answer = read(&mut cls, &mut dev);
            assert_eq!(answer[15], 0xC0);
        })
        .expect("with_usb");
}
