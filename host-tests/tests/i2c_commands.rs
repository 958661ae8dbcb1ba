//! Every PoStep60 I2C command of manual §8.3 against the bridge and the
//! simulated chain: the bytes a master sends, the bytes it gets back, and
//! what the motors do. Byte vectors follow the manual's formulas.

use bridge_logic::bridge::ResetTarget;
use bridge_logic::motion::axis::logical_to_physical;
use bridge_logic::postep60::analog::AnalogSample;
use bridge_logic::postep60::settings::{DriverMode, IMAGE_LEN};
use bridge_logic::postep60::{Inputs, PowerStage, Settings};
use bridge_logic::powerstep::registers::Register;
use bridge_logic::powerstep::Direction;
use bridge_logic::powerstep::StepSel;
use host_tests::i2c_bench::{le_i32, le_u16, I2cBench};
use stepbridge_sim::Fault;

const A0: u8 = 1; // factory address of axis 0
const A1: u8 = 2; // axis 1

fn bench() -> I2cBench {
    I2cBench::new(2, Settings::FACTORY)
}

/// Physical microsteps of a logical position in the factory step mode (1/16 on 1/128).
fn phys(pos: i64) -> i32 {
    logical_to_physical(pos, 4, StepSel::OneTwentyEighth) as i32
}

// ------------------------------------------------------------- protocol ----

#[test]
fn loopback_0x01_returns_the_four_bytes_written() {
    let mut b = bench();
    assert!(b.write(A0, &[0x01, 0xDE, 0xAD, 0xBE, 0xEF]));
    assert_eq!(b.read(A0, 4).unwrap(), [0xDE, 0xAD, 0xBE, 0xEF]);
}

#[test]
fn a_read_repeats_the_last_command() {
    let mut b = bench();
    b.write(A0, &[0x01, 1, 2, 3, 4]);
    assert_eq!(b.read(A0, 4).unwrap(), [1, 2, 3, 4]);
    assert_eq!(b.read(A0, 4).unwrap(), [1, 2, 3, 4]);
}

#[test]
fn reads_past_the_response_return_zeros() {
    let mut b = bench();
    assert_eq!(b.query(A0, 0x14, 4), [4, 0, 0, 0]);
}

#[test]
fn unknown_commands_are_ignored_counted_and_read_as_zeros() {
    let mut b = bench();
    assert!(b.write(A0, &[0x99, 1, 2]));
    assert_eq!(b.read(A0, 3).unwrap(), [0, 0, 0]);
    assert_eq!(b.bridge.diag.i2c_unknown, 1);
}

#[test]
fn short_writes_are_ignored() {
    let mut b = bench();
    b.write(A0, &[0x50, 0x10, 0x27]); // Set position needs 4 bytes
    b.run(50);
    assert_eq!(b.bridge.diag.i2c_short, 1);
    assert_eq!(b.chip(0).abs_pos(), 0);
    assert_eq!(b.chip(0).speed_reg(), 0);
}

#[test]
fn other_addresses_are_not_acknowledged() {
    let mut b = bench();
    assert!(!b.write(3, &[0x14]));
    assert!(b.read(0x50, 1).is_none());
}

// ---------------------------------------------------------------- reads ----

#[test]
fn hw_fw_info_0x0a_is_driver_id_0x41_then_versions() {
    let mut b = bench();
    // FW 1.9 (0x0109): the PoStep60 version the box reports, so the PoStep60
    // application neither pushes an update nor applies its errata
    // workarounds; the box's own version is at extension 0x0343.
    assert_eq!(b.query(A0, 0x0A, 5), [0x41, 1, 0, 1, 9]);
}

#[test]
fn voltage_0x10_is_0_072_v_per_lsb_little_endian() {
    let mut b = bench();
    let v = b.query(A0, 0x10, 2);
    // 24 V supply: (BYTE1·256 + BYTE0)·0.072 ≈ 24
    let volts = f64::from(le_u16(&v)) * 0.072;
    assert!((23.9..=24.1).contains(&volts), "{volts} V from {v:?}");
    assert_eq!(v, [0x4D, 0x01]); // 333
}

#[test]
fn temperature_0x11_is_0_125_c_per_lsb_little_endian() {
    let mut b = bench();
    let t = f64::from(le_u16(&b.query(A0, 0x11, 2))) * 0.125;
    assert!((24.0..=26.0).contains(&t), "{t} °C");
}

#[test]
fn pin_statuses_0x12_report_bootloader_enable_buttons_and_end_switch() {
    let mut b = bench();
    assert_eq!(b.query(A0, 0x12, 1), [0b0111_0011]);
    b.chip_mut(0).set_switch(true); // closed pulls the input low
    b.bridge.on_inputs(
        0,
        Inputs {
            bin1: true,
            bin2: false,
            ..Inputs::default()
        },
    );
    b.run(4);
    assert_eq!(b.query(A0, 0x12, 1), [0b0010_0011]);
}

#[test]
fn driver_status_0x13_is_active_after_boot() {
    let mut b = bench();
    assert_eq!(b.query(A0, 0x13, 1), [2]);
}

#[test]
fn driver_mode_0x14_is_position_control_from_the_factory() {
    let mut b = bench();
    assert_eq!(b.query(A0, 0x14, 1), [4]);
}

