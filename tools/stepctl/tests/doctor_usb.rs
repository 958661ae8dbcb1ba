//! `stepctl doctor` over USB against the logic crate's bridge on simulated
//! chips (the report layer of "PoStep60 over USB HID", no kernel): every
//! read the doctor makes goes through `Bridge::on_usb_report` and comes back
//! from `Bridge::usb_next`, with control ticks in between, so the 0xE0
//! extension reads (chunks of at most 16, chip registers answered a tick
//! later) are what the firmware serves.
// A test: it may index, unwrap and panic.
#![allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used
)]
#![allow(clippy::expect_used, clippy::panic)]

use std::time::Duration;

use bridge_logic::bridge::Bridge;
use host_tests::sim_bridge::factory_bridge_on;
use stepbridge_sim::{Fault, SimChain};
use stepctl::doctor::{self, Expect, Options, Verdict};
use stepctl::usb::{Hid, Report, UsbBus};

/// The bridge behind a HID: each OUT report executed, control ticks run
/// until the response is there.
struct BridgeHid {
    bridge: Bridge<SimChain>,
    now_ms: u64,
}

impl BridgeHid {
    fn new(chips: usize, dead_at_boot: Option<usize>) -> BridgeHid {
        let mut chain = SimChain::new(chips);
        if let Some(k) = dead_at_boot {
            chain.device_mut(k).unwrap().inject(Fault::Dead(0xFF));
        }
        let bridge = factory_bridge_on(chain);
        let mut h = BridgeHid { bridge, now_ms: 0 };
        h.run(200);
        h
    }

    fn tick(&mut self) {
        self.now_ms += 1;
        self.bridge.chain_mut().bus_mut().advance(1_000_000);
        self.bridge.tick(self.now_ms);
        self.bridge.tick_timing(120, 1000);
    }

    fn run(&mut self, ms: u64) {
        for _ in 0..ms {
            self.tick();
        }
    }
}

impl Hid for BridgeHid {
    fn write(&mut self, report: &Report) -> Result<(), String> {
        // hidapi writes the report id first: the bridge sees the same 64 bytes.
        self.bridge.on_usb_report(report, self.now_ms);
        Ok(())
    }

    fn read(&mut self, _timeout: Duration) -> Result<Option<Report>, String> {
        for _ in 0..100 {
            if let Some(r) = self.bridge.usb_next(self.now_ms).copied() {
                self.bridge.usb_sent();
                return Ok(Some(r.0));
            }
            self.tick();
        }
        Ok(None)
    }

    fn name(&self) -> String {
        "usb bridge-on-sim".into()
    }
}

fn opts() -> Options {
    Options {
        first_id: 1,
        loopback: false,
        seconds: 0.0,
    }
}

fn verdict(checks: &[doctor::Check], name: &str) -> Verdict {
    checks
        .iter()
        .find(|c| c.check == name)
        .unwrap_or_else(|| panic!("no {name:?} in {checks:#?}"))
        .verdict
}

#[test]
fn a_healthy_box_over_usb_passes_every_check_but_the_tick_rate_this_harness_fakes() {
    let mut bus = UsbBus::new(BridgeHid::new(2, None), Duration::from_millis(10));
    let expect = Expect {
        axes: Some(2),
        ..Expect::default()
    };
    let r = doctor::read(&mut bus, &opts());
    let checks = doctor::judge(&r, &expect);
    for c in &checks {
        if c.check != "control tick" {
            assert_eq!(c.verdict, Verdict::Ok, "{c:#?}");
        }
    }
    assert_eq!(r.axes.len(), 2);
    assert!(r.axes[1].chip.len() >= 10, "every configured register read");
}

#[test]
fn a_chip_reset_and_a_dead_chip_are_found_over_usb() {
    let mut hid = BridgeHid::new(3, None);
    hid.bridge
        .chain_mut()
        .bus_mut()
        .device_mut(2)
        .unwrap()
        .inject(Fault::PowerCycle);
    hid.run(50);
    hid.bridge
        .chain_mut()
        .bus_mut()
        .device_mut(0)
        .unwrap()
        .inject(Fault::Dead(0xFF));
    hid.run(5);
    let mut bus = UsbBus::new(hid, Duration::from_millis(10));
    let checks = doctor::judge(&doctor::read(&mut bus, &opts()), &Expect::default());
    assert_eq!(
        verdict(&checks, "axis 3 faults"),
        Verdict::Fail,
        "UVLO latched"
    );
    assert_eq!(verdict(&checks, "axis 3 chip resets"), Verdict::Warn);
    assert_eq!(
        verdict(&checks, "axis 1 STATUS"),
        Verdict::Fail,
        "SDO stuck"
    );
    assert_eq!(verdict(&checks, "axis 1 chip registers"), Verdict::Fail);
}

#[test]
fn a_chip_dead_at_power_up_leaves_axis_0_answering_the_diagnostics_over_usb() {
    let mut bus = UsbBus::new(BridgeHid::new(4, Some(1)), Duration::from_millis(10));
    let expect = Expect {
        axes: Some(4),
        ..Expect::default()
    };
    let checks = doctor::judge(&doctor::read(&mut bus, &opts()), &expect);
    assert_eq!(verdict(&checks, "link"), Verdict::Ok);
    assert_eq!(verdict(&checks, "chain"), Verdict::Fail);
    assert_eq!(verdict(&checks, "supply"), Verdict::Ok);
    assert!(checks.iter().all(|c| !c.check.starts_with("axis")));
}
