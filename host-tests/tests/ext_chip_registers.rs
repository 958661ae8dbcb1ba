//! Extension 0x01nn: direct powerSTEP01 register access over Modbus (and
//! the same map over I2C 0x72/0x73 and USB 0xE0/0xE1), against the bridge
//! on simulated chips. Frames are built with the harness's own CRC.

use bridge_logic::postep60::settings::{IMAGE_LEN, TUNABLE};
use bridge_logic::postep60::{PowerStage, Settings};
use bridge_logic::powerstep::registers::{Register, REGISTERS};
use bridge_logic::powerstep::Command;
use host_tests::i2c_bench::I2cBench;
use host_tests::modbus_bench::ModbusBench;
use stepbridge_sim::Fault;

fn line() -> ModbusBench {
    ModbusBench::new(2, Settings::FACTORY)
}

fn width(r: Register) -> u16 {
    if r.bytes() == 3 {
        2
    } else {
        1
    }
}

fn value(regs: &[u16]) -> u32 {
    regs.iter().fold(0, |v, r| v << 16 | u32::from(*r))
}

#[test]
fn every_register_reads_what_the_chip_holds() {
    let mut b = line();
    b.set_position(1, 12_345).unwrap();
    b.settle(30_000);
    for info in REGISTERS.iter() {
        let r = info.register;
        let got = b
            .read(1, 0x0100 | u16::from(r.address()), width(r))
            .expect("read");
        let want = b.chip(0).register(r);
        assert_eq!(value(&got), want, "{}", info.voltage_mode_name);
    }
    // ABS_POS: right-aligned, 22 bits over two registers, high word first.
    assert_eq!(b.read(1, 0x0101, 2), Ok(vec![0x0001, 0x81C8])); // 98 760 = 12 345 · 8
}

#[test]
fn a_read_goes_to_the_chip_as_getparam_and_a_status_read_clears_nothing() {
    let mut b = line();
    b.chip_mut(0).clear_log();
    let st = b.read(1, 0x011B, 1).expect("STATUS");
    assert!(b
        .chip(0)
        .received()
        .any(|c| *c == Command::GetParam(Register::Status)));
    assert_eq!(st[0] & 0x0002, 0x0002, "not busy");
    assert_eq!(
        b.server.stats().deferred,
        1,
        "answered after a control tick"
    );
}

#[test]
fn a_read_of_the_wrong_width_or_a_missing_register_is_an_illegal_address() {
    let mut b = line();
    assert_eq!(b.read(1, 0x0101, 1), Err(2), "ABS_POS needs two registers");
    assert_eq!(b.read(1, 0x0109, 2), Err(2), "KVAL_HOLD is one");
    assert_eq!(b.read(1, 0x0100, 1), Err(2));
    assert_eq!(b.read(1, 0x011C, 1), Err(2));
}

#[test]
fn registers_the_bridge_owns_are_read_only_here() {
    let mut b = line();
    for r in [
        Register::AbsPos,
        Register::ElPos,
        Register::Mark,
        Register::Speed,
        Register::Acc,
        Register::Dec,
        Register::MaxSpeed,
        Register::KvalHold,
        Register::KvalRun,
        Register::KvalAcc,
        Register::KvalDec,
        Register::AdcOut,
        Register::StepMode,
        Register::Status,
    ] {
        let a = 0x0100 | u16::from(r.address());
        let res = if width(r) == 2 {
            b.write_multiple(1, a, &[0, 1])
        } else {
            b.write(1, a, 1)
        };
        assert_eq!(res, Err(2), "{r:?}");
    }
}

#[test]
fn a_wr_register_is_written_at_any_time() {
    let mut b = line();
    b.set_position(1, 200_000).unwrap();
    b.run(100);
    assert_eq!(b.write(1, 0x0113, 0x1F), Ok(()), "OCD_TH while moving");
    b.run(5);
    assert_eq!(b.chip(0).register(Register::OcdTh), 0x1F);
}

#[test]
fn a_ws_register_is_refused_with_04_while_the_axis_moves() {
    let mut b = line();
    b.set_position(1, 5_000).unwrap();
    b.run(100);
    assert_eq!(b.write(1, 0x0117, 0x0F), Err(4), "ALARM_EN is WS");
    assert_eq!(b.chip(0).register(Register::AlarmEn), 0xFF);
    assert!(b.bridge.diag.refused >= 1);
    b.settle(60_000);
    assert_eq!(b.write(1, 0x0117, 0x0F), Ok(()));
    b.run(5);
    assert_eq!(b.chip(0).register(Register::AlarmEn), 0x0F);
    assert_eq!(
        b.chip(0).command_errors(),
        0,
        "the chip never had to refuse"
    );
}

