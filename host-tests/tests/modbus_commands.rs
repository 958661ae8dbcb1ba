//! Every PoStep60 Modbus command of manual §9.3 against the bridge and the
//! simulated chain: the ADU a master sends and the ADU it gets back (server
//! id, function, data, CRC low byte first), and what the motors do.
//! Registers are big-endian; the byte vectors follow the manual's tables.
//! Factory settings: axis 0 answers id 1, axis 1 id 2, 9600 baud even parity.

use bridge_logic::bridge::ResetTarget;
use bridge_logic::motion::axis::logical_to_physical;
use bridge_logic::postep60::settings::IMAGE_LEN;
use bridge_logic::postep60::{PowerStage, Settings};
use bridge_logic::powerstep::registers::Register;
use bridge_logic::powerstep::Direction;
use bridge_logic::powerstep::StepSel;
use host_tests::modbus_bench::ModbusBench;
use stepbridge_sim::Fault;

fn line() -> ModbusBench {
    ModbusBench::new(2, Settings::FACTORY)
}

/// Physical microsteps of a logical position in the factory step mode (1/16 on 1/128).
fn phys(pos: i64) -> i32 {
    logical_to_physical(pos, 4, StepSel::OneTwentyEighth) as i32
}

// ------------------------------------------------------------ 9.3.1-4 ----

#[test]
fn run_sleep_0x03_0x000f_sleeps_and_0x00da_runs_again() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x03, 0x00, 0x0F, 0x39, 0xCE]),
        Some([0x01, 0x06, 0x00, 0x03, 0x00, 0x0F, 0x39, 0xCE].to_vec())
    );
    b.run(10);
    assert!(b.chip(0).is_hiz());
    assert_eq!(b.read(1, 0x13, 1), Ok(vec![1]), "driver in sleep mode");
    // Motion is refused while asleep: exception 04.
    assert_eq!(
        b.transact(&[0x01, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x00, 0x00, 0x03, 0xE8, 0xF6, 0x2D]),
        Some([0x01, 0x90, 0x04, 0x4D, 0xC3].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x03, 0x00, 0xDA, 0xF8, 0x51]),
        Some([0x01, 0x06, 0x00, 0x03, 0x00, 0xDA, 0xF8, 0x51].to_vec())
    );
    b.run(10);
    assert!(!b.chip(0).is_hiz());
    assert_eq!(b.read(1, 0x13, 1), Ok(vec![2]));
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn run_sleep_0x03_other_values_are_ignored_with_a_normal_response() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x03, 0x00, 0x55, 0xB9, 0xF5]),
        Some([0x01, 0x06, 0x00, 0x03, 0x00, 0x55, 0xB9, 0xF5].to_vec())
    );
    assert_eq!(b.read(1, 0x13, 1), Ok(vec![2]));
    assert_eq!(b.server.stats().ignored_values, 1);
    assert_eq!(b.bridge.diag.refused, 1);
}

#[test]
fn set_address_0x04_is_new_in_byte1_current_in_byte0_and_the_reply_comes_from_the_old_id() {
    let mut b = line();
    // (0x20 << 8) | 0x01 to id 1: the reply still comes from id 1.
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x04, 0x20, 0x01, 0x10, 0x0B]),
        Some([0x01, 0x06, 0x00, 0x04, 0x20, 0x01, 0x10, 0x0B].to_vec())
    );
    assert_eq!(b.bridge.base_address(), 0x20);
    // Now axis 0 is 0x20 and axis 1 follows at 0x21; ids 1 and 2 are silent.
    assert_eq!(
        b.transact(&[0x20, 0x03, 0x00, 0x14, 0x00, 0x01, 0xC2, 0xBF]),
        Some([0x20, 0x03, 0x02, 0x00, 0x04, 0x05, 0x80].to_vec())
    );
    assert_eq!(b.read(0x21, 0x14, 1), Ok(vec![4]));
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x14, 0x00, 0x01, 0xC4, 0x0E]),
        None
    );
    assert_eq!(
        b.transact(&[0x02, 0x03, 0x00, 0x14, 0x00, 0x01, 0xC4, 0x3D]),
        None
    );
}

