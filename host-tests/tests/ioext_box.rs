//! The box's buttons, switches and lamps on the I/O extension (74HC165 /
//! 74HC595 shift registers on SPI2, simulated bit by bit on the wire):
//! what a user presses and sees, on the simulated chain.
//!
//! Wiring of every test: two '165s (16 inputs: contact to GND, pull-up —
//! closed reads 0) and one '595 (8 lamps), a 16-bit transfer in mode 0 with
//! auto-restart, so receive bit i is '165 #i/8 input H − i%8 and transmit
//! bits 8..15 land in the '595.

use bridge_logic::bridge::{Bridge, ExtError};
use bridge_logic::postep60::{DriverMode, Query, Request, Settings, Value};
use host_tests::clock::SimClock;
use host_tests::modbus_bench::ModbusBench;
use host_tests::sim_bridge::{chip, new_bridge, TICK_US};
use stepbridge_sim::{ShiftChain, SimChain};

const OPTIONS: u16 = 0x0200;
const CONFIG: u16 = 0x0202;
const TRANSFERS: u16 = 0x0204;
const RX: u16 = 0x0220;
const MAP: u16 = 0x0240;

/// Configuration: SPI mode, N = 10, auto-restart, 16 bits.
const CONFIG_16_AUTO: [u16; 2] = [0x100A, 0x020F];

/// Mapping entry offsets within an axis's 8 registers.
const BIN1: u16 = 0;
const BIN2: u16 = 1;
const END: u16 = 2;
const RUN: u16 = 3;
const MOVING: u16 = 4;
const FAULT: u16 = 5;
const IDLE: u16 = 6;

fn input(bit: u16) -> u16 {
    0x8000 | bit
}

fn input_nc(bit: u16) -> u16 {
    0xC000 | bit
}

fn lamp(bit: u16) -> u16 {
    0x8000 | bit
}

struct BoxRig {
    bridge: Bridge<SimChain>,
    clock: SimClock,
}

impl BoxRig {
    /// One axis with `settings`, the shift registers attached, every input
    /// open (high), the extension on and running.
    fn new(settings: Settings) -> BoxRig {
        let mut bridge = new_bridge(1, settings, bridge_logic::postep60::PowerStage::REFERENCE);
        let mut io = ShiftChain::new(2, 1);
        for i in 0..16 {
            io.set_rx_bit(i, true);
        }
        bridge.chain_mut().bus_mut().attach_io(io);
        let mut rig = BoxRig {
            bridge,
            clock: SimClock::new(TICK_US),
        };
        rig.run(20);
        rig.write(CONFIG, &CONFIG_16_AUTO).expect("config");
        rig.write(OPTIONS, &[0, 1]).expect("enable");
        rig
    }

    fn write(&mut self, address: u16, data: &[u16]) -> Result<(), ExtError> {
        self.bridge.ext_write(0, address, data)
    }

    fn reg(&mut self, address: u16) -> u16 {
        let mut out = [0u16];
        self.bridge
            .ext_read(0, address, &mut out)
            .expect("readable");
        out[0]
    }

    fn map(&mut self, entry: u16, value: u16) {
        self.write(MAP + entry, &[value]).expect("mapping");
    }

    /// Close (`true`) or open the contact on receive bit `i`.
    fn contact(&mut self, i: usize, closed: bool) {
        self.bridge
            .chain_mut()
            .bus_mut()
            .io_mut()
            .set_rx_bit(i, !closed);
    }

    /// '595 output QA + `pin` (transmit bit 15 − pin of a 16-bit transfer).
    fn lamp_on(&self, tx_bit: usize) -> bool {
        self.bridge.chain().bus().io().output(0, 15 - tx_bit)
    }

    fn run(&mut self, ms: u64) {
        self.clock.run(&mut self.bridge, ms);
    }

    fn settled(&self) -> bool {
        self.bridge.axis(0).is_some_and(|a| a.is_settled())
    }

    fn settle(&mut self) {
        for _ in 0..20_000 {
            if self.settled() {
                return;
            }
            self.run(1);
        }
        panic!("not settled");
    }

    fn position(&self) -> i32 {
        match self.bridge.query(0, Query::Position) {
            Some(Value::I32(p)) => p,
            other => panic!("position: {other:?}"),
        }
    }

    fn shaft(&self) -> i64 {
        chip(&self.bridge, 0).shaft_position()
    }
}

fn bin_settings() -> Settings {
    let mut s = Settings::FACTORY;
    s.axes[0].mode = DriverMode::BinButtons;
    s.axes[0].bin1_steps = 100;
    s.axes[0].bin2_steps = -40;
    s
}

