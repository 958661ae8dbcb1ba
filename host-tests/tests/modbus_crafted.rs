//! Crafted requests, after libmodbus `tests/unit-test-client.c`
//! (`test_server`, `send_crafted_request` and the "slave reply" cases),
//! against our server: what gets an exception and which one, and what on a
//! multidrop bus must get no answer at all.
//!
//! Our server implements FC 0x03, 0x06 and 0x10 only, so where libmodbus's
//! own server answers 03 for coils, discrete inputs, input registers and
//! FC 0x17, ours answers 01 first (the Modbus spec checks the function
//! before the quantity). Exceptions come back as function | 0x80 (the product rules (`docs/PRODUCT.md`)).
//! Another server on the bus is id 18 (0x12), libmodbus's INVALID_SERVER_ID.

use bridge_logic::postep60::Settings;
use host_tests::modbus_bench::{adu, ModbusBench};
use stepbridge_sim::Fault;

fn line() -> ModbusBench {
    ModbusBench::new(2, Settings::FACTORY)
}

// ------------------------------------------------ quantity 0 and max+1 ----

#[test]
fn read_holding_registers_of_0_and_126_registers_are_illegal_data_value() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x01, 0x00, 0x00, 0x14, 0x0A]),
        Some([0x01, 0x83, 0x03, 0x01, 0x31].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x01, 0x00, 0x7E, 0x94, 0x2A]),
        Some([0x01, 0x83, 0x03, 0x01, 0x31].to_vec())
    );
    // … also where a command lives: the quantity is checked before the address.
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x40, 0x00, 0x00, 0x44, 0x1E]),
        Some([0x01, 0x83, 0x03, 0x01, 0x31].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x40, 0xFF, 0xFF, 0x45, 0xAE]),
        Some([0x01, 0x83, 0x03, 0x01, 0x31].to_vec())
    );
    // 125 is a legal quantity: no command has 125 registers, so 02.
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x40, 0x00, 0x7D, 0x84, 0x3F]),
        Some([0x01, 0x83, 0x02, 0xC0, 0xF1].to_vec())
    );
}

#[test]
fn coils_discrete_inputs_and_input_registers_are_illegal_functions_whatever_the_quantity() {
    let mut b = line();
    // FC 0x01 / 0x02 with 0 and MODBUS_MAX_READ_BITS + 1 = 2001 (0x07D1),
    // FC 0x04 with 0 and MODBUS_MAX_READ_REGISTERS + 1 = 126.
    assert_eq!(
        b.transact(&[0x01, 0x01, 0x00, 0x01, 0x00, 0x00, 0x6D, 0xCA]),
        Some([0x01, 0x81, 0x01, 0x81, 0x90].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x01, 0x00, 0x01, 0x07, 0xD1, 0xAF, 0xA6]),
        Some([0x01, 0x81, 0x01, 0x81, 0x90].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x02, 0x00, 0x01, 0x00, 0x00, 0x29, 0xCA]),
        Some([0x01, 0x82, 0x01, 0x81, 0x60].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x02, 0x00, 0x01, 0x07, 0xD1, 0xEB, 0xA6]),
        Some([0x01, 0x82, 0x01, 0x81, 0x60].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x04, 0x00, 0x01, 0x00, 0x00, 0xA1, 0xCA]),
        Some([0x01, 0x84, 0x01, 0x82, 0xC0].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x04, 0x00, 0x01, 0x00, 0x7E, 0x21, 0xEA]),
        Some([0x01, 0x84, 0x01, 0x82, 0xC0].to_vec())
    );
}

#[test]
fn write_and_read_registers_0x17_is_an_illegal_function() {
    let mut b = line();
    // read 0 at 0, MODBUS_MAX_WR_READ_REGISTERS + 1 = 126; write 1 register
    assert_eq!(
        b.transact(&[
            0x01, 0x17, 0x00, 0x00, 0x00, 0x7E, 0x00, 0x00, 0x00, 0x01, 0x02, 0x12, 0x34, 0x1E,
            0xBD
        ]),
        Some([0x01, 0x97, 0x01, 0x8F, 0xF0].to_vec())
    );
}