#[test]
fn set_address_0x04_sent_to_axis_1_gives_axis_1_the_new_address() {
    let mut b = line();
    assert_eq!(b.write(2, 0x04, 0x3002), Ok(()));
    assert_eq!(b.bridge.base_address(), 0x2F);
    assert_eq!(b.read(0x30, 0x14, 1), Ok(vec![4]));
    assert_eq!(b.read(0x2F, 0x14, 1), Ok(vec![4]));
}

#[test]
fn set_address_0x04_with_a_wrong_current_address_or_an_invalid_new_one_is_refused_with_04() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x04, 0x20, 0x07, 0x90, 0x09]),
        Some([0x01, 0x86, 0x04, 0x43, 0xA3].to_vec())
    );
    assert_eq!(b.write(1, 0x04, 0x0001), Err(4), "new address 0");
    assert_eq!(b.write(1, 0x04, 0x8001), Err(4), "new address 128");
    assert_eq!(b.write(2, 0x04, 0x0102), Err(4), "axis 0 would need id 0");
    // Axis 1 at 128: a valid Modbus id but no I2C address (one base serves both).
    assert_eq!(b.write(1, 0x04, 0x7F01), Err(4), "axis 1 would need 128");
    assert_eq!(
        b.read(1, 0x0349, 1),
        Ok(vec![6]),
        "why: bad address, axis 0"
    );
    assert_eq!(b.bridge.base_address(), 1);
}

#[test]
fn set_driver_mode_0x05_auto_run_then_position_control() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x05, 0x00, 0x06, 0x19, 0xC9]),
        Some([0x01, 0x06, 0x00, 0x05, 0x00, 0x06, 0x19, 0xC9].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x14, 0x00, 0x01, 0xC4, 0x0E]),
        Some([0x01, 0x03, 0x02, 0x00, 0x06, 0x38, 0x46].to_vec())
    );
    assert_eq!(b.write(1, 0x05, 4), Ok(()));
    assert_eq!(b.read(1, 0x14, 1), Ok(vec![4]));
}

#[test]
fn set_driver_mode_0x05_dc_motor_and_external_step_dir_are_refused_with_04() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x05, 0x00, 0x03, 0xD9, 0xCA]),
        Some([0x01, 0x86, 0x04, 0x43, 0xA3].to_vec())
    );
    // Mode 1 needs STEP routed to the chips; the reference board does not.
    assert_eq!(b.write(1, 0x05, 1), Err(4));
    // Codes the manual does not list are ignored, as on a PoStep60.
    assert_eq!(b.write(1, 0x05, 9), Ok(()));
    assert_eq!(b.read(1, 0x14, 1), Ok(vec![4]));
    assert_eq!(b.server.stats().ignored_values, 1);
}

#[test]
fn set_driver_mode_0x05_external_is_accepted_where_the_board_routes_step() {
    let board = PowerStage {
        step_dir_routed: true,
        ..PowerStage::REFERENCE
    };
    let mut b = ModbusBench::with_board(1, Settings::FACTORY, board);
    assert_eq!(b.write(1, 0x05, 1), Ok(()));
    assert_eq!(b.read(1, 0x14, 1), Ok(vec![1]));
}

#[test]
fn set_pwm_0x06_three_registers_by_fc_0x10_is_refused_with_04_and_moves_nothing() {
    let mut b = line();
    // Motor1 PWM 480 kHz, Motor1 100 % CCW, Motor2 100 % ACW.
    assert_eq!(
        b.transact(&[
            0x01, 0x10, 0x00, 0x06, 0x00, 0x03, 0x06, 0x00, 0x00, 0x64, 0x00, 0x00, 0x64, 0x18,
            0x44
        ]),
        Some([0x01, 0x90, 0x04, 0x4D, 0xC3].to_vec())
    );
    // One register by FC 0x06 is not the command's shape: 02.
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x06, 0x00, 0x00, 0x69, 0xCB]),
        Some([0x01, 0x86, 0x02, 0xC3, 0xA1].to_vec())
    );
    b.run(100);
    assert_eq!(b.chip(0).abs_pos(), 0);
    assert_eq!(b.chip(0).speed_reg(), 0);
}