#[test]
fn a_wh_register_needs_the_bridges_off() {
    let mut b = line();
    assert_eq!(
        b.write(1, 0x010E, 0x30),
        Err(4),
        "ST_SLP is WH: the bridges are on"
    );
    assert_eq!(b.write(1, 0x03, 0x0F), Ok(()), "sleep");
    b.run(10);
    assert_eq!(b.write(1, 0x010E, 0x30), Ok(()));
    b.run(5);
    assert_eq!(b.chip(0).register(Register::StSlp), 0x30);
    assert_eq!(b.chip(0).command_errors(), 0);
}

#[test]
fn min_speed_takes_only_zero_or_a_low_speed_optimisation_threshold() {
    let mut b = line();
    assert_eq!(b.write(1, 0x0108, 0x0123), Err(3));
    assert_eq!(b.write(1, 0x0108, 0x1123), Ok(()));
    b.run(5);
    assert_eq!(b.chip(0).register(Register::MinSpeed), 0x1123);
    // Streaming still reaches low speeds: LSPD_OPT makes the floor 0 … on
    // the real chip; the bridge's moves land exactly either way.
    b.write(1, 0x0108, 0).unwrap();
    b.set_position(1, 77).unwrap();
    b.settle(10_000);
    assert_eq!(b.chip(0).abs_pos(), 77 * 8);
}

#[test]
fn config_keeps_the_board_s_clock_and_sw_mode() {
    let mut b = line();
    b.write(1, 0x03, 0x0F).unwrap(); // bridges off: CONFIG is WH
    b.run(10);
    assert_eq!(b.write(1, 0x011A, 0x1F00), Ok(()));
    b.run(5);
    let board = PowerStage::REFERENCE.config_register();
    assert_eq!(
        b.chip(0).register(Register::Config),
        u32::from(0x1F00 | (board & 0x1F))
    );
}

#[test]
fn a_value_wider_than_the_register_is_an_illegal_value() {
    let mut b = line();
    assert_eq!(b.write(1, 0x0113, 0x20), Err(3), "OCD_TH has 5 bits");
}

#[test]
fn tuning_is_written_again_after_a_chip_reset() {
    let mut b = line();
    b.write(1, 0x0113, 0x17).unwrap();
    b.write(1, 0x0114, 0x09).unwrap();
    b.run(5);
    b.chip_mut(0).inject(Fault::PowerCycle);
    assert_eq!(b.chip(0).register(Register::OcdTh), 0x08);
    b.run(50);
    assert_eq!(b.chip(0).register(Register::OcdTh), 0x17);
    assert_eq!(b.chip(0).register(Register::StallTh), 0x09);
}

#[test]
fn tuning_persists_with_write_settings() {
    let mut b = line();
    b.write(1, 0x0113, 0x17).unwrap();
    b.write(1, 0x0115, 0x0300).unwrap();
    b.write(1, 0x3F, 0).unwrap();
    let mut img = [0u8; IMAGE_LEN];
    assert!(b.bridge.take_save(&mut img));
    b.bridge.saved(true);
    let s = Settings::from_image(&img).expect("image");
    assert_eq!(s.axes[0].tuning.get(Register::OcdTh), Some(0x17));
    assert_eq!(s.axes[0].tuning.get(Register::FsSpd), Some(0x0300));
    assert_eq!(s.axes[1].tuning.get(Register::OcdTh), None);
    // A new boot with that image: the chip gets them at setup.
    let mut b2 = ModbusBench::new(2, s);
    b2.run(20);
    assert_eq!(b2.chip(0).register(Register::OcdTh), 0x17);
    assert_eq!(b2.chip(0).register(Register::FsSpd), 0x0300);
    assert_eq!(b2.chip(1).register(Register::OcdTh), 0x08);
}

#[test]
fn the_tunable_registers_are_the_documented_thirteen() {
    let names: Vec<Register> = TUNABLE.to_vec();
    assert_eq!(names.len(), 13);
    for r in names {
        assert_ne!(
            r.access(),
            bridge_logic::powerstep::registers::Access::ReadOnly
        );
    }
}

#[test]
fn i2c_0x72_reads_a_register_after_a_tick_and_0x73_writes_one() {
    let mut b = I2cBench::new(2, Settings::FACTORY);
    // OCD_TH: first read "not yet" (status 1), after a tick [0, 0x00, 0x08].
    assert!(b.write(1, &[0x72, 0x01, 0x13, 1]));
    assert_eq!(b.read(1, 3).unwrap(), [1, 0, 0]);
    b.run(2);
    assert_eq!(b.read(1, 3).unwrap(), [0, 0x00, 0x08]);
    assert!(b.write(1, &[0x73, 0x01, 0x13, 0x00, 0x11]));
    assert_eq!(b.read(1, 1).unwrap(), [0], "written");
    b.run(2);
    assert_eq!(b.chip(0).register(Register::OcdTh), 0x11);
    assert!(b.write(1, &[0x73, 0x01, 0x01, 0x00, 0x11]));
    assert_eq!(
        b.read(1, 1).unwrap(),
        [10],
        "ABS_POS is read-only: illegal address"
    );
}

