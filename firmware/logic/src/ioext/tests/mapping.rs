//! The box's use: shift-register bits → axis inputs, axis state → lamps,
//! through the registers and the simulated chips.

use super::*;

/// 16 bits, mode 0, auto-restart, debounce `k`, enabled.
fn box_rig(k: u16) -> Rig {
    let mut r = Rig::new();
    r.setup(16, SpiMode::MODE0, 10, cfg::AUTO_RESTART);
    r.write(addr::DEBOUNCE, &[k]).unwrap();
    // All inputs open (pull-ups: high).
    for i in 0..256 {
        r.chain.set_rx_bit(i, true);
    }
    r
}

fn entry(bit: u8, flag: bool) -> u16 {
    0x8000 | if flag { 0x4000 } else { 0 } | u16::from(bit)
}

/// Press (close) or release the contact on receive bit `i`.
fn contact(r: &mut Rig, i: usize, closed: bool) {
    r.chain.set_rx_bit(i, !closed);
}

#[test]
fn a_pressed_button_is_bin1_of_its_axis_after_k_transfers() {
    let mut r = box_rig(3);
    // Axis 2: BIN1 on receive bit 5 ('165 #0 input C), NO.
    r.write(addr::map(2, addr::BIN1), &[entry(5, false)])
        .unwrap();
    for _ in 0..3 {
        r.tick();
    }
    let released = Some(Contact {
        closed: false,
        active: false,
    });
    assert_eq!(r.io.inputs(2).bin1, released);
    contact(&mut r, 5, true);
    r.tick();
    r.tick();
    assert_eq!(r.io.inputs(2).bin1, released, "2 of 3 transfers");
    r.tick();
    assert_eq!(
        r.io.inputs(2).bin1,
        Some(Contact {
            closed: true,
            active: true
        })
    );
    // Nothing else is mapped.
    assert_eq!(r.io.inputs(2).bin2, None);
    assert_eq!(r.io.inputs(1), AxisInputs::default());
}

#[test]
fn a_bouncing_button_gives_one_clean_press() {
    let mut r = box_rig(5);
    r.write(addr::map(0, addr::BIN2), &[entry(9, false)])
        .unwrap();
    for _ in 0..5 {
        r.tick();
    }
    let mut presses = 0;
    let mut was = false;
    // Bounce for 12 transfers, then held.
    let bounce = [1, 0, 1, 1, 0, 1, 0, 0, 1, 1, 1, 0];
    for k in 0..30 {
        let closed = bounce.get(k).is_none_or(|b| *b == 1);
        contact(&mut r, 9, closed);
        r.tick();
        let now = r.io.inputs(0).bin2.unwrap().active;
        if now && !was {
            presses += 1;
        }
        was = now;
    }
    assert_eq!(presses, 1);
}

#[test]
fn a_released_nc_end_switch_reads_closed_and_not_active() {
    let mut r = box_rig(1);
    r.write(addr::map(1, addr::END_SWITCH), &[entry(14, true)])
        .unwrap();
    // NC switch, released: contact closed.
    contact(&mut r, 14, true);
    r.tick();
    assert_eq!(
        r.io.inputs(1).end_switch,
        Some(Contact {
            closed: true,
            active: false
        })
    );
    // Reached: the contact opens → active.
    contact(&mut r, 14, false);
    r.tick();
    assert_eq!(
        r.io.inputs(1).end_switch,
        Some(Contact {
            closed: false,
            active: true
        })
    );
}

#[test]
fn a_no_end_switch_is_active_when_closed() {
    let mut r = box_rig(1);
    r.write(addr::map(1, addr::END_SWITCH), &[entry(14, false)])
        .unwrap();
    r.tick();
    assert_eq!(
        r.io.inputs(1).end_switch,
        Some(Contact {
            closed: false,
            active: false
        })
    );
    contact(&mut r, 14, true);
    r.tick();
    assert_eq!(
        r.io.inputs(1).end_switch,
        Some(Contact {
            closed: true,
            active: true
        })
    );
}

#[test]
fn an_nc_end_switch_with_a_broken_wire_reads_active() {
    let mut r = box_rig(1);
    r.write(addr::map(0, addr::END_SWITCH), &[entry(3, true)])
        .unwrap();
    // A broken wire is an open contact: the pull-up reads high.
    r.tick();
    assert!(r.io.inputs(0).end_switch.unwrap().active);
}