// ---------------------------------------------------------- 9.3.5-16 ----

#[test]
fn hw_fw_info_0x0a_is_three_registers_driver_id_hw_fw() {
    let mut b = line();
    // 0x0041, HW 1.0, FW 1.9: the PoStep60 version the box reports (its
    // own version is in the extension space, 0x0343)
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x0A, 0x00, 0x03, 0x25, 0xC9]),
        Some([0x01, 0x03, 0x06, 0x00, 0x41, 0x01, 0x00, 0x01, 0x09, 0xDD, 0x10].to_vec())
    );
}

#[test]
fn voltage_0x10_is_0_072_v_per_lsb() {
    let mut b = line();
    // 333 · 0.072 = 23.98 V
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x10, 0x00, 0x01, 0x85, 0xCF]),
        Some([0x01, 0x03, 0x02, 0x01, 0x4D, 0x79, 0xE1].to_vec())
    );
}

#[test]
fn temperature_0x11_is_0_125_c_per_lsb() {
    let mut b = line();
    // 199 · 0.125 = 24.875 °C (25 °C sensor reading)
    let t = f64::from(b.read(1, 0x11, 1).unwrap()[0]) * 0.125;
    assert!((24.0..=26.0).contains(&t), "{t} °C");
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x11, 0x00, 0x01, 0xD4, 0x0F]),
        Some([0x01, 0x03, 0x02, 0x00, 0xC7, 0xF9, 0xD6].to_vec())
    );
}

#[test]
fn pin_statuses_0x12_are_bits_of_byte0() {
    let mut b = line();
    // bootloader override, sleep (run), BIN1, BIN2, end switch high
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x12, 0x00, 0x01, 0x24, 0x0F]),
        Some([0x01, 0x03, 0x02, 0x00, 0x73, 0xF9, 0xA1].to_vec())
    );
    b.chip_mut(0).set_switch(true);
    b.run(4);
    assert_eq!(b.read(1, 0x12, 1), Ok(vec![0x33]));
}

#[test]
fn driver_status_0x13_is_active_after_boot() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x13, 0x00, 0x01, 0x75, 0xCF]),
        Some([0x01, 0x03, 0x02, 0x00, 0x02, 0x39, 0x85].to_vec())
    );
}

#[test]
fn driver_mode_0x14_is_position_control_from_the_factory() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x02, 0x03, 0x00, 0x14, 0x00, 0x01, 0xC4, 0x3D]),
        Some([0x02, 0x03, 0x02, 0x00, 0x04, 0xFD, 0x87].to_vec())
    );
}

#[test]
fn currents_0x20_to_0x22_are_ai_in_byte1_and_tq_in_byte0() {
    let mut b = line();
    // 1.0 A → Tq 123, Ai 3; 0.5 A → Tq 61, Ai 3: 0.065 · BYTE0 / 2^BYTE1
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x20, 0x00, 0x01, 0x85, 0xC0]),
        Some([0x01, 0x03, 0x02, 0x03, 0x7B, 0xF8, 0x97].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x21, 0x00, 0x01, 0xD4, 0x00]),
        Some([0x01, 0x03, 0x02, 0x03, 0x3D, 0x79, 0x65].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x22, 0x00, 0x01, 0x24, 0x00]),
        Some([0x01, 0x03, 0x02, 0x03, 0x3D, 0x79, 0x65].to_vec())
    );
}

#[test]
fn step_mode_0x23_temperature_limit_0x24_and_faults_0x25_read_byte0() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x23, 0x00, 0x01, 0x75, 0xC0]),
        Some([0x01, 0x03, 0x02, 0x00, 0x04, 0xB9, 0x87].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x24, 0x00, 0x01, 0xC4, 0x01]),
        Some([0x01, 0x03, 0x02, 0x00, 0x50, 0xB8, 0x78].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x25, 0x00, 0x01, 0x95, 0xC1]),
        Some([0x01, 0x03, 0x02, 0x00, 0x00, 0xB8, 0x44].to_vec())
    );
}

