//! Extension 0x04nn: homing against an end switch on the chip's SW input,
//! on the simulated chain. The switch is a cam on the motor shaft (the
//! simulator's shaft position, which ABS_POS writes do not move): pressed
//! while the shaft is at or below the edge.

use bridge_logic::bridge::Bridge;
use bridge_logic::postep60::{Query, Request, Settings, Value};
use bridge_logic::powerstep::registers::Register;
use host_tests::clock::SimClock;
use host_tests::modbus_bench::ModbusBench;
use host_tests::sim_bridge::{chip, chip_mut, new_bridge, TICK_US};
use stepbridge_sim::{Fault, SimChain};

/// Homing registers.
const CMD: u16 = 0x0400;
const RESULT: u16 = 0x0401;
const HOMED: u16 = 0x0402;
const TRAVEL: u16 = 0x0408;
const TIMEOUT: u16 = 0x040A;

/// A bridge, one axis at 1/16 on a 1/128 chip, a switch at `edge` (shaft
/// units: 1/128 steps), normally open or closed.
struct Home {
    bridge: Bridge<SimChain>,
    clock: SimClock,
    edge: i64,
    nc: bool,
}

impl Home {
    fn new(edge: i64, nc: bool, settings: Option<Settings>) -> Home {
        let mut s = settings.unwrap_or(Settings::FACTORY);
        s.axes[0].end_switch = true;
        s.axes[0].end_switch_nc = nc;
        s.axes[0].max_speed = 3200; // 200 full steps/s
        s.axes[0].acc = 32_000;
        s.axes[0].dec = 32_000;
        let mut h = Home {
            bridge: new_bridge(1, s, bridge_logic::postep60::PowerStage::REFERENCE),
            clock: SimClock::new(TICK_US),
            edge,
            nc,
        };
        h.switch();
        h.run(30);
        h
    }

    fn pressed(&self) -> bool {
        chip(&self.bridge, 0).shaft_position() <= self.edge
    }

    fn switch(&mut self) {
        let closed = self.pressed() != self.nc;
        chip_mut(&mut self.bridge, 0).set_switch(closed);
    }

    fn run(&mut self, ms: u64) {
        for _ in 0..ms {
            self.clock.tick(&mut self.bridge);
            self.switch();
        }
    }

    fn reg(&mut self, address: u16) -> u16 {
        let mut out = [0u16];
        self.bridge
            .ext_read(0, address, &mut out)
            .expect("readable");
        out[0]
    }

    fn write(
        &mut self,
        address: u16,
        data: &[u16],
    ) -> Result<(), bridge_logic::ext_space::ExtError> {
        self.bridge.ext_write(0, address, data)
    }

    /// Run until homing left its running states (panics after `cap` ms).
    fn home(&mut self, cap: u64) -> u16 {
        self.write(CMD, &[1]).expect("homing starts");
        for _ in 0..cap {
            self.run(1);
            let state = self.reg(CMD);
            if state >= 4 {
                self.settle();
                return state;
            }
        }
        panic!("homing did not end in {cap} ms");
    }

    fn settle(&mut self) {
        for _ in 0..10_000 {
            if self.bridge.axis(0).unwrap().is_settled() {
                return;
            }
            self.run(1);
        }
        panic!("not settled");
    }

    /// Shaft position relative to the switch's edge — the first microstep
    /// where it is released — 1/128 steps.
    fn past_edge(&self) -> i64 {
        chip(&self.bridge, 0).shaft_position() - (self.edge + 1)
    }

    fn abs_pos(&self) -> i64 {
        i64::from(chip(&self.bridge, 0).abs_pos())
    }
}

#[test]
fn a_normally_open_switch_homes_position_zero_onto_its_edge() {
    let mut h = Home::new(-12_000, false, None);
    assert_eq!(h.home(60_000), 4, "done");
    assert_eq!(h.reg(HOMED), 1);
    assert_eq!(h.reg(RESULT), 0);
    // ABS_POS 0 is where the switch released: the shaft stands within a
    // microstep or two past the edge, and ABS_POS says exactly where.
    assert!(
        (0..=3).contains(&h.past_edge()),
        "{} from the edge",
        h.past_edge()
    );
    assert_eq!(h.abs_pos(), h.past_edge());
    // The profile takes over exactly: a move lands on its microstep.
    h.bridge.request(0, Request::SetPosition(1000)).unwrap();
    h.settle();
    assert_eq!(h.abs_pos(), 8000);
    assert_eq!(h.past_edge(), 8000, "8000 µsteps from the edge");
    assert_eq!(h.bridge.query(0, Query::Position), Some(Value::I32(1000)));
}