#[test]
fn currents_0x20_to_0x22_read_tq_then_ai() {
    let mut b = bench();
    // 1.0 A → Tq 123, Ai 3; 0.5 A → Tq 61, Ai 3 (manual's loop)
    assert_eq!(b.query(A0, 0x20, 2), [123, 3]);
    assert_eq!(b.query(A0, 0x21, 2), [61, 3]);
    assert_eq!(b.query(A0, 0x22, 2), [61, 3]);
}

#[test]
fn step_mode_0x23_reads_the_logical_step_mode() {
    let mut b = bench();
    assert_eq!(b.query(A0, 0x23, 1), [4]);
}

#[test]
fn temperature_limit_0x24_reads_degrees() {
    let mut b = bench();
    assert_eq!(b.query(A0, 0x24, 1), [80]);
}

#[test]
fn faults_0x25_are_zero_on_a_healthy_chip() {
    let mut b = bench();
    assert_eq!(b.query(A0, 0x25, 1), [0]);
}

#[test]
fn position_0x40_is_four_bytes_lsb_first() {
    let mut b = bench();
    b.write(A0, &[0x50, 0x10, 0x27, 0x00, 0x00]); // 10 000
    b.settle(30_000);
    assert_eq!(b.query(A0, 0x40, 4), [0x10, 0x27, 0x00, 0x00]);
    assert_eq!(b.chip(0).abs_pos(), phys(10_000));
}

#[test]
fn negative_positions_are_twos_complement() {
    let mut b = bench();
    b.write(A0, &[0x50, 0x18, 0xFC, 0xFF, 0xFF]); // −1000
    b.settle(30_000);
    assert_eq!(le_i32(&b.query(A0, 0x40, 4)), -1000);
    assert_eq!(b.chip(0).abs_pos(), phys(-1000));
}

#[test]
fn profile_0x41_to_0x43_read_back_what_0x51_to_0x53_set() {
    let mut b = bench();
    b.write(A0, &[0x51, 0xD0, 0x07]); // 2000 steps/s
    b.write(A0, &[0x52, 0x88, 0x13]); // 5000 steps/s²
    b.write(A0, &[0x53, 0x10, 0x27]); // 10000 steps/s²
    assert_eq!(b.query(A0, 0x41, 2), [0xD0, 0x07]);
    assert_eq!(b.query(A0, 0x42, 2), [0x88, 0x13]);
    assert_eq!(b.query(A0, 0x43, 2), [0x10, 0x27]);
}

#[test]
fn current_speed_0x44_reads_the_profile_speed_while_moving() {
    let mut b = bench();
    b.write(A0, &[0x50, 0x40, 0x42, 0x0F, 0x00]); // 1 000 000
    b.run(2000); // 1000 steps/s², max 1000 steps/s: at max speed after 1 s
    assert_eq!(le_u16(&b.query(A0, 0x44, 2)), 1000);
}

#[test]
fn requested_speed_0x45_and_invert_0x46_read_zero_from_the_factory() {
    let mut b = bench();
    assert_eq!(b.query(A0, 0x45, 2), [0, 0]);
    assert_eq!(b.query(A0, 0x46, 1), [0]);
}

// --------------------------------------------------------------- writes ----

#[test]
fn run_sleep_0x03_0x0f_sleeps_and_0xda_runs_again() {
    let mut b = bench();
    b.write(A0, &[0x03, 0x0F]);
    b.run(10);
    assert_eq!(b.query(A0, 0x13, 1), [1]);
    assert!(b.chip(0).is_hiz());
    b.write(A0, &[0x50, 0xE8, 0x03, 0, 0]); // ignored while asleep
    b.run(200);
    assert_eq!(b.chip(0).abs_pos(), 0);
    b.write(A0, &[0x03, 0xDA]);
    b.run(10);
    assert_eq!(b.query(A0, 0x13, 1), [2]);
    assert!(!b.chip(0).is_hiz());
}

#[test]
fn run_sleep_ignores_other_values() {
    let mut b = bench();
    b.write(A0, &[0x03, 0x55]);
    b.run(10);
    assert_eq!(b.query(A0, 0x13, 1), [2]);
    assert_eq!(b.bridge.diag.refused, 1);
}

#[test]
fn address_0x04_moves_axis_0_and_axis_1_follows() {
    let mut b = bench();
    assert!(b.write(A0, &[0x04, 1, 0x20]));
    assert!(b.bridge.take_address_change());
    assert_eq!(b.bridge.i2c_addresses(), (0x20, Some(0x21)));
    assert_eq!(b.query(0x20, 0x14, 1), [4]);
    assert!(!b.write(A0, &[0x14]));
}

#[test]
fn address_0x04_sent_to_axis_1_gives_axis_1_the_new_address() {
    let mut b = bench();
    b.write(A1, &[0x04, 2, 0x30]);
    assert_eq!(b.bridge.i2c_addresses(), (0x2F, Some(0x30)));
}

#[test]
fn address_0x04_needs_byte0_equal_to_the_current_address() {
    let mut b = bench();
    b.write(A0, &[0x04, 7, 0x20]);
    assert_eq!(b.bridge.i2c_addresses(), (1, Some(2)));
    assert!(!b.bridge.take_address_change());
}