// --------------------------------------------------------- 9.3.17-23 ----

#[test]
fn set_full_scale_current_0x30_round_trips_and_reaches_kval() {
    let mut b = line();
    // 2.5 A: Tq = 307 → 153, Ai 2: register 0x0299
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x30, 0x02, 0x99, 0x48, 0xCF]),
        Some([0x01, 0x06, 0x00, 0x30, 0x02, 0x99, 0x48, 0xCF].to_vec())
    );
    assert_eq!(b.read(1, 0x20, 1), Ok(vec![0x0299]));
    b.run(10);
    assert_eq!(b.chip(0).register(Register::KvalRun), 27);
}

#[test]
fn set_idle_0x31_and_overheat_0x32_currents_round_trip_and_clamp_at_6_a() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x31, 0x03, 0x64, 0xD9, 0x1E]),
        Some([0x01, 0x06, 0x00, 0x31, 0x03, 0x64, 0xD9, 0x1E].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x32, 0x03, 0xC8, 0x29, 0x63]),
        Some([0x01, 0x06, 0x00, 0x32, 0x03, 0xC8, 0x29, 0x63].to_vec())
    );
    assert_eq!(b.read(1, 0x21, 1), Ok(vec![0x0364]));
    assert_eq!(b.read(1, 0x22, 1), Ok(vec![0x03C8]));
    // 8.29 A is clamped to the manual's encoding of 6 A (Tq 184, Ai 1).
    assert_eq!(b.write(1, 0x32, 0x01FF), Ok(()));
    assert_eq!(b.read(1, 0x22, 1), Ok(vec![0x01B8]));
}

#[test]
fn set_step_mode_0x33_sets_0_to_8_and_ignores_the_rest_with_a_normal_response() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x33, 0x00, 0x08, 0x78, 0x03]),
        Some([0x01, 0x06, 0x00, 0x33, 0x00, 0x08, 0x78, 0x03].to_vec())
    );
    assert_eq!(b.read(1, 0x23, 1), Ok(vec![8]));
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x33, 0x00, 0x09, 0xB9, 0xC3]),
        Some([0x01, 0x06, 0x00, 0x33, 0x00, 0x09, 0xB9, 0xC3].to_vec())
    );
    assert_eq!(b.read(1, 0x23, 1), Ok(vec![8]));
    assert_eq!(b.server.stats().ignored_values, 1);
    assert_eq!(b.server.stats().exceptions, 0);
}

#[test]
fn set_temperature_limit_0x34_is_clamped_to_120() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x34, 0x00, 0x64, 0xC9, 0xEF]),
        Some([0x01, 0x06, 0x00, 0x34, 0x00, 0x64, 0xC9, 0xEF].to_vec())
    );
    assert_eq!(b.read(1, 0x24, 1), Ok(vec![100]));
    assert_eq!(b.write(1, 0x34, 200), Ok(()));
    assert_eq!(b.read(1, 0x24, 1), Ok(vec![120]));
}

#[test]
fn a_fault_refuses_motion_with_04_until_reset_faults_0x35() {
    let mut b = line();
    b.chip_mut(0).inject(Fault::Overcurrent);
    b.run(4);
    assert_eq!(b.read(1, 0x25, 1), Ok(vec![0b0000_0110]), "AOCP, BOCP");
    assert_eq!(b.set_position(1, 1000), Err(4));
    b.run(300);
    assert_eq!(b.chip(0).abs_pos(), 0);
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x35, 0x00, 0x00, 0x99, 0xC4]),
        Some([0x01, 0x06, 0x00, 0x35, 0x00, 0x00, 0x99, 0xC4].to_vec())
    );
    assert_eq!(b.read(1, 0x25, 1), Ok(vec![0]));
    assert_eq!(b.set_position(1, 1000), Ok(()));
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(1000));
}