#[test]
fn a_normally_closed_switch_homes_onto_its_edge_too() {
    let mut h = Home::new(-6_000, true, None);
    assert_eq!(h.home(60_000), 4);
    assert!(
        (-3..=3).contains(&h.past_edge()),
        "{} from the edge",
        h.past_edge()
    );
    assert_eq!(h.abs_pos(), h.past_edge());
}

#[test]
fn an_axis_already_on_the_switch_moves_off_it_first() {
    // The shaft (at 0) is below the edge: the switch is pressed at the start.
    let mut h = Home::new(4_000, false, None);
    assert!(h.pressed());
    assert_eq!(h.home(60_000), 4);
    assert!(
        (0..=3).contains(&h.past_edge()),
        "{} from the edge",
        h.past_edge()
    );
    assert_eq!(h.abs_pos(), h.past_edge());
}

#[test]
fn a_switch_not_found_within_the_travel_stops_and_reports_it() {
    let mut h = Home::new(-1_000_000, false, None);
    h.write(TRAVEL, &[0, 500]).unwrap(); // 500 logical steps = 4000 µsteps
    assert_eq!(h.home(60_000), 5, "failed");
    assert_eq!(h.reg(RESULT), 1, "not found");
    assert_eq!(h.reg(HOMED), 0);
    // It stopped a little beyond the travel (braking), not far.
    let travelled = -chip(&h.bridge, 0).shaft_position();
    assert!((4000..6000).contains(&travelled), "{travelled}");
}

#[test]
fn the_timeout_ends_a_search_that_takes_too_long() {
    let mut h = Home::new(-1_000_000, false, None);
    h.write(TIMEOUT, &[1]).unwrap();
    assert_eq!(h.home(5_000), 5);
    assert_eq!(h.reg(RESULT), 2, "timeout");
}

#[test]
fn homing_with_the_end_switch_disabled_is_refused() {
    let mut s = Settings::FACTORY;
    s.axes[0].end_switch = false;
    let mut b = ModbusBench::new(1, s);
    assert_eq!(b.write(1, CMD, 1), Err(4));
    assert_eq!(b.read(1, RESULT, 1), Ok(vec![3]), "switch disabled");
    assert_eq!(b.read(1, CMD, 1), Ok(vec![0]), "idle");
}

#[test]
fn a_stop_during_homing_aborts_it() {
    let mut h = Home::new(-1_000_000, false, None);
    h.write(CMD, &[1]).unwrap();
    h.run(300);
    assert_eq!(h.reg(CMD), 2, "searching");
    h.bridge.request(0, Request::Stop).unwrap();
    h.settle();
    assert_eq!(h.reg(CMD), 5);
    assert_eq!(h.reg(RESULT), 4, "aborted");
    assert_eq!(h.reg(HOMED), 0);
    let p = chip(&h.bridge, 0).shaft_position();
    h.run(200);
    assert_eq!(chip(&h.bridge, 0).shaft_position(), p, "stopped");
}

#[test]
fn motion_requests_wait_while_homing() {
    let mut h = Home::new(-1_000_000, false, None);
    h.write(CMD, &[1]).unwrap();
    h.run(50);
    assert!(h.bridge.request(0, Request::SetPosition(100)).is_err());
}

#[test]
fn a_chip_reset_forgets_the_home() {
    let mut h = Home::new(-3_000, false, None);
    assert_eq!(h.home(60_000), 4);
    assert_eq!(h.reg(HOMED), 1);
    chip_mut(&mut h.bridge, 0).inject(Fault::PowerCycle);
    h.run(20);
    assert_eq!(h.reg(HOMED), 0);
}

#[test]
fn homing_parameters_persist_with_write_settings() {
    let mut h = Home::new(-3_000, false, None);
    h.write(0x0403, &[1]).unwrap(); // forward
    h.write(0x0404, &[0, 4000]).unwrap();
    h.write(0x0406, &[0, 160]).unwrap();
    h.write(TRAVEL, &[1, 0]).unwrap();
    h.write(TIMEOUT, &[30]).unwrap();
    let s = h.bridge.settings().axes[0].homing;
    assert!(s.forward);
    assert_eq!(
        (s.search_speed, s.release_speed, s.max_travel, s.timeout_s),
        (4000, 160, 65_536, 30)
    );
    let mut out = [0u16; 11];
    h.bridge.ext_read(0, 0x0400, &mut out).unwrap();
    assert_eq!(&out[3..], &[1, 0, 4000, 0, 160, 1, 0, 30]);
}