#[test]
fn address_0x04_accepts_only_1_to_127() {
    let mut b = bench();
    b.write(A0, &[0x04, 1, 0]);
    b.write(A0, &[0x04, 1, 128]);
    assert_eq!(b.bridge.i2c_addresses(), (1, Some(2)));
    // axis 1 cannot take address 1: axis 0 would need address 0
    b.write(A1, &[0x04, 2, 1]);
    assert_eq!(b.bridge.i2c_addresses(), (1, Some(2)));
}

#[test]
fn address_0x04_that_would_leave_an_axis_without_a_7_bit_address_is_refused() {
    // The filed case: 2 axes, 04 01 7F: axis 0 at 127 would put axis 1 at
    // 128, which is no I2C address. Refused, and why is readable.
    let mut b = bench();
    b.write(A0, &[0x04, 1, 0x7F]);
    assert_eq!(b.bridge.i2c_addresses(), (1, Some(2)), "unchanged");
    let mut r = [0u16];
    b.bridge.ext_read(0, 0x0349, &mut r).unwrap();
    assert_eq!(r, [6], "last refusal: axis 0, bad address");
    // 126 is fine: axis 1 gets 127.
    b.write(A0, &[0x04, 1, 126]);
    assert_eq!(b.bridge.i2c_addresses(), (126, Some(127)));
    assert_eq!(b.query(126, 0x14, 1), [4]);
    assert_eq!(b.query(127, 0x14, 1), [4]);
}

#[test]
fn driver_mode_0x05_accepts_auto_run() {
    let mut b = bench();
    b.write(A0, &[0x05, 6]);
    assert_eq!(b.query(A0, 0x14, 1), [6]);
}

#[test]
fn driver_mode_0x05_refuses_dc_motor_and_external_step_dir_on_this_board() {
    let mut b = bench();
    b.write(A0, &[0x05, 3]);
    b.write(A0, &[0x05, 1]);
    b.write(A0, &[0x05, 2]);
    b.write(A0, &[0x05, 9]);
    assert_eq!(b.query(A0, 0x14, 1), [4]);
    assert_eq!(b.bridge.diag.refused, 4);
}

#[test]
fn driver_mode_1_is_accepted_where_the_board_routes_step() {
    let board = PowerStage {
        step_dir_routed: true,
        ..PowerStage::REFERENCE
    };
    let mut b = I2cBench::with_board(1, Settings::FACTORY, board);
    b.write(A0, &[0x05, 1]);
    assert_eq!(b.query(A0, 0x14, 1), [1]);
}

#[test]
fn set_pwm_0x06_is_refused_and_moves_nothing() {
    let mut b = bench();
    b.write(A0, &[0x06, 1, 1, 0x64, 0, 0x64, 0]);
    b.run(100);
    assert_eq!(b.chip(0).abs_pos(), 0);
    assert_eq!(b.bridge.diag.refused, 1);
}

#[test]
fn full_scale_current_0x30_round_trips_and_reaches_kval() {
    let mut b = bench();
    // 2.5 A: Tq = 307 → 153, Ai 2
    b.write(A0, &[0x30, 153, 2]);
    assert_eq!(b.query(A0, 0x20, 2), [153, 2]);
    b.run(10);
    // 0.065·153/4 = 2.486 A · 1 Ω / 24 V · 256 = 26.5 → 27
    assert_eq!(b.chip(0).register(Register::KvalRun), 27);
    assert_eq!(b.chip(0).register(Register::KvalHold), 27);
}

#[test]
fn currents_above_6_a_are_clamped_to_the_manual_encoding_of_6_a() {
    let mut b = bench();
    b.write(A0, &[0x30, 255, 1]); // 8.29 A
    assert_eq!(b.query(A0, 0x20, 2), [184, 1]);
    b.write(A0, &[0x31, 255, 0]); // 16.6 A
    assert_eq!(b.query(A0, 0x21, 2), [184, 1]);
    b.write(A0, &[0x32, 200, 1]); // 6.5 A
    assert_eq!(b.query(A0, 0x22, 2), [184, 1]);
}

#[test]
fn idle_and_overheat_currents_0x31_0x32_round_trip() {
    let mut b = bench();
    b.write(A0, &[0x31, 100, 3]);
    b.write(A0, &[0x32, 200, 3]);
    assert_eq!(b.query(A0, 0x21, 2), [100, 3]);
    assert_eq!(b.query(A0, 0x22, 2), [200, 3]);
}

#[test]
fn step_mode_0x33_sets_0_to_8_and_ignores_the_rest() {
    let mut b = bench();
    b.write(A0, &[0x33, 8]);
    assert_eq!(b.query(A0, 0x23, 1), [8]);
    b.write(A0, &[0x33, 9]);
    assert_eq!(b.query(A0, 0x23, 1), [8]);
}

#[test]
fn step_mode_change_keeps_the_physical_position() {
    let mut b = bench();
    b.write(A0, &[0x50, 0xE8, 0x03, 0, 0]); // 1000 sixteenth steps
    b.settle(30_000);
    b.write(A0, &[0x33, 2]); // quarter steps
    b.settle(1000);
    assert_eq!(le_i32(&b.query(A0, 0x40, 4)), 250);
    assert_eq!(b.chip(0).abs_pos(), phys(1000));
    b.write(A0, &[0x50, 0xF4, 0x01, 0, 0]); // 500 quarter steps
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), 500 * 32);
}