#[test]
fn write_settings_0x3f_hands_out_the_image_once_every_axis_rests() {
    let mut b = line();
    let mut img = [0u8; IMAGE_LEN];
    assert_eq!(b.write(1, 0x51, 2000), Ok(()));
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x3F, 0x00, 0x00, 0xB9, 0xC6]),
        Some([0x01, 0x06, 0x00, 0x3F, 0x00, 0x00, 0xB9, 0xC6].to_vec())
    );
    assert!(b.bridge.take_save(&mut img));
    let s = Settings::from_image(&img).unwrap();
    assert_eq!(s.axes[0].max_speed, 2000);
}

#[test]
fn write_settings_0x3f_while_an_axis_moves_is_acknowledged_and_written_at_rest() {
    let mut b = line();
    let mut img = [0u8; IMAGE_LEN];
    assert_eq!(b.write(1, 0x51, 2000), Ok(()));
    assert_eq!(b.set_position(1, 20_000), Ok(()));
    b.run(50);
    // Acknowledged (no exception 04), pending while the axis moves.
    assert_eq!(b.write(1, 0x3F, 0), Ok(()));
    assert_eq!(b.read(1, 0x0346, 1), Ok(vec![3]), "pending");
    assert!(!b.bridge.take_save(&mut img));
    b.settle(60_000);
    assert!(b.bridge.take_save(&mut img));
    b.bridge.saved(true);
    assert_eq!(Settings::from_image(&img).unwrap().axes[0].max_speed, 2000);
    assert_eq!(b.read(1, 0x0346, 1), Ok(vec![1]));
}

// --------------------------------------------------------- 9.3.24-30 ----

#[test]
fn read_position_0x40_is_two_registers_high_word_first() {
    let mut b = line();
    // Set position 100 000 = 0x0001_86A0 by FC 0x10, two registers.
    assert_eq!(
        b.transact(&[0x01, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x00, 0x01, 0x86, 0xA0, 0xC5, 0x4B]),
        Some([0x01, 0x10, 0x00, 0x50, 0x00, 0x02, 0x41, 0xD9].to_vec())
    );
    b.settle(200_000);
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x40, 0x00, 0x02, 0xC5, 0xDF]),
        Some([0x01, 0x03, 0x04, 0x00, 0x01, 0x86, 0xA0, 0xC9, 0xEB].to_vec())
    );
    assert_eq!(b.chip(0).abs_pos(), phys(100_000));
}

#[test]
fn negative_positions_are_twos_complement() {
    let mut b = line();
    // −1000 = 0xFFFF_FC18
    assert_eq!(
        b.transact(&[0x02, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0xFF, 0xFF, 0xFC, 0x18, 0xB8, 0xF9]),
        Some([0x02, 0x10, 0x00, 0x50, 0x00, 0x02, 0x41, 0xEA].to_vec())
    );
    b.settle(30_000);
    assert_eq!(
        b.transact(&[0x02, 0x03, 0x00, 0x40, 0x00, 0x02, 0xC5, 0xEC]),
        Some([0x02, 0x03, 0x04, 0xFF, 0xFF, 0xFC, 0x18, 0x88, 0x1D].to_vec())
    );
    assert_eq!(b.chip(1).abs_pos(), phys(-1000));
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn profile_0x41_to_0x43_read_back_what_0x51_to_0x53_set() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x51, 0x07, 0xD0, 0xDB, 0xB7]),
        Some([0x01, 0x06, 0x00, 0x51, 0x07, 0xD0, 0xDB, 0xB7].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x52, 0x13, 0x88, 0x25, 0x4D]),
        Some([0x01, 0x06, 0x00, 0x52, 0x13, 0x88, 0x25, 0x4D].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x53, 0x27, 0x10, 0x63, 0xE7]),
        Some([0x01, 0x06, 0x00, 0x53, 0x27, 0x10, 0x63, 0xE7].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x41, 0x00, 0x01, 0xD4, 0x1E]),
        Some([0x01, 0x03, 0x02, 0x07, 0xD0, 0xBB, 0xE8].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x42, 0x00, 0x01, 0x24, 0x1E]),
        Some([0x01, 0x03, 0x02, 0x13, 0x88, 0xB5, 0x12].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x43, 0x00, 0x01, 0x75, 0xDE]),
        Some([0x01, 0x03, 0x02, 0x27, 0x10, 0xA2, 0x78].to_vec())
    );
}