#[test]
fn modbus_starts_homing_with_fc06_on_0x0400() {
    let mut s = Settings::FACTORY;
    s.axes[0].end_switch = true;
    let mut b = ModbusBench::new(1, s);
    // Switch far away: the search starts and runs.
    assert_eq!(
        b.transact(&[0x01, 0x06, 0x04, 0x00, 0x00, 0x01, 0x49, 0x3A]),
        Some([0x01, 0x06, 0x04, 0x00, 0x00, 0x01, 0x49, 0x3A].to_vec())
    );
    b.run(100);
    assert_eq!(b.read(1, CMD, 1), Ok(vec![2]), "searching");
    assert!(b.chip(0).is_busy());
}

#[test]
fn the_end_switch_settings_are_writable_over_modbus_and_enable_homing() {
    let mut s = Settings::FACTORY;
    s.axes[0].end_switch = false;
    let mut b = ModbusBench::new(1, s);
    assert_eq!(b.write(1, CMD, 1), Err(4), "switch disabled");
    assert_eq!(b.write(1, 0x040B, 3), Ok(()));
    assert_eq!(
        b.read(1, 0x040B, 1),
        Ok(vec![3]),
        "enabled, normally closed"
    );
    assert!(b.bridge.settings().axes[0].end_switch);
    assert!(b.bridge.settings().axes[0].end_switch_nc);
    assert_eq!(b.write(1, 0x040B, 4), Err(3), "reserved bits");
    assert_eq!(b.write(1, 0x040B, 1), Ok(()));
    assert_eq!(b.write(1, CMD, 1), Ok(()), "homing starts now");
    assert_eq!(b.write(1, 0x040B, 0), Err(4), "not while homing");
}

#[test]
fn a_cam_on_the_simulated_shaft_homes_the_axis_onto_its_edge_without_help() {
    use stepbridge_sim::HomeCam;
    let mut s = Settings::FACTORY;
    s.axes[0].end_switch = true;
    let mut b = ModbusBench::new(1, s);
    b.bridge
        .chain_mut()
        .bus_mut()
        .device_mut(0)
        .expect("chip")
        .set_home_cam(Some(HomeCam {
            edge: -3_000,
            nc: false,
        }));
    assert_eq!(b.write(1, CMD, 1), Ok(()));
    for _ in 0..600 {
        b.run(100);
        if b.read(1, CMD, 1) == Ok(vec![4]) {
            break;
        }
    }
    assert_eq!(b.read(1, CMD, 1), Ok(vec![4]), "done");
    assert_eq!(b.read(1, HOMED, 1), Ok(vec![1]));
    let past = b.chip(0).shaft_position() - (-3_000 + 1);
    // The cam is sampled once per control tick: the zero is within a tick of
    // release travel of the edge.
    assert!((0..=64).contains(&past), "{past} microsteps from the edge");
}

// ------------------------------------------- after homing, the axis rests ----

/// Commands a chip may receive while its axis rests: reads, register
/// writes and the stop commands (none of them turns the shaft).
fn moves_the_shaft(c: &bridge_logic::powerstep::Command) -> bool {
    use bridge_logic::powerstep::Command as C;
    !matches!(
        c,
        C::Nop
            | C::GetParam(_)
            | C::GetStatus
            | C::SetParam(..)
            | C::HardStop
            | C::HardHiZ
            | C::SoftStop
            | C::SoftHiZ
            | C::ResetPos
    )
}

impl Home {
    /// Motion commands the chip received since `seen` (its receive count then).
    fn motion_since(&self, seen: u64) -> Vec<bridge_logic::powerstep::Command> {
        let c = chip(&self.bridge, 0);
        let new = (c.received_count() - seen).min(32) as usize;
        let skip = c.received().count().saturating_sub(new);
        c.received()
            .skip(skip)
            .filter(|c| moves_the_shaft(c))
            .copied()
            .collect()
    }

    /// Start homing and run until it has ended (done or failed), no longer.
    fn home_to_end(&mut self, cap: u64) -> u16 {
        self.write(CMD, &[1]).expect("homing starts");
        for _ in 0..cap {
            self.run(1);
            let state = self.reg(CMD);
            if state >= 4 {
                return state;
            }
        }
        panic!("homing did not end in {cap} ms");
    }