#[test]
fn write_multiple_registers_of_0_and_124_registers_are_illegal_data_value() {
    let mut b = line();
    // libmodbus's 13-byte request: 3 values of dummy data, quantity and
    // byte count crafted: (0, 0) then (MODBUS_MAX_WRITE_REGISTERS + 1, 6).
    assert_eq!(
        b.transact(&[
            0x01, 0x10, 0x00, 0x50, 0x00, 0x00, 0x00, 0x02, 0x2B, 0x00, 0x01, 0x00, 0x64, 0xB6,
            0x1B
        ]),
        Some([0x01, 0x90, 0x03, 0x0C, 0x01].to_vec())
    );
    assert_eq!(
        b.transact(&[
            0x01, 0x10, 0x00, 0x50, 0x00, 0x7C, 0x06, 0x02, 0x2B, 0x00, 0x01, 0x00, 0x64, 0xD7,
            0x6A
        ]),
        Some([0x01, 0x90, 0x03, 0x0C, 0x01].to_vec())
    );
    b.run(200);
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn write_multiple_with_a_byte_count_inconsistent_with_the_quantity_is_illegal_data_value() {
    let mut b = line();
    // quantity 2, byte count 6, 6 bytes
    assert_eq!(
        b.transact(&[
            0x01, 0x10, 0x00, 0x50, 0x00, 0x02, 0x06, 0x00, 0x00, 0x03, 0xE8, 0x00, 0x00, 0xA4,
            0x7D
        ]),
        Some([0x01, 0x90, 0x03, 0x0C, 0x01].to_vec())
    );
    // quantity 2, byte count 4, but 6 data bytes follow
    assert_eq!(
        b.transact(&[
            0x01, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x00, 0x00, 0x03, 0xE8, 0x00, 0x00, 0x87,
            0xBD
        ]),
        Some([0x01, 0x90, 0x03, 0x0C, 0x01].to_vec())
    );
    // quantity 2, byte count 4, only 2 data bytes
    assert_eq!(
        b.transact(&[0x01, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x03, 0xE8, 0x4A, 0xFB]),
        Some([0x01, 0x90, 0x03, 0x0C, 0x01].to_vec())
    );
    // consistent, but 3 registers where 0x50 has 2: illegal data address
    assert_eq!(
        b.transact(&[
            0x01, 0x10, 0x00, 0x50, 0x00, 0x03, 0x06, 0x00, 0x00, 0x03, 0xE8, 0x00, 0x00, 0x65,
            0xB1
        ]),
        Some([0x01, 0x90, 0x02, 0xCD, 0xC1].to_vec())
    );
    b.run(200);
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn write_multiple_coils_0x0f_is_an_illegal_function() {
    let mut b = line();
    assert_eq!(
        b.transact(&[
            0x01, 0x0F, 0x00, 0x50, 0x07, 0xB1, 0x06, 0x02, 0x2B, 0x00, 0x01, 0x00, 0x64, 0xE9,
            0x78
        ]),
        Some([0x01, 0x8F, 0x01, 0x85, 0xF0].to_vec())
    );
}

#[test]
fn a_write_single_register_of_the_wrong_length_is_illegal_data_value() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x5F, 0x00, 0x20, 0xB8]),
        Some([0x01, 0x86, 0x03, 0x02, 0x61].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x5F, 0x00, 0x00, 0x00, 0x19, 0xB2]),
        Some([0x01, 0x86, 0x03, 0x02, 0x61].to_vec())
    );
}

// ------------------------------------------------------ addresses (02) ----

#[test]
fn addresses_the_extension_space_does_not_have_are_illegal_data_addresses() {
    let mut b = line();
    // 0x0150: the chip has no register 0x50.
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x01, 0x50, 0x00, 0x01, 0x85, 0xE7]),
        Some([0x01, 0x83, 0x02, 0xC0, 0xF1].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x01, 0x5F, 0x00, 0x00, 0xB8, 0x24]),
        Some([0x01, 0x86, 0x02, 0xC3, 0xA1].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x10, 0xFF, 0x50, 0x00, 0x02, 0x04, 0x00, 0x00, 0x03, 0xE8, 0xB3, 0xD9]),
        Some([0x01, 0x90, 0x02, 0xCD, 0xC1].to_vec())
    );
    b.run(200);
    assert_eq!(b.chip(0).abs_pos(), 0);
}

#[test]
fn loopback_0x01_the_i2c_extensions_and_unknown_commands_are_illegal_addresses() {
    let mut b = line();
    for cmd in [
        0x00u16, 0x01, 0x02, 0x07, 0x26, 0x47, 0x56, 0x61, 0x70, 0x71, 0xFF,
    ] {
        assert_eq!(b.read(1, cmd, 1), Err(2), "read {cmd:#04x}");
        assert_eq!(b.write(1, cmd, 0), Err(2), "write {cmd:#04x}");
    }
}