fn auto_run_settings() -> Settings {
    let mut s = Settings::FACTORY;
    s.axes[0].mode = DriverMode::AutoRun;
    s.axes[0].max_speed = 1600;
    s.axes[0].requested_speed = 1600;
    s
}

#[test]
fn the_extension_reads_the_box_inputs_in_wire_order() {
    let mut r = BoxRig::new(Settings::FACTORY);
    r.contact(0, true);
    r.contact(9, true);
    r.run(3);
    let mut n = [0u16; 2];
    r.bridge.ext_read(0, TRANSFERS, &mut n).unwrap();
    assert!(n[1] >= 2 && n[0] == 0, "a transfer every tick: {n:?}");
    assert_eq!(r.reg(RX), 0b0111_1111_1011_1111, "closed reads 0");
}

#[test]
fn a_bin1_press_on_the_extension_moves_bin1_steps() {
    let mut r = BoxRig::new(bin_settings());
    r.map(BIN1, input(3));
    r.run(10);
    r.contact(3, true);
    r.run(10);
    r.settle();
    assert_eq!(r.position(), 100);
    assert_eq!(r.shaft(), 100 * 8, "1/16 logical on a 1/128 chip");
}

#[test]
fn a_bin2_press_moves_bin2_steps_and_a_held_button_moves_once() {
    let mut r = BoxRig::new(bin_settings());
    r.map(BIN2, input(4));
    r.run(10);
    r.contact(4, true);
    r.run(2000);
    r.settle();
    assert_eq!(r.position(), -40);
    r.contact(4, false);
    r.run(20);
    r.contact(4, true);
    r.run(20);
    r.settle();
    assert_eq!(r.position(), -80, "a second press, a second move");
}

#[test]
fn a_bounce_shorter_than_the_debounce_never_moves_the_motor() {
    let mut r = BoxRig::new(bin_settings());
    r.map(BIN1, input(3));
    r.run(10);
    for _ in 0..20 {
        r.contact(3, true);
        r.run(2);
        r.contact(3, false);
        r.run(2);
    }
    r.run(100);
    assert_eq!(r.position(), 0);
    assert_eq!(r.shaft(), 0);
}

#[test]
fn a_press_is_acted_on_within_the_debounce_plus_one_tick() {
    let mut r = BoxRig::new(bin_settings());
    r.map(BIN1, input(3));
    r.run(10);
    r.contact(3, true);
    let mut ms = 0;
    while r.bridge.axis(0).is_some_and(|a| a.is_settled()) {
        r.run(1);
        ms += 1;
        assert!(ms <= 6, "K = 5 transfers + 1 tick");
    }
    assert!(ms >= 5, "not before K transfers agree ({ms} ms)");
}

#[test]
fn a_normally_closed_button_is_pressed_when_its_contact_opens() {
    let mut r = BoxRig::new(bin_settings());
    r.contact(5, true); // NC contact at rest
    r.map(BIN1, input_nc(5));
    r.run(20);
    assert_eq!(r.position(), 0, "closed NC contact = released");
    r.contact(5, false);
    r.run(10);
    r.settle();
    assert_eq!(r.position(), 100);
}

#[test]
fn buttons_do_nothing_outside_bin_mode() {
    let mut r = BoxRig::new(Settings::FACTORY);
    r.map(BIN1, input(3));
    r.run(10);
    r.contact(3, true);
    r.run(100);
    assert_eq!(r.shaft(), 0);
}

#[test]
fn an_end_switch_on_the_extension_stops_a_moving_axis() {
    let mut s = Settings::FACTORY;
    s.axes[0].end_switch = true;
    let mut r = BoxRig::new(s);
    r.map(END, input(7));
    r.run(10);
    r.bridge
        .request(0, Request::SetPosition(1_000_000))
        .unwrap();
    r.run(300);
    assert!(!r.settled());
    r.contact(7, true);
    r.run(20);
    let p = r.shaft();
    r.run(200);
    assert_eq!(r.shaft(), p, "stopped and stays");
    assert!(p < 1_000_000 * 8);
    // Manual 8.3.9 pin status bit 6: end switch (1 = open).
    assert_eq!(
        r.bridge
            .query(0, Query::Pins)
            .map(|v| matches!(v, Value::U8(p) if p & 0x40 == 0)),
        Some(true),
        "the pin status shows the extension's end switch closed"
    );
}

#[test]
fn an_end_switch_on_the_extension_is_ignored_when_the_setting_is_off() {
    let mut r = BoxRig::new(Settings::FACTORY);
    r.map(END, input(7));
    r.run(10);
    r.bridge.request(0, Request::SetPosition(2000)).unwrap();
    r.run(50);
    r.contact(7, true);
    r.settle();
    assert_eq!(r.position(), 2000);
}