#[test]
fn current_speed_0x44_reads_the_profile_speed_while_moving() {
    let mut b = line();
    assert_eq!(b.set_position(1, 1_000_000), Ok(()));
    b.run(2000); // 1000 steps/s² up to 1000 steps/s: at max speed after 1 s
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x44, 0x00, 0x01, 0xC4, 0x1F]),
        Some([0x01, 0x03, 0x02, 0x03, 0xE8, 0xB8, 0xFA].to_vec())
    );
}

#[test]
fn requested_speed_0x45_and_invert_0x46_read_zero_from_the_factory() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x45, 0x00, 0x01, 0x95, 0xDF]),
        Some([0x01, 0x03, 0x02, 0x00, 0x00, 0xB8, 0x44].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x46, 0x00, 0x01, 0x65, 0xDF]),
        Some([0x01, 0x03, 0x02, 0x00, 0x00, 0xB8, 0x44].to_vec())
    );
}

// --------------------------------------------------------- 9.3.31-39 ----

#[test]
fn set_position_0x50_moves_the_addressed_axis_exactly() {
    let mut b = line();
    // 12345 = 0x0000_3039 to id 2 (axis 1)
    assert_eq!(
        b.transact(&[0x02, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x00, 0x00, 0x30, 0x39, 0x2D, 0xC5]),
        Some([0x02, 0x10, 0x00, 0x50, 0x00, 0x02, 0x41, 0xEA].to_vec())
    );
    b.settle(60_000);
    assert_eq!(b.chip(1).abs_pos(), phys(12345));
    assert_eq!(b.chip(0).abs_pos(), 0);
    assert_eq!(b.position(2), 12345);
    assert_eq!(b.position(1), 0);
}

#[test]
fn set_position_0x50_needs_exactly_two_registers() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x50, 0x03, 0xE8, 0x89, 0x65]),
        Some([0x01, 0x86, 0x02, 0xC3, 0xA1].to_vec())
    );
    assert_eq!(b.write_multiple(1, 0x50, &[0, 1000, 0]), Err(2));
    b.run(200);
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn set_position_0x50_is_refused_with_04_outside_position_and_binx_modes() {
    let mut b = line();
    assert_eq!(b.write(1, 0x05, 6), Ok(()));
    assert_eq!(
        b.transact(&[0x01, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x00, 0x00, 0x03, 0xE8, 0xF6, 0x2D]),
        Some([0x01, 0x90, 0x04, 0x4D, 0xC3].to_vec())
    );
    b.run(500);
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn requested_speed_0x54_and_invert_0x55_run_the_motor_in_auto_run_only() {
    let mut b = line();
    // Position mode: not performable.
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x54, 0x00, 0xC8, 0xC9, 0x8C]),
        Some([0x01, 0x86, 0x04, 0x43, 0xA3].to_vec())
    );
    assert_eq!(b.write(1, 0x55, 1), Err(4));
    assert_eq!(b.write(1, 0x05, 6), Ok(()));
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x54, 0x00, 0xC8, 0xC9, 0x8C]),
        Some([0x01, 0x06, 0x00, 0x54, 0x00, 0xC8, 0xC9, 0x8C].to_vec())
    );
    b.run(1000);
    assert_eq!(b.read(1, 0x45, 1), Ok(vec![200]));
    assert_eq!(b.read(1, 0x44, 1), Ok(vec![200]));
    assert!(b.chip(0).abs_pos() > 0);
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x55, 0x00, 0x01, 0x58, 0x1A]),
        Some([0x01, 0x06, 0x00, 0x55, 0x00, 0x01, 0x58, 0x1A].to_vec())
    );
    b.run(1000);
    assert_eq!(b.read(1, 0x46, 1), Ok(vec![1]));
    // A magnitude (manual: BYTE1·256 + BYTE0); the chip runs in reverse.
    assert_eq!(b.read(1, 0x44, 1), Ok(vec![200]));
    assert_eq!(b.chip(0).status().direction(), Direction::Reverse);
}