#[test]
fn a_wh_register_written_asleep_reaches_the_chip_even_when_a_wake_follows_at_once() {
    use bridge_logic::postep60::Request;
    // The filed sequence: asleep, 20 ms, GATECFG1 = 0x111 accepted, and the
    // wake before the next control tick. The write goes out before the
    // wake's HardStop (a WH register is refused once the bridges are on).
    // Also when a stop, a Set zero or a move follows the wake at once (each
    // ends HiZ too).
    let then = [
        None,
        Some(Request::Stop),
        Some(Request::SetZero),
        Some(Request::SetPosition(100)),
    ];
    for (reg, then) in [0x0118u16, 0x010F]
        .into_iter()
        .flat_map(|r| then.into_iter().map(move |t| (r, t)))
    {
        let mut b = line();
        b.bridge.request(0, Request::RunSleep(0x0F)).unwrap();
        b.run(20);
        let errors = b.chip(0).command_errors();
        let value = if reg == 0x0118 { 0x111 } else { 0x31 };
        assert_eq!(b.bridge.ext_write(0, reg, &[value]), Ok(()));
        b.bridge.request(0, Request::RunSleep(0xDA)).unwrap();
        if let Some(req) = then {
            b.bridge.request(0, req).unwrap();
        }
        b.run(20);
        let r = Register::from_address(reg as u8).unwrap();
        assert_eq!(
            b.chip(0).register(r),
            u32::from(value),
            "{r:?}, then {then:?}: the chip holds what was acknowledged"
        );
        assert_eq!(
            b.chip(0).command_errors(),
            errors,
            "{r:?}, then {then:?}: never refused"
        );
        assert!(!b.chip(0).is_hiz(), "awake again");
    }
}

#[test]
fn a_register_write_the_chip_refused_is_written_again_once_it_can_be() {
    use bridge_logic::postep60::Request;
    let mut b = line();
    b.bridge.request(0, Request::RunSleep(0x0F)).unwrap();
    b.run(20);
    assert_eq!(b.bridge.ext_write(0, 0x0118, &[0x0AB]), Ok(()));
    // Before the write goes out the chip leaves HiZ behind the bridge's
    // back (a HardStop it was never sent, as noise on SDI could make one):
    // the write reaches a chip with its bridges on and is refused.
    b.chip_mut(0).exchange(0xB8);
    assert!(!b.chip(0).is_hiz());
    b.run(20);
    // CMD_ERROR in the next STATUS puts it back on the list; asleep means
    // bridges off, so the chip is put back in HiZ; then it is written.
    assert!(b.chip(0).command_errors() >= 1, "the chip did refuse once");
    assert!(b.chip(0).is_hiz(), "asleep: bridges off again");
    assert_eq!(b.chip(0).register(Register::GateCfg1), 0x0AB);
}

/// Eight axes streaming at 5 kHz, overlapped, every batch within the 5
/// windows the period holds: a register read finds no room beside the
/// regular read and Run, and goes in a position read's place instead.
#[test]
fn a_register_read_beside_eight_streaming_axes_under_a_five_window_budget_arrives() {
    use bridge_logic::postep60::Request;
    use host_tests::clock::SimClock;
    use host_tests::sim_bridge::{chip, new_bridge_at, tick_overlapped};
    let mut b = new_bridge_at(8, Settings::FACTORY, PowerStage::REFERENCE, 200);
    tick_overlapped(&mut b, 8, 200);
    let mut clock = SimClock::new(200);
    clock.run(&mut b, 200);
    for k in 0..8 {
        let _ = b.request(k, Request::SetMode(4));
        let _ = b.request(k, Request::RunSleep(1));
        b.request(k, Request::SetPosition(2_000_000)).unwrap();
    }
    clock.run(&mut b, 2000);
    for (reg, words) in [
        (Register::Config, 1),
        (Register::Speed, 2),
        (Register::AbsPos, 2),
    ] {
        for k in [0, 5] {
            let address = 0x0100 | u16::from(reg.address());
            let mut out = vec![0u16; words];
            let mut ticks = 0;
            while b.ext_read(k, address, &mut out).is_err() {
                clock.tick(&mut b);
                ticks += 1;
                assert!(
                    ticks < 20,
                    "{reg:?} of axis {k} not read after {ticks} ticks"
                );
            }
            if reg == Register::Config {
                assert_eq!(u32::from(out[0]), chip(&b, k).register(reg));
            }
            assert!(!b.axis(k).unwrap().is_at_rest(), "axis {k} still streams");
        }
    }
}