#[test]
fn auto_run_waits_for_its_run_switch_and_stops_when_it_turns_off() {
    let mut s = auto_run_settings();
    // The mapping must be stored for power-up: build it on a first bridge.
    let mut first = BoxRig::new(Settings::FACTORY);
    first.map(RUN, input(2));
    s.io = first.bridge.settings().io;
    let mut r = BoxRig::new(s);
    r.run(300);
    assert_eq!(r.shaft(), 0, "run switch off: no motion at power-up");
    r.contact(2, true);
    r.run(500);
    let moving = r.shaft();
    assert!(moving > 0, "switch on: runs");
    r.contact(2, false);
    r.run(20);
    r.settle();
    let stopped = r.shaft();
    r.run(300);
    assert_eq!(r.shaft(), stopped, "switch off: stops and stays");
    r.contact(2, true);
    r.run(300);
    assert!(r.shaft() > stopped, "on again: runs again");
}

#[test]
fn lamps_show_moving_then_idle_and_a_fault() {
    let mut r = BoxRig::new(Settings::FACTORY);
    r.map(MOVING, lamp(8));
    r.map(FAULT, lamp(9));
    r.map(IDLE, lamp(10));
    r.run(5);
    assert!(!r.lamp_on(8));
    r.bridge.request(0, Request::SetPosition(500)).unwrap();
    r.run(5);
    assert!(r.lamp_on(8), "moving lamp on while moving");
    r.settle();
    r.run(3);
    assert!(!r.lamp_on(8), "off once landed");
    assert!(!r.lamp_on(10));
    r.run(bridge_logic::postep60::device::IDLE_AFTER_MS + 10);
    assert!(r.lamp_on(10), "idle lamp after the idle time");
    assert!(!r.lamp_on(9));
}

#[test]
fn inputs_the_extension_does_not_map_keep_the_board_levels() {
    let mut r = BoxRig::new(bin_settings());
    r.map(END, input(7));
    r.run(10);
    r.bridge.on_inputs(
        0,
        bridge_logic::postep60::Inputs {
            bin1: true,
            ..Default::default()
        },
    );
    r.run(10);
    r.settle();
    assert_eq!(r.position(), 100);
}

#[test]
fn switching_the_extension_off_releases_its_inputs() {
    let mut r = BoxRig::new(bin_settings());
    r.map(BIN1, input(3));
    r.run(10);
    r.contact(3, true);
    r.run(10);
    r.settle();
    assert_eq!(r.position(), 100);
    r.write(OPTIONS, &[0, 0]).unwrap();
    r.run(10);
    r.contact(3, false);
    r.run(10);
    r.contact(3, true);
    r.run(50);
    assert_eq!(r.position(), 100, "no input while off");
}

#[test]
fn the_extension_is_configured_over_modbus_and_kept_by_write_settings() {
    let mut b = ModbusBench::new(1, Settings::FACTORY);
    b.write_multiple(1, CONFIG, &CONFIG_16_AUTO).unwrap();
    b.write_multiple(1, OPTIONS, &[0, 1]).unwrap();
    b.write(1, MAP + BIN1, input(3)).unwrap();
    let status = 0x0800; // bit 11: a transfer has ended since
    assert_eq!(
        b.read(1, CONFIG, 2),
        Ok(vec![CONFIG_16_AUTO[0], CONFIG_16_AUTO[1] | status])
    );
    assert_eq!(b.read(1, MAP, 2), Ok(vec![0x8003, 0]));
    let s = b.bridge.settings();
    let mut image = [0u8; bridge_logic::postep60::settings::IMAGE_LEN];
    s.to_image(&mut image);
    let back = Settings::from_image(&image).unwrap();
    assert_eq!(back.io, s.io);
    assert!(back.io.enabled);
    let mut b2 = ModbusBench::new(1, back);
    assert_eq!(
        b2.read(1, CONFIG, 2),
        Ok(vec![CONFIG_16_AUTO[0], CONFIG_16_AUTO[1] | status])
    );
    assert_eq!(b2.read(1, MAP, 1), Ok(vec![0x8003]));
}

#[test]
fn a_reserved_mapping_bit_is_an_illegal_value_over_modbus() {
    let mut b = ModbusBench::new(1, Settings::FACTORY);
    assert_eq!(b.write(1, MAP + BIN1, 0x8100), Err(3));
    assert_eq!(b.write(1, 0x020C, 0), Err(2), "a hole of the page");
}