#[test]
fn reading_a_write_only_command_or_writing_a_read_only_one_is_an_illegal_address() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x50, 0x00, 0x02, 0xC4, 0x1A]),
        Some([0x01, 0x83, 0x02, 0xC0, 0xF1].to_vec())
    );
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x00, 0x14, 0x00, 0x06, 0x49, 0xCC]),
        Some([0x01, 0x86, 0x02, 0xC3, 0xA1].to_vec())
    );
    assert_eq!(b.write_multiple(1, 0x40, &[0, 0]), Err(2));
    assert_eq!(b.read(1, 0x14, 1), Ok(vec![4]));
}

#[test]
fn a_quantity_other_than_the_command_register_count_is_an_illegal_address() {
    let mut b = line();
    // libmodbus's raw read: address 1, 5 registers
    assert_eq!(
        b.transact(&[0x01, 0x03, 0x00, 0x01, 0x00, 0x05, 0xD4, 0x09]),
        Some([0x01, 0x83, 0x02, 0xC0, 0xF1].to_vec())
    );
    // position is 2 registers, HW/FW info 3, everything else 1
    assert_eq!(b.read(1, 0x40, 1), Err(2));
    assert_eq!(b.read(1, 0x40, 3), Err(2));
    assert_eq!(b.read(1, 0x0A, 2), Err(2));
    assert_eq!(b.read(1, 0x14, 2), Err(2));
    assert_eq!(b.write_multiple(1, 0x51, &[1, 2]), Err(2));
}

// ---------------------------------------------------- performable (04) ----

#[test]
fn commands_the_axis_cannot_perform_answer_server_device_failure() {
    let mut b = line();
    b.chip_mut(1).inject(Fault::Overcurrent);
    b.run(4);
    assert_eq!(
        b.transact(&[0x02, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x00, 0x00, 0x03, 0xE8, 0xF9, 0x69]),
        Some([0x02, 0x90, 0x04, 0xBD, 0xC3].to_vec())
    );
    // Axis 0 is healthy.
    assert_eq!(b.set_position(1, 1000), Ok(()));
    assert_eq!(b.server.stats().exceptions, 1);
}

// ---------------------------------------------------- other servers ----

#[test]
fn no_response_for_another_server_id() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x12, 0x03, 0x00, 0x40, 0x00, 0x02, 0xC7, 0x7C]),
        None
    );
    assert_eq!(b.server.stats().other_ids, 1);
}

#[test]
fn a_request_and_its_response_for_another_server_are_both_ignored() {
    let mut b = line();
    // Indication then confirmation, as on an RS-485 bus (libmodbus 1-B).
    // The request asks for 257 registers: nonsense, but not ours to judge.
    b.put(&[0x12, 0x03, 0x00, 0x01, 0x01, 0x01, 0xD6, 0xF9]);
    b.pause(5_000);
    b.put(&[0x12, 0x03, 0x04, 0x00, 0x00, 0x00, 0x00, 0xD8, 0xF2]);
    assert!(b.collect().is_empty());
    // An invalid request for another server (libmodbus 1-C).
    assert_eq!(
        b.transact(&[0x12, 0x03, 0x00, 0x01, 0xFF, 0xFF, 0x17, 0x19]),
        None
    );
    assert_eq!(b.server.stats().other_ids, 3);
    assert_eq!(b.server.stats().exceptions, 0);
    // … and we are still in sync.
    assert_eq!(b.read(1, 0x14, 1), Ok(vec![4]));
}

#[test]
fn a_response_of_another_server_that_looks_like_a_request_for_us_is_not_executed() {
    let mut b = line();
    // Another server's FC 0x06 echo is shaped exactly like a request; only
    // the id tells them apart, and it is not ours.
    b.put(&[0x05, 0x06, 0x00, 0x5E, 0x00, 0x00, 0xE9, 0x9C]);
    b.pause(5_000);
    b.put(&[0x05, 0x06, 0x00, 0x5E, 0x00, 0x00, 0xE9, 0x9C]);
    assert!(b.collect().is_empty());
    assert_eq!(b.server.stats().other_ids, 2);
}