    /// From now on for `ms` the axis rests: the chip gets no motion command
    /// and, once its stop (if any) is over, the shaft does not turn.
    fn assert_rests(&mut self, ms: u64, what: &str) {
        let seen = chip(&self.bridge, 0).received_count();
        let mut rest: Option<i64> = None;
        for t in 0..ms {
            self.run(1);
            let moved = self.motion_since(seen);
            assert!(
                moved.is_empty(),
                "{what}: {t} ms after the end: motion commands {moved:?}"
            );
            let c = chip(&self.bridge, 0);
            match rest {
                None if c.is_stopped() => rest = Some(c.shaft_position()),
                Some(p) => assert_eq!(
                    c.shaft_position(),
                    p,
                    "{what}: the shaft turned after {t} ms"
                ),
                None => {}
            }
        }
        assert!(rest.is_some(), "{what}: never came to rest");
    }

    fn set_position(&mut self, p: i32) {
        self.bridge.request(0, Request::SetPosition(p)).unwrap();
        self.settle();
    }
}

#[test]
fn after_homing_is_done_the_axis_rests_on_the_edge_not_at_its_old_target() {
    // The filed case: 1/16 on a 1/128 chip, switch pressed at or below
    // −12 800 µsteps, the axis at 1600 (12 800 µsteps) when homing starts.
    let mut h = Home::new(-12_800, false, Some(Settings::FACTORY));
    h.set_position(1600);
    assert_eq!(h.abs_pos(), 12_800);
    assert_eq!(h.home_to_end(60_000), 4, "done");
    h.assert_rests(3000, "done");
    assert!(
        (0..=3).contains(&h.past_edge()),
        "{} from the edge",
        h.past_edge()
    );
    assert_eq!(h.reg(HOMED), 1);
    assert_eq!(
        chip(&h.bridge, 0).register(Register::MinSpeed),
        0,
        "MIN_SPEED back to the bridge's 0"
    );
}

#[test]
fn after_homing_fails_by_max_travel_the_axis_rests_where_it_stopped() {
    let mut h = Home::new(-1_000_000, false, Some(Settings::FACTORY));
    h.set_position(1600);
    h.write(TRAVEL, &[0, 500]).unwrap();
    assert_eq!(h.home_to_end(60_000), 5);
    assert_eq!(h.reg(RESULT), 1, "not found");
    h.assert_rests(3000, "not found");
}

#[test]
fn after_homing_times_out_the_axis_rests_where_it_stopped() {
    let mut h = Home::new(-1_000_000, false, Some(Settings::FACTORY));
    h.set_position(1600);
    h.write(TIMEOUT, &[1]).unwrap();
    assert_eq!(h.home_to_end(60_000), 5);
    assert_eq!(h.reg(RESULT), 2, "timeout");
    h.assert_rests(3000, "timeout");
}

#[test]
fn min_speed_is_back_before_the_first_move_after_homing() {
    let mut h = Home::new(-3_000, false, None);
    h.write(CMD, &[1]).unwrap();
    // Ask for a move in the very tick homing ends.
    for _ in 0..60_000 {
        h.run(1);
        if h.reg(CMD) >= 4 {
            break;
        }
    }
    assert_eq!(h.reg(CMD), 4);
    let seen = chip(&h.bridge, 0).received_count();
    // Accepted as soon as the axis rests.
    let mut accepted = false;
    for _ in 0..100 {
        if h.bridge.request(0, Request::SetPosition(2000)).is_ok() {
            accepted = true;
            break;
        }
        h.run(1);
    }
    assert!(accepted);
    h.settle();
    let c = chip(&h.bridge, 0);
    let new = (c.received_count() - seen).min(32) as usize;
    let skip = c.received().count().saturating_sub(new);
    let after: Vec<_> = c.received().skip(skip).copied().collect();
    let first_motion = after.iter().position(moves_the_shaft).expect("the move");
    let restored = after
        .iter()
        .position(|c| *c == bridge_logic::powerstep::Command::SetParam(Register::MinSpeed, 0));
    assert!(
        chip(&h.bridge, 0).register(Register::MinSpeed) == 0
            && restored.is_none_or(|r| r < first_motion),
        "MIN_SPEED 0 before the first motion command: {after:?}"
    );
    assert_eq!(h.abs_pos(), 16_000);
}