#[test]
fn temperature_limit_0x34_is_clamped_to_120() {
    let mut b = bench();
    b.write(A0, &[0x34, 100]);
    assert_eq!(b.query(A0, 0x24, 1), [100]);
    b.write(A0, &[0x34, 200]);
    assert_eq!(b.query(A0, 0x24, 1), [120]);
}

#[test]
fn overcurrent_sets_aocp_and_bocp_and_reset_faults_0x35_clears_them() {
    let mut b = bench();
    b.chip_mut(0).inject(Fault::Overcurrent);
    b.run(4);
    assert_eq!(b.query(A0, 0x25, 1), [0b0000_0110]);
    b.write(A0, &[0x35]);
    assert_eq!(b.query(A0, 0x25, 1), [0]);
}

#[test]
fn a_latched_fault_refuses_set_position_until_reset() {
    let mut b = bench();
    b.chip_mut(0).inject(Fault::Overcurrent);
    b.run(4);
    b.write(A0, &[0x50, 0xE8, 0x03, 0, 0]);
    b.run(300);
    assert_eq!(b.chip(0).abs_pos(), 0);
    b.write(A0, &[0x35]);
    b.write(A0, &[0x50, 0xE8, 0x03, 0, 0]);
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(1000));
}

#[test]
fn thermal_shutdown_sets_ots_until_the_chip_cools() {
    let mut b = bench();
    b.chip_mut(1).inject(Fault::ThermalShutdown);
    b.run(4);
    assert_eq!(b.query(A1, 0x25, 1)[0] & 1, 1);
    b.write(A1, &[0x35]);
    b.run(4);
    assert_eq!(
        b.query(A1, 0x25, 1)[0] & 1,
        1,
        "OTS cannot be cleared while hot"
    );
    b.chip_mut(1).inject(Fault::ThermalNormal);
    b.run(4);
    assert_eq!(b.query(A1, 0x25, 1), [0], "cooled: cleared by itself");
}

#[test]
fn stall_sets_std_and_stdlat_without_stopping() {
    let mut b = bench();
    b.chip_mut(0).inject(Fault::Stall);
    let mut seen = 0;
    for _ in 0..3 {
        b.run(1);
        seen |= b.query(A0, 0x25, 1)[0];
        if seen & 0x40 != 0 {
            break;
        }
    }
    assert_eq!(seen & 0xC0, 0xC0);
    b.run(4);
    assert_eq!(
        b.query(A0, 0x25, 1)[0] & 0xC0,
        0x80,
        "STD follows, STDLAT stays"
    );
}

#[test]
fn undervoltage_sets_the_uvlo_fault() {
    let mut b = bench();
    b.chip_mut(0).inject(Fault::Uvlo);
    b.run(10);
    assert_eq!(b.query(A0, 0x25, 1)[0] & 0x20, 0x20);
}

#[test]
fn write_settings_0x3f_while_an_axis_moves_is_written_once_every_axis_rests() {
    // The filed case: temperature limit 44 °C (0x34 0x2C), a move, 0x3F 50 ms
    // into it. Accepted, pending while the axis moves, written at rest with
    // the settings it was accepted with.
    let mut b = bench();
    let mut img = [0u8; IMAGE_LEN];
    b.write(A0, &[0x34, 0x2C]);
    b.write(A0, &[0x50, 0x10, 0x27, 0, 0]);
    b.run(50);
    b.write(A0, &[0x3F]);
    assert_eq!(b.bridge.diag.refused, 0, "accepted");
    assert!(!b.bridge.take_save(&mut img), "not while the axis moves");
    let mut pending = [0u16];
    b.bridge.ext_read(0, 0x0346, &mut pending).unwrap();
    assert_eq!(pending, [3], "visible as pending");
    // A change after the acknowledged save is not part of it.
    b.write(A0, &[0x34, 0x30]);
    b.settle(30_000);
    assert!(b.bridge.take_save(&mut img), "written at rest");
    b.bridge.saved(true);
    let s = Settings::from_image(&img).unwrap();
    assert_eq!(s.axes[0].temperature_limit, 44);
    b.bridge.ext_read(0, 0x0346, &mut pending).unwrap();
    assert_eq!(pending, [1], "saved");
}

#[test]
fn write_settings_0x3f_at_rest_hands_out_the_image_once() {
    let mut b = bench();
    let mut img = [0u8; IMAGE_LEN];
    b.write(A0, &[0x51, 0xD0, 0x07]);
    b.write(A0, &[0x3F]);
    assert!(b.bridge.take_save(&mut img));
    assert!(!b.bridge.take_save(&mut img), "once");
    b.bridge.saved(true);
    let s = Settings::from_image(&img).unwrap();
    assert_eq!(s, b.bridge.settings());
    assert_eq!(s.axes[0].max_speed, 2000);
}