#[test]
fn ids_outside_1_to_247_are_never_answered() {
    // Axis 1 would sit at id 248: it is reachable over I2C only.
    let mut s = Settings::FACTORY;
    s.base_address = 247;
    let mut b = ModbusBench::new(2, s);
    assert_eq!(b.read(247, 0x14, 1), Ok(vec![4]));
    for id in 248..=255u8 {
        assert_eq!(
            b.transact(&adu(&[id, 0x03, 0x00, 0x14, 0x00, 0x01])),
            None,
            "id {id}"
        );
        assert_eq!(
            b.transact(&adu(&[
                id, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0, 0, 3, 0xE8
            ])),
            None
        );
    }
    b.run(200);
    assert_eq!(b.chip(1).abs_pos(), 0);
    assert_eq!(b.server.stats().other_ids, 16);
}

// --------------------------------------------------------- broadcast ----

#[test]
fn a_broadcast_read_gets_no_reply_and_the_next_request_is_answered() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x00, 0x03, 0x00, 0x14, 0x00, 0x01, 0xC5, 0xDF]),
        None
    );
    // not even an exception for a broken broadcast
    assert_eq!(
        b.transact(&[0x00, 0x03, 0x00, 0x14, 0x00, 0x00, 0x04, 0x1F]),
        None
    );
    assert_eq!(
        b.transact(&[0x00, 0x2B, 0x0E, 0x01, 0x00, 0x4D, 0xB7]),
        None
    );
    assert_eq!(
        b.transact(&[0x00, 0x06, 0x01, 0x5F, 0x00, 0x00, 0xB9, 0xF5]),
        None
    );
    assert_eq!(b.server.stats().broadcasts, 4);
    assert_eq!(b.server.stats().exceptions, 0);
    assert_eq!(b.read(1, 0x14, 1), Ok(vec![4]));
}

#[test]
fn a_broadcast_write_runs_on_every_axis_without_a_reply() {
    let mut b = ModbusBench::new(3, Settings::FACTORY);
    // Set position 800 on every axis, then max speed 2000 on every axis.
    assert_eq!(
        b.transact(&[0x00, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x00, 0x00, 0x03, 0x20, 0xF3, 0x47]),
        None
    );
    assert_eq!(
        b.transact(&[0x00, 0x06, 0x00, 0x51, 0x07, 0xD0, 0xDA, 0x66]),
        None
    );
    b.settle(30_000);
    for id in 1..=3u8 {
        assert_eq!(b.position(id), 800, "id {id}");
        assert_eq!(b.read(id, 0x41, 1), Ok(vec![2000]));
    }
    // A broadcast Stop while everything moves.
    assert_eq!(b.set_position(1, 1_000_000), Ok(()));
    assert_eq!(b.set_position(3, -1_000_000), Ok(()));
    b.run(500);
    assert_eq!(
        b.transact(&[0x00, 0x06, 0x00, 0x5F, 0x00, 0x00, 0xB8, 0x09]),
        None
    );
    b.settle(1000);
    assert!((0..3).all(|k| b.chip(k).speed_reg() == 0));
}

#[test]
fn a_broadcast_the_axes_refuse_is_still_silent() {
    let mut b = line();
    b.chip_mut(0).inject(Fault::Overcurrent);
    b.run(4);
    assert_eq!(
        b.transact(&[0x00, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x00, 0x00, 0x03, 0xE8, 0xF2, 0xD1]),
        None
    );
    b.settle(30_000);
    assert_eq!(b.position(1), 0, "faulted axis refused");
    assert_eq!(b.position(2), 1000, "healthy axis moved");
    assert_eq!(b.server.stats().exceptions, 0);
}

#[test]
fn a_broadcast_address_change_moves_only_the_axis_at_byte0() {
    let mut b = ModbusBench::new(3, Settings::FACTORY);
    // current 2 (axis 1) → 5: base becomes 4, axes at 4, 5, 6.
    assert_eq!(
        b.transact(&[0x00, 0x06, 0x00, 0x04, 0x05, 0x02, 0x4B, 0x4B]),
        None
    );
    assert_eq!(b.bridge.base_address(), 4);
    // current 5 → 4 would cascade if run on every axis in turn; it must
    // move the base by exactly one.
    assert_eq!(
        b.transact(&[0x00, 0x06, 0x00, 0x04, 0x04, 0x05, 0x0B, 0x19]),
        None
    );
    assert_eq!(b.bridge.base_address(), 3);
    assert_eq!(b.read(4, 0x14, 1), Ok(vec![4]));
}