// ------------------------------------------- every phase is bounded ----

#[test]
fn the_clear_phase_is_bounded_by_max_travel() {
    // The filed case: the switch is pressed for shaft ≤ 100, the chip at 0,
    // the search direction forward — away from the cam, so clearing drives
    // deeper into it. Max travel 200 full steps (3200 logical), no timeout.
    let mut h = Home::new(100, false, Some(Settings::FACTORY));
    h.write(0x0403, &[1]).unwrap(); // forward
    h.write(TRAVEL, &[0, 3200]).unwrap();
    h.write(TIMEOUT, &[0]).unwrap();
    assert!(h.pressed());
    assert_eq!(h.home_to_end(60_000), 5, "failed");
    assert_eq!(h.reg(RESULT), 7, "the switch did not release");
    let travelled = chip(&h.bridge, 0).shaft_position().abs();
    assert!(
        (200 * 128..=210 * 128).contains(&travelled),
        "{travelled} µsteps"
    );
    h.assert_rests(1000, "clear phase bounded");
}

#[test]
fn the_release_phase_is_bounded_by_max_travel() {
    // A contact that sticks once it has closed: the release never sees it open.
    let mut h = Home::new(-1_600, false, Some(Settings::FACTORY));
    h.write(TRAVEL, &[0, 400]).unwrap(); // 25 full steps
    h.write(TIMEOUT, &[0]).unwrap();
    h.write(CMD, &[1]).unwrap();
    let mut stuck = false;
    for _ in 0..60_000 {
        h.clock.tick(&mut h.bridge);
        stuck |= h.pressed();
        let closed = stuck || h.pressed();
        chip_mut(&mut h.bridge, 0).set_switch(closed);
        if h.reg(CMD) >= 4 {
            break;
        }
    }
    assert_eq!(h.reg(CMD), 5, "failed");
    assert_eq!(h.reg(RESULT), 7, "the switch did not release");
    let off = chip(&h.bridge, 0).shaft_position() - (-1_600);
    assert!(off <= 30 * 128, "{off} µsteps past the edge");
}

#[test]
fn homing_with_neither_max_travel_nor_timeout_is_refused() {
    let mut h = Home::new(-3_000, false, None);
    h.write(TRAVEL, &[0, 0]).unwrap();
    h.write(TIMEOUT, &[0]).unwrap();
    assert!(h.write(CMD, &[1]).is_err(), "it could run for ever");
    assert_eq!(h.reg(RESULT), 8, "unbounded");
    assert_eq!(h.reg(CMD), 0);
}

#[test]
fn a_chip_reset_during_a_search_with_max_travel_reports_a_fault() {
    // At every phase of the read-back cadence.
    // The reset zeroes ABS_POS: 32 000 µsteps from where the search began,
    // more than the 24 000 of max travel.
    for at in 300..310 {
        let mut h = Home::new(-1_000_000, false, None);
        h.set_position(4000);
        h.write(TRAVEL, &[0, 3000]).unwrap();
        h.write(CMD, &[1]).unwrap();
        h.run(at);
        assert_eq!(h.reg(CMD), 2, "searching");
        chip_mut(&mut h.bridge, 0).inject(Fault::PowerCycle);
        h.run(50);
        assert_eq!(h.reg(CMD), 5);
        assert_eq!(
            h.reg(RESULT),
            5,
            "reset {at} ms in: a fault, not 'not found'"
        );
    }
}

#[test]
fn the_search_ramps_with_the_axis_s_current_limits() {
    let mut h = Home::new(-1_000_000, false, None);
    // A move with one set of ramps, then other ramps at rest.
    h.set_position(800);
    h.bridge.request(0, Request::SetAcceleration(4000)).unwrap();
    h.bridge.request(0, Request::SetDeceleration(8000)).unwrap();
    h.write(CMD, &[1]).unwrap();
    h.run(50);
    assert_eq!(h.reg(CMD), 2, "searching");
    // The chip runs the search's ramps itself: ACC/DEC are the axis's
    // limits, not the 3/2 headroom of streaming. 4000 and 8000 steps/s²
    // at 1/16 are 250 and 500 full steps/s²; ACC = a · 2⁴⁰ / (4·10⁶)²
    // (datasheet, ACC register): 17.18 → 17 and 34.36 → 34.
    let c = chip(&h.bridge, 0);
    assert_eq!(c.register(Register::Acc), 17);
    assert_eq!(c.register(Register::Dec), 34);
}