#[test]
fn nothing_can_start_a_move_while_settings_are_being_written() {
    let mut b = bench();
    let mut img = [0u8; IMAGE_LEN];
    b.write(A0, &[0x3F]);
    assert!(b.bridge.take_save(&mut img));
    // The flash is being programmed: a Set position must not start a move.
    b.write(A0, &[0x50, 0x10, 0x27, 0, 0]);
    b.run(200);
    assert_eq!(b.chip(0).abs_pos(), 0);
    b.bridge.saved(true);
    b.write(A0, &[0x50, 0x10, 0x27, 0, 0]);
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(10_000));
}

#[test]
fn set_position_0x50_moves_to_the_target_exactly() {
    let mut b = bench();
    b.write(A1, &[0x50, 0x39, 0x30, 0, 0]); // 12345
    b.settle(60_000);
    assert_eq!(b.chip(1).abs_pos(), phys(12345));
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn set_position_0x50_is_refused_outside_position_and_binx_modes() {
    let mut b = bench();
    b.write(A0, &[0x05, 6]); // auto run at requested speed 0
    b.write(A0, &[0x50, 0xE8, 0x03, 0, 0]);
    b.run(500);
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn requested_speed_0x54_and_invert_0x55_work_only_in_auto_run() {
    let mut b = bench();
    b.write(A0, &[0x54, 0xC8, 0x00]); // 200 steps/s, position mode: ignored
    assert_eq!(b.query(A0, 0x45, 2), [0, 0]);
    b.write(A0, &[0x05, 6]);
    b.write(A0, &[0x54, 0xC8, 0x00]);
    b.run(1000);
    assert_eq!(b.query(A0, 0x45, 2), [0xC8, 0x00]);
    assert_eq!(le_u16(&b.query(A0, 0x44, 2)), 200);
    b.write(A0, &[0x55, 0x01]);
    b.run(1000);
    assert_eq!(b.query(A0, 0x46, 1), [1]);
    // Current speed is a magnitude (manual: BYTE1·256 + BYTE0); the chip
    // runs in reverse now.
    assert_eq!(le_u16(&b.query(A0, 0x44, 2)), 200);
    assert_eq!(b.chip(0).status().direction(), Direction::Reverse);
}

#[test]
fn set_zero_0x5e_makes_required_and_actual_position_zero() {
    let mut b = bench();
    b.write(A0, &[0x50, 0xE8, 0x03, 0, 0]);
    b.settle(30_000);
    b.write(A0, &[0x5E]);
    b.settle(1000);
    assert_eq!(b.query(A0, 0x40, 4), [0, 0, 0, 0]);
    assert_eq!(b.chip(0).abs_pos(), 0);
    b.write(A0, &[0x50, 0x64, 0, 0, 0]);
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(100));
}

#[test]
fn stop_0x5f_stops_at_once_without_a_ramp() {
    let mut b = bench();
    b.write(A0, &[0x50, 0x40, 0x42, 0x0F, 0x00]);
    b.run(1500);
    b.write(A0, &[0x5F]);
    b.run(3);
    let stopped = b.chip(0).abs_pos();
    b.settle(1000);
    let held = b.chip(0).abs_pos();
    // Stopped within the tick that carried the HardStop (1000 steps/s · 1 ms
    // = 1 step = 8 µsteps), and held there: no landing move afterwards.
    assert_eq!(held, stopped, "no move after the stop");
    assert_eq!(b.chip(0).speed_reg(), 0);
    // The position reads as the logical step at or below the chip.
    assert_eq!(
        i64::from(le_i32(&b.query(A0, 0x40, 4))),
        i64::from(held).div_euclid(8)
    );
}

#[test]
fn system_reset_0x60_stops_every_axis_then_is_handed_out() {
    let mut b = bench();
    assert_eq!(b.bridge.take_reset(), None);
    b.write(A1, &[0x50, 0x40, 0x42, 0x0F, 0x00]);
    b.run(500);
    b.write(A0, &[0x60]);
    assert_eq!(b.bridge.take_reset(), None, "not while axis 1 moves");
    b.run(20);
    assert_eq!(b.bridge.take_reset(), Some(ResetTarget::Application));
    assert_eq!(b.chip(1).speed_reg(), 0);
}

#[test]
fn soft_stop_extension_0x71_decelerates_with_dec() {
    let mut b = bench();
    b.write(A0, &[0x50, 0x40, 0x42, 0x0F, 0x00]);
    b.run(1500);
    b.write(A0, &[0x71]);
    b.settle(5000);
    let pos = le_i32(&b.query(A0, 0x40, 4));
    // From 1000 steps/s at 1000 steps/s²: ~500 steps of braking after 1000 steps.
    assert!((1400..=1600).contains(&pos), "{pos}");
}

#[test]
fn select_axis_extension_0x70_reaches_every_axis_from_one_address() {
    let mut b = I2cBench::new(4, Settings::FACTORY);
    b.write(A0, &[0x70, 3]);
    assert_eq!(b.read(A0, 2).unwrap(), [3, 4]);
    b.write(A0, &[0x50, 0x64, 0, 0, 0]);
    b.settle(30_000);
    assert_eq!(b.chip(3).abs_pos(), phys(100));
    assert_eq!(b.chip(0).abs_pos(), 0);
    b.write(A0, &[0x70, 9]); // no such axis: ignored
    assert_eq!(b.read(A0, 2).unwrap(), [3, 4]);
}

// ------------------------------------------------- behaviour over time ----

#[test]
fn hold_current_drops_to_idle_current_10_s_after_motion() {
    let mut b = bench();
    b.write(A0, &[0x50, 0x64, 0, 0, 0]);
    b.settle(30_000);
    let full = b.chip(0).register(Register::KvalHold);
    b.run(9_000);
    assert_eq!(b.query(A0, 0x13, 1), [2]);
    assert_eq!(b.chip(0).register(Register::KvalHold), full);
    b.run(1_100);
    assert_eq!(b.query(A0, 0x13, 1), [3]);
    // 0.5 A · 1 Ω / 24 V · 256 = 5.3 → 5 (idle); run current unchanged
    assert_eq!(b.chip(0).register(Register::KvalHold), 5);
    assert_eq!(b.chip(0).register(Register::KvalRun), full);
}

#[test]
fn motion_ends_idle_and_restores_the_full_hold_current() {
    let mut b = bench();
    b.run(10_100);
    assert_eq!(b.query(A0, 0x13, 1), [3]);
    b.write(A0, &[0x50, 0x64, 0, 0, 0]);
    b.run(5);
    assert_eq!(b.query(A0, 0x13, 1), [2]);
    assert_eq!(b.chip(0).register(Register::KvalHold), 11);
}

#[test]
fn above_the_temperature_limit_currents_drop_to_the_overheat_current() {
    let mut b = bench();
    // 90 °C: 0.76 V + 65·2.5 mV = 0.9225 V = 1145 counts at VDDA 3.2988 V
    b.bridge.on_analog(AnalogSample {
        supply: 1490,
        temperature: 1145,
        vrefint: 1502,
    });
    b.run(4);
    assert_eq!(b.query(A0, 0x13, 1), [4]);
    assert_eq!(b.chip(0).register(Register::KvalRun), 5);
    assert_eq!(b.chip(0).register(Register::KvalHold), 5);
    // Back below limit − 2 °C: full current again.
    b.bridge.on_analog(AnalogSample::NOMINAL_24V_25C);
    b.run(4);
    assert_eq!(b.query(A0, 0x13, 1), [2]);
    assert_eq!(b.chip(0).register(Register::KvalRun), 11);
}

fn settings_with(f: impl Fn(&mut bridge_logic::postep60::AxisSettings)) -> Settings {
    let mut s = Settings::FACTORY;
    for a in s.axes.iter_mut() {
        f(a);
    }
    s
}

#[test]
fn an_end_switch_edge_stops_the_axis_and_a_new_target_either_way_is_accepted() {
    let mut b = I2cBench::new(
        1,
        settings_with(|a| {
            a.end_switch = true;
            a.max_speed = 2000;
        }),
    );
    b.write(A0, &[0x50, 0x40, 0x42, 0x0F, 0x00]);
    b.run(800);
    b.chip_mut(0).set_switch(true);
    b.run(4);
    let at_switch = b.chip(0).abs_pos();
    b.settle(2000);
    assert!((b.chip(0).abs_pos() - at_switch).abs() <= 16);
    // Either direction works afterwards, the switch still closed.
    b.write(A0, &[0x50, 0x00, 0x00, 0x00, 0x00]);
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), 0);
    b.write(A0, &[0x50, 0x10, 0x27, 0x00, 0x00]);
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(10_000));
}