#[test]
fn the_run_switch_runs_when_active_for_no_and_nc() {
    for nc in [false, true] {
        let mut r = box_rig(1);
        r.write(addr::map(4, addr::RUN), &[entry(0, nc)]).unwrap();
        contact(&mut r, 0, true);
        r.tick();
        assert_eq!(r.io.inputs(4).run.unwrap().active, !nc, "closed, nc {nc}");
        contact(&mut r, 0, false);
        r.tick();
        assert_eq!(r.io.inputs(4).run.unwrap().active, nc, "open, nc {nc}");
    }
}

#[test]
fn inputs_on_bits_the_transfer_does_not_clock_stay_unknown() {
    let mut r = box_rig(1);
    r.write(addr::map(0, addr::BIN1), &[entry(16, false)])
        .unwrap();
    r.tick();
    assert_eq!(r.io.inputs(0).bin1, None);
}

#[test]
fn changing_a_mapping_forgets_that_inputs_level() {
    let mut r = box_rig(2);
    r.write(addr::map(0, addr::BIN1), &[entry(1, false)])
        .unwrap();
    r.tick();
    r.tick();
    assert!(r.io.inputs(0).bin1.is_some());
    r.write(addr::map(0, addr::BIN1), &[entry(2, false)])
        .unwrap();
    assert_eq!(r.io.inputs(0).bin1, None);
    // Rewriting the same entry keeps it.
    r.tick();
    r.tick();
    r.write(addr::map(0, addr::BIN1), &[entry(2, false)])
        .unwrap();
    assert!(r.io.inputs(0).bin1.is_some());
}

#[test]
fn inputs_are_unknown_while_the_extension_is_off() {
    let mut r = box_rig(1);
    r.write(addr::map(0, addr::BIN1), &[entry(1, false)])
        .unwrap();
    r.tick();
    r.write(addr::IO_OPTIONS, &[0, 0]).unwrap();
    assert_eq!(r.io.inputs(0).bin1, None);
    r.io.tick(&[]);
    r.enable();
    assert_eq!(
        r.io.inputs(0).bin1,
        None,
        "forgotten when the port was released"
    );
    r.tick();
    assert!(r.io.inputs(0).bin1.is_some());
}

#[test]
fn lamps_show_axis_state_on_the_595_outputs() {
    let mut r = box_rig(1);
    // Axis 0 moving → tx bit 15 ('595 #0 QA after 16 bits); axis 1 fault →
    // tx bit 0 ('595 #1 QH), inverted; axis 1 idle → tx bit 8.
    r.write(addr::map(0, addr::MOVING), &[entry(15, false)])
        .unwrap();
    r.write(addr::map(1, addr::FAULT), &[entry(0, true)])
        .unwrap();
    r.write(addr::map(1, addr::IDLE), &[entry(8, false)])
        .unwrap();
    r.write(addr::TX, &[0x7F7F]).unwrap();
    let moving = AxisOutputs {
        moving: true,
        fault: false,
        idle: false,
    };
    let faulted = AxisOutputs {
        moving: false,
        fault: true,
        idle: true,
    };
    r.tick_with(&[moving, faulted]);
    assert!(r.chain.output(0, 0), "axis 0 moving: QA of '595 #0");
    assert!(
        !r.chain.output(1, 7),
        "axis 1 fault, inverted: QH of '595 #1 low"
    );
    assert!(r.chain.stage(7), "axis 1 idle: tx bit 8");
    // Unmapped bits carry the transmit register; it still reads as written.
    assert!(r.chain.tx_bit_output(16, 1));
    assert_eq!(r.read(addr::TX, 1).unwrap(), [0x7F7F]);
    // Next tick: state changed.
    r.tick_with(&[AxisOutputs::default(), AxisOutputs::default()]);
    assert!(!r.chain.output(0, 0));
    assert!(r.chain.output(1, 7));
    assert!(!r.chain.stage(7));
}

#[test]
fn the_mapping_persists_through_the_image() {
    let mut r = box_rig(7);
    r.write(
        addr::map(5, addr::BIN1),
        &[entry(200, true), entry(201, false)],
    )
    .unwrap();
    r.write(addr::map(5, addr::IDLE), &[entry(255, true)])
        .unwrap();
    let s = r.io.settings();
    let mut img = [0u8; IMAGE_LEN];
    s.encode(&mut img);
    let back = IoSettings::decode(&img).unwrap();
    assert_eq!(back, s);
    let mut again = Rig::with(back);
    assert_eq!(
        again.read(addr::map(5, 0), 8).unwrap(),
        r.read(addr::map(5, 0), 8).unwrap()
    );
    assert_eq!(again.read(addr::DEBOUNCE, 1).unwrap(), [7]);
    assert!(again.io.enabled());
    assert!(again.io.config().auto_restart());
}