#[test]
fn set_zero_0x5e_makes_required_and_actual_position_zero() {
    let mut b = line();
    assert_eq!(b.set_position(1, 1000), Ok(()));
    b.settle(30_000);
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x5E, 0x00, 0x00, 0xE8, 0x18]),
        Some([0x01, 0x06, 0x00, 0x5E, 0x00, 0x00, 0xE8, 0x18].to_vec())
    );
    b.settle(1000);
    assert_eq!(b.position(1), 0);
    assert_eq!(b.chip(0).abs_pos(), 0);
    assert_eq!(b.set_position(1, 100), Ok(()));
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(100));
}

#[test]
fn stop_0x5f_stops_at_once_without_a_ramp() {
    let mut b = line();
    assert_eq!(b.set_position(1, 1_000_000), Ok(()));
    b.run(1500);
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x5F, 0x00, 0x00, 0xB9, 0xD8]),
        Some([0x01, 0x06, 0x00, 0x5F, 0x00, 0x00, 0xB9, 0xD8].to_vec())
    );
    let stopped = b.chip(0).abs_pos();
    b.settle(1000);
    let held = b.chip(0).abs_pos();
    // The reply took ~25 ms on the wire at 9600 baud: within 1000 steps/s
    // · 30 ms = 30 steps = 240 µsteps of where the reply left it.
    assert!((held - stopped).abs() <= 240, "{stopped} → {held}");
    assert_eq!(b.chip(0).speed_reg(), 0);
}

#[test]
fn system_reset_0x60_is_requested_and_answered_first() {
    let mut b = line();
    assert_eq!(b.bridge.take_reset(), None);
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x60, 0x00, 0x00, 0x89, 0xD4]),
        Some([0x01, 0x06, 0x00, 0x60, 0x00, 0x00, 0x89, 0xD4].to_vec())
    );
    assert_eq!(b.bridge.take_reset(), Some(ResetTarget::Application));
}

// ------------------------------------------------------------ general ----

#[test]
fn single_register_commands_may_also_be_written_by_fc_0x10() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x10, 0x00, 0x51, 0x00, 0x01, 0x02, 0x0B, 0xB8, 0xAC, 0x93]),
        Some([0x01, 0x10, 0x00, 0x51, 0x00, 0x01, 0x50, 0x18].to_vec())
    );
    assert_eq!(b.read(1, 0x41, 1), Ok(vec![3000]));
}

#[test]
fn two_axes_at_ids_base_and_base_plus_1_move_independently() {
    let mut s = Settings::FACTORY;
    s.base_address = 100;
    let mut b = ModbusBench::new(2, s);
    assert_eq!(b.set_position(100, 500), Ok(()));
    assert_eq!(b.set_position(101, -700), Ok(()));
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(500));
    assert_eq!(b.chip(1).abs_pos(), phys(-700));
    assert_eq!(b.position(100), 500);
    assert_eq!(b.position(101), -700);
    // Nobody at 99 or 102.
    assert_eq!(
        b.transact(&[0x63, 0x03, 0x00, 0x40, 0x00, 0x02, 0xCD, 0x9D]),
        None
    );
    assert_eq!(
        b.transact(&[0x66, 0x03, 0x00, 0x40, 0x00, 0x02, 0xCD, 0xC8]),
        None
    );
}

#[test]
fn nineteen_thousand_two_hundred_baud_without_parity_works_the_same() {
    let mut s = Settings::FACTORY;
    s.serial = bridge_logic::postep60::settings::Serial::from_code(5).unwrap();
    let mut b = ModbusBench::new(1, s);
    assert_eq!(b.char_us, 573);
    assert_eq!(b.timing.t35_us, 2006);
    assert_eq!(b.set_position(1, 321), Ok(()));
    b.settle(30_000);
    assert_eq!(b.position(1), 321);
}

// ------------------------------------- motion truth on this bus (issue 8) ----