#[test]
fn a_disabled_end_switch_does_not_stop_the_axis() {
    let mut b = I2cBench::new(1, Settings::FACTORY);
    b.write(A0, &[0x50, 0x10, 0x27, 0x00, 0x00]);
    b.run(300);
    b.chip_mut(0).set_switch(true);
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(10_000));
}

#[test]
fn binx_buttons_move_by_bin1_and_bin2_steps() {
    let mut b = I2cBench::new(
        1,
        settings_with(|a| {
            a.mode = DriverMode::BinButtons;
            a.bin1_steps = 300;
            a.bin2_steps = -120;
        }),
    );
    b.bridge.on_inputs(
        0,
        Inputs {
            bin1: true,
            bin2: false,
            ..Inputs::default()
        },
    );
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(300));
    b.bridge.on_inputs(
        0,
        Inputs {
            bin1: false,
            bin2: false,
            ..Inputs::default()
        },
    );
    b.bridge.on_inputs(
        0,
        Inputs {
            bin1: false,
            bin2: true,
            ..Inputs::default()
        },
    );
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(180));
    // Holding a button does not repeat.
    b.bridge.on_inputs(
        0,
        Inputs {
            bin1: false,
            bin2: true,
            ..Inputs::default()
        },
    );
    b.run(500);
    assert_eq!(b.chip(0).abs_pos(), phys(180));
}

