//! Which window the MCU's independent watchdog must have
//! (`Bridge::watchdog_window`, applied by the firmware): short whenever an
//! axis may move, long only from a `take_save` that handed out an image
//! until `saved`, while every axis rests and every request is refused.
//! Driven over I2C on two simulated chips; the save's flash work is the
//! firmware's housekeeping, played here by `take_save` … `saved`.

use bridge_logic::bridge::WatchdogWindow::{Long, Short};
use bridge_logic::postep60::settings::IMAGE_LEN;
use bridge_logic::postep60::Settings;
use host_tests::i2c_bench::I2cBench;
use host_tests::rng::Rng;
use host_tests::sim_bridge::all_settled;

const A0: u8 = 1;
const A1: u8 = 2;

fn bench() -> I2cBench {
    I2cBench::new(2, Settings::FACTORY)
}

/// Set position (0x50) of the axis at `addr`.
fn go(b: &mut I2cBench, addr: u8, pos: i32) {
    let p = pos.to_le_bytes();
    b.write(addr, &[0x50, p[0], p[1], p[2], p[3]]);
}

/// Any simulated chip moving (its SPEED register) or busy.
fn chips_moving(b: &I2cBench) -> bool {
    (0..2).any(|k| b.chip(k).speed_reg() != 0 || b.chip(k).is_busy())
}

#[test]
fn short_from_boot_and_while_an_axis_moves() {
    let mut b = bench();
    assert_eq!(b.bridge.watchdog_window(), Short);
    go(&mut b, A0, 20_000);
    let mut moved = 0;
    for _ in 0..2_000 {
        b.run(1);
        moved += usize::from(chips_moving(&b));
        assert_eq!(b.bridge.watchdog_window(), Short);
    }
    assert!(moved > 100, "the axis moved ({moved} ms)");
}

#[test]
fn long_only_from_take_save_until_saved() {
    for ok in [true, false] {
        let mut b = bench();
        let mut img = [0u8; IMAGE_LEN];
        b.write(A0, &[0x3F]);
        b.run(5);
        assert_eq!(
            b.bridge.watchdog_window(),
            Short,
            "a pending save is not enough"
        );
        assert!(b.bridge.take_save(&mut img));
        assert_eq!(b.bridge.watchdog_window(), Long);
        // Ticks run between the flash operations: still long, and a move
        // asked for meanwhile is refused.
        go(&mut b, A1, 10_000);
        for _ in 0..200 {
            b.run(1);
            assert_eq!(b.bridge.watchdog_window(), Long);
            assert!(!chips_moving(&b));
        }
        b.bridge.saved(ok);
        assert_eq!(b.bridge.watchdog_window(), Short, "saved({ok})");
        go(&mut b, A1, 10_000);
        b.run(50);
        assert!(chips_moving(&b));
        assert_eq!(b.bridge.watchdog_window(), Short);
    }
}

#[test]
fn a_save_requested_at_rest_stays_short_while_a_move_started_after_it_runs() {
    let mut b = bench();
    let mut img = [0u8; IMAGE_LEN];
    b.write(A0, &[0x3F]);
    go(&mut b, A0, 5_000);
    b.run(20);
    assert!(chips_moving(&b));
    assert!(!b.bridge.take_save(&mut img), "not handed out while moving");
    assert_eq!(b.bridge.watchdog_window(), Short);
    b.settle(30_000);
    assert!(b.bridge.take_save(&mut img));
    assert_eq!(b.bridge.watchdog_window(), Long);
    b.bridge.saved(true);
    assert_eq!(b.bridge.watchdog_window(), Short);
}

/// Random moves, stops and saves on both axes, the firmware's housekeeping
/// every 100 ms (a handed-out save holds for 0–300 ms of ticks): at every
/// tick, long means every axis settled and no chip moving.
#[test]
fn random_moves_and_saves_never_leave_a_moving_axis_in_the_long_window() {
    let mut rng = Rng(0x5744_4F47_1D0F_0001);
    let mut b = bench();
    let mut img = [0u8; IMAGE_LEN];
    let (mut longs, mut saves) = (0u32, 0u32);
    let mut saving: Option<u64> = None;
    for ms in 0..60_000u64 {
        let addr = if rng.below(2) == 0 { A0 } else { A1 };
        match rng.below(400) {
            0..=2 => go(&mut b, addr, rng.range(-20_000, 20_000) as i32),
            3 => {
                b.write(addr, &[0x5F]);
            }
            4..=6 => {
                b.write(addr, &[0x3F]);
            }
            _ => {}
        }
        if ms % 100 == 0 && saving.is_none() && b.bridge.take_save(&mut img) {
            saving = Some(ms + rng.below(300));
            saves += 1;
        }
        if saving.is_some_and(|end| ms >= end) {
            b.bridge.saved(rng.below(8) != 0);
            saving = None;
        }
        b.run(1);
        let window = b.bridge.watchdog_window();
        assert_eq!(window == Long, saving.is_some(), "at {ms} ms");
        if window == Long {
            longs += 1;
            assert!(
                all_settled(&b.bridge),
                "an axis unsettled in the long window at {ms} ms"
            );
            assert!(
                !chips_moving(&b),
                "a chip moving in the long window at {ms} ms"
            );
        }
    }
    assert!(saves > 10 && longs > 500, "{saves} saves, {longs} ms long");
}