#[test]
fn a_target_right_after_stop_0x5f_arrives() {
    let mut b = line();
    b.set_position(1, 50_000).unwrap();
    b.run(300);
    assert_eq!(b.write(1, 0x5F, 0), Ok(()));
    b.set_position(1, -2_000).unwrap();
    b.settle(60_000);
    assert_eq!(b.position(1), -2_000);
    assert_eq!(b.chip(0).abs_pos(), phys(-2_000));
}

#[test]
fn set_zero_0x5e_reads_zero_at_once_and_the_next_target_is_in_the_new_coordinates() {
    let mut b = line();
    b.set_position(1, 50_000).unwrap();
    b.run(300);
    assert_eq!(b.write(1, 0x5E, 0), Ok(()));
    assert_eq!(b.position(1), 0, "the read right after the acknowledgement");
    b.set_position(1, 1_000).unwrap();
    b.settle(60_000);
    assert_eq!(b.position(1), 1_000);
    assert_eq!(b.chip(0).abs_pos(), phys(1_000));
}

#[test]
fn a_chip_reset_gets_the_configured_currents_back() {
    let mut b = line();
    // 2.0 A full scale: Tq 246, Ai 3 → registers [Ai, Tq] big-endian.
    assert_eq!(b.write(1, 0x30, 0x03F6), Ok(()));
    b.run(50);
    let run = b.chip(0).register(Register::KvalRun);
    assert_ne!(run, 0x29);
    b.chip_mut(0).inject(Fault::PowerCycle);
    b.run(50);
    for r in [
        Register::KvalHold,
        Register::KvalRun,
        Register::KvalAcc,
        Register::KvalDec,
    ] {
        assert_eq!(b.chip(0).register(r), run, "{r:?}");
    }
    assert_eq!(b.read(1, 0x25, 1), Ok(vec![0x20]), "UVLO latched");
}

#[test]
fn raising_acceleration_mid_move_never_passes_the_target() {
    let mut b = line();
    b.set_position(1, 3_000).unwrap();
    b.run(400);
    assert_eq!(b.write(1, 0x52, 0xFFFF), Ok(()));
    assert_eq!(b.write(1, 0x53, 0xFFFF), Ok(()));
    for _ in 0..20_000 {
        b.run(1);
        assert!(b.chip(0).abs_pos() <= phys(3_000) + 1, "passed the target");
    }
    assert_eq!(b.chip(0).abs_pos(), phys(3_000));
}

#[test]
fn limits_beyond_the_chip_read_back_clamped() {
    let mut b = line();
    assert_eq!(b.write(1, 0x33, 0), Ok(())); // full steps
    assert_eq!(b.write(1, 0x51, 0xFFFF), Ok(()));
    assert_eq!(b.write(1, 0x52, 0xFFFF), Ok(()));
    assert_eq!(b.read(1, 0x41, 1), Ok(vec![12_481]));
    assert_eq!(b.read(1, 0x42, 1), Ok(vec![39_712]));
    assert_eq!(b.bridge.diag.limit_clamps, 2);
}

#[test]
fn current_speed_0x44_reads_speeds_above_32767() {
    let mut b = line();
    assert_eq!(b.write(1, 0x33, 8), Ok(())); // 1/256
    assert_eq!(b.write(1, 0x51, 50_000), Ok(()));
    assert_eq!(b.write(1, 0x52, 0xFFFF), Ok(()));
    b.set_position(1, 10_000_000).unwrap();
    b.run(1500);
    assert_eq!(b.read(1, 0x44, 1), Ok(vec![50_000]));
}

#[test]
fn adcin_undervoltage_is_not_a_fault() {
    // An unused ADCIN may read as undervoltage for good (datasheet).
    let mut b = line();
    b.chip_mut(0).inject(Fault::AdcinLow);
    b.run(20);
    assert!(b.chip(0).status().uvlo_adc());
    assert_eq!(b.read(1, 0x25, 1), Ok(vec![0]));
    b.set_position(1, 800).unwrap();
    b.settle(20_000);
    assert_eq!(b.chip(0).abs_pos(), phys(800));
}