#[test]
fn binx_buttons_do_nothing_in_position_mode() {
    let mut b = bench();
    b.bridge.on_inputs(
        0,
        Inputs {
            bin1: true,
            bin2: false,
            ..Inputs::default()
        },
    );
    b.run(500);
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn auto_run_starts_at_power_up_with_max_speed() {
    let mut b = I2cBench::new(
        1,
        settings_with(|a| {
            a.mode = DriverMode::AutoRun;
            a.max_speed = 500;
            a.requested_speed = 100;
        }),
    );
    b.run(2000);
    assert_eq!(le_u16(&b.query(A0, 0x44, 2)), 500);
    assert!(b.chip(0).abs_pos() > 0);
}

#[test]
fn auto_run_with_invert_runs_backwards() {
    let mut b = I2cBench::new(
        1,
        settings_with(|a| {
            a.mode = DriverMode::AutoRun;
            a.max_speed = 500;
            a.invert = true;
        }),
    );
    b.run(2000);
    assert!(b.chip(0).abs_pos() < 0);
}

#[test]
fn stop_and_set_zero_keep_a_sleeping_axis_unpowered() {
    let mut b = bench();
    b.write(A0, &[0x03, 0x0F]);
    b.run(10);
    b.write(A0, &[0x5F]);
    b.write(A0, &[0x5E]);
    b.run(50);
    assert!(b.chip(0).is_hiz());
    assert_eq!(b.query(A0, 0x13, 1), [1]);
}

#[test]
fn auto_run_does_not_start_on_a_faulted_axis() {
    let mut b = bench();
    b.write(A0, &[0x05, 6]);
    b.chip_mut(0).inject(Fault::Overcurrent);
    b.run(4);
    b.write(A0, &[0x05, 4]);
    b.write(A0, &[0x05, 6]); // requested speed 0 anyway; power-up path below
    b.run(200);
    assert_eq!(b.chip(0).abs_pos(), 0);
    let mut s = Settings::FACTORY;
    s.axes[0].mode = DriverMode::AutoRun;
    s.axes[0].max_speed = 500;
    let mut b = I2cBench::new(1, s);
    b.chip_mut(0).inject(Fault::Overcurrent);
    b.run(2000);
    // It started at power-up, then the overcurrent stopped it and it stays stopped.
    let p = b.chip(0).abs_pos();
    b.run(1000);
    assert_eq!(b.chip(0).abs_pos(), p);
}

#[test]
fn ots_clears_by_itself_once_the_chip_has_cooled() {
    // Manual 8.3.17: "OTS bit will clear once temperature has fallen to safe
    // levels"; Reset faults cannot clear it.
    let mut b = bench();
    b.write(A0, &[0x50, 0x10, 0x27, 0, 0]);
    b.run(100);
    b.chip_mut(0).inject(Fault::ThermalShutdown);
    b.run(4);
    assert_eq!(b.query(A0, 0x25, 1)[0] & 1, 1);
    let stopped_at = b.chip(0).abs_pos();
    b.chip_mut(0).inject(Fault::ThermalNormal);
    b.run(10);
    assert_eq!(b.query(A0, 0x25, 1), [0], "cleared, no Reset faults needed");
    // The axis stays where it stopped until a new motion command.
    b.run(500);
    assert_eq!(b.chip(0).abs_pos(), stopped_at);
    b.write(A0, &[0x50, 0x10, 0x27, 0, 0]);
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(10_000));
}

// ------------------------------------- motion truth on this bus (issue 8) ----

#[test]
fn a_target_right_after_stop_0x5f_arrives() {
    let mut b = bench();
    b.write(A0, &[0x50, 0x50, 0xC3, 0, 0]); // 50 000
    b.run(300);
    b.write(A0, &[0x5F]);
    b.write(A0, &[0x50, 0x30, 0xF8, 0xFF, 0xFF]); // −2000
    b.settle(60_000);
    assert_eq!(le_i32(&b.query(A0, 0x40, 4)), -2000);
    assert_eq!(b.chip(0).abs_pos(), phys(-2000));
}

#[test]
fn set_zero_0x5e_reads_zero_at_once_and_the_next_target_is_in_the_new_coordinates() {
    let mut b = bench();
    b.write(A0, &[0x50, 0x50, 0xC3, 0, 0]);
    b.run(300);
    b.write(A0, &[0x5E]);
    assert_eq!(b.query(A0, 0x40, 4), [0, 0, 0, 0]);
    b.write(A0, &[0x50, 0xE8, 0x03, 0, 0]); // 1000
    b.settle(60_000);
    assert_eq!(le_i32(&b.query(A0, 0x40, 4)), 1000);
    assert_eq!(b.chip(0).abs_pos(), phys(1000));
}

#[test]
fn a_chip_reset_gets_the_configured_currents_back() {
    let mut b = bench();
    b.write(A0, &[0x30, 246, 3]); // 2.0 A full scale
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
    assert_eq!(b.query(A0, 0x25, 1), [0x20], "UVLO latched");
}

#[test]
fn raising_acceleration_mid_move_never_passes_the_target() {
    let mut b = bench();
    b.write(A0, &[0x50, 0xB8, 0x0B, 0, 0]); // 3000
    b.run(400);
    b.write(A0, &[0x52, 0xFF, 0xFF]);
    b.write(A0, &[0x53, 0xFF, 0xFF]);
    for _ in 0..20_000 {
        b.run(1);
        assert!(b.chip(0).abs_pos() <= phys(3000) + 1, "passed the target");
    }
    assert_eq!(b.chip(0).abs_pos(), phys(3000));
}

#[test]
fn limits_beyond_the_chip_read_back_clamped() {
    let mut b = bench();
    b.write(A0, &[0x33, 0]); // full steps
    b.write(A0, &[0x51, 0xFF, 0xFF]);
    b.write(A0, &[0x52, 0xFF, 0xFF]);
    assert_eq!(le_u16(&b.query(A0, 0x41, 2)), 12_481);
    assert_eq!(le_u16(&b.query(A0, 0x42, 2)), 39_712);
    assert_eq!(b.bridge.diag.limit_clamps, 2);
}

#[test]
fn current_speed_0x44_reads_speeds_above_32767() {
    let mut b = bench();
    b.write(A0, &[0x33, 8]); // 1/256
    b.write(A0, &[0x51, 0x50, 0xC3]); // 50 000
    b.write(A0, &[0x52, 0xFF, 0xFF]);
    b.write(A0, &[0x50, 0x80, 0x96, 0x98, 0x00]); // 10 000 000
    b.run(1500);
    assert_eq!(le_u16(&b.query(A0, 0x44, 2)), 50_000);
}

#[test]
fn moving_off_a_pressed_end_switch_completes_the_move() {
    // Manual §6: "End switch reacts only on change of end switch state.
    // Position change request after end switch touched can be set in either
    // direction." The box stops when the switch becomes pressed (closed for
    // a normally open switch, open for a normally closed one), not when it
    // is released: a move off the switch runs to its target.
    use stepbridge_sim::HomeCam;
    for nc in [false, true] {
        let mut b = I2cBench::new(
            1,
            settings_with(|a| {
                a.end_switch = true;
                a.end_switch_nc = nc;
                a.max_speed = 2000;
            }),
        );
        let edge = i64::from(phys(-1000));
        b.chip_mut(0).set_home_cam(Some(HomeCam { edge, nc }));
        b.run(20);
        // Into the switch: stopped just past its pressed edge.
        b.write(A0, &[0x50, 0x48, 0xF4, 0xFF, 0xFF]); // −3000
        b.settle(30_000);
        let at = i64::from(b.chip(0).abs_pos());
        assert!(
            (edge - 8 * 16..=edge).contains(&at),
            "nc {nc}: stopped at {at}, the edge is {edge}"
        );
        // Off it: the release edge does not stop the move.
        b.write(A0, &[0x50, 0xD0, 0x07, 0x00, 0x00]); // 2000
        b.settle(30_000);
        assert_eq!(
            b.chip(0).abs_pos(),
            phys(2000),
            "nc {nc}: the move off the switch arrived"
        );
        // And into it again from the other side: stopped again.
        b.write(A0, &[0x50, 0x48, 0xF4, 0xFF, 0xFF]);
        b.settle(30_000);
        let at = i64::from(b.chip(0).abs_pos());
        assert!((edge - 8 * 16..=edge).contains(&at), "nc {nc}: {at}");
    }
}

#[test]
fn a_write_longer_than_its_command_does_not_move_and_is_counted() {
    let mut b = bench();
    // 25 bytes: beyond the slave's 16-byte buffer.
    let mut long = vec![0x50, 0x40, 0x01, 0x00, 0x00];
    long.extend([0u8; 20]);
    b.write(A0, &long);
    // One byte more than 0x50 takes.
    b.write(A0, &[0x50, 0xA0, 0x00, 0x00, 0x00, 0x00]);
    // A query with a stray data byte, and 0x73 with half a register.
    b.write(A0, &[0x40, 0x00]);
    b.write(A0, &[0x73, 0x01, 0x13, 0x00, 0x17, 0x00]);
    b.run(500);
    assert_eq!(b.chip(0).abs_pos(), 0, "nothing moved");
    assert_eq!(b.bridge.diag.i2c_long, 4);
    assert_eq!(
        b.read(A0, 4).unwrap(),
        [0, 0, 0, 0],
        "a read after it returns zeros"
    );
    // The well-formed command still works.
    b.write(A0, &[0x50, 0xA0, 0x00, 0x00, 0x00]);
    b.settle(30_000);
    assert_eq!(b.chip(0).abs_pos(), phys(160));
}

/// `fault` while axis 0 streams: the bridges go off and stay off, and the
/// shaft stands (through the device model, which stops the axis too).
fn a_fault_while_moving_switches_the_bridges_off(fault: Fault) {
    let mut b = bench();
    // Far away: the axis streams when the fault comes.
    b.write(A0, &[0x50, 0x40, 0x9C, 0, 0]);
    b.run(300);
    assert!(!b.chip(0).is_hiz(), "moving");
    b.chip_mut(0).inject(fault);
    b.run(20);
    assert!(b.chip(0).is_hiz(), "bridges off after {fault:?}");
    let p = b.chip(0).abs_pos();
    b.run(500);
    assert_eq!(b.chip(0).abs_pos(), p, "and nothing moves after it");
    assert!(b.chip(0).is_hiz(), "still off");
}

#[test]
fn an_overcurrent_while_moving_switches_the_bridges_off_through_the_device_model() {
    a_fault_while_moving_switches_the_bridges_off(Fault::Overcurrent);
}

#[test]
fn a_thermal_shutdown_while_moving_switches_the_bridges_off_through_the_device_model() {
    a_fault_while_moving_switches_the_bridges_off(Fault::ThermalShutdown);
}
