//! A USB test bench: the bridge on simulated chips behind the PoStep60 HID
//! class on an emulated USB bus (`usbd-class-tester`), enumerated by a
//! host-like device model through the real `usb-device` stack, with the
//! virtual clock and a flash store for saves.
//!
//! After every poll of the stack (the tester's hook) the bench does what the
//! firmware's OTG_FS task does with an OUT report: it goes to the bridge.
//! The bridge's next IN report is put into the IN endpoint when the host
//! reads ([`read`]): the emulated bus has no IN-token timing of its own.

use crate::clock::SimClock;
use bridge_logic::bridge::{Bridge, RunMode};
use bridge_logic::persist::sim::SimFlash;
use bridge_logic::persist::Store;
use bridge_logic::postep60::settings::IMAGE_LEN;
use bridge_logic::postep60::{PowerStage, Settings};
use bridge_logic::transport::usb::{self, PoStepHid, REPORT_LEN};
use stepbridge_sim::SimChain;
use usb_device::class_prelude::*;
use usb_device::device::UsbDevice;
use usbd_class_tester::prelude::*;

pub use crate::sim_bridge::TICK_US;

/// The unique id the bench's MCU has.
pub const UID: [u32; 3] = [0x0045_0021, 0x3133_5111, 0x3538_3530];

/// The settings flash: two 4 KiB sectors.
pub type Flash = SimFlash<4096, 2>;

/// The class under test plus everything behind it.
pub struct UsbBench<'a> {
    pub hid: PoStepHid<'a, EmulatedUsbBus>,
    pub bridge: Bridge<SimChain>,
    pub clock: SimClock,
    pub store: Store<Flash>,
    /// The USB device exists (endpoints may only be touched after that).
    usb_up: bool,
}

impl UsbBench<'_> {
    /// What the firmware's USB task does with OUT reports after a poll.
    pub fn pump(&mut self) {
        if !self.usb_up {
            return;
        }
        let mut buf = [0u8; REPORT_LEN];
        while let Some(n) = self.hid.read_report(&mut buf) {
            let n = n.min(REPORT_LEN);
            self.bridge.on_usb_report(&buf[..n], self.clock.now_ms());
        }
    }

    /// What the firmware's USB task does when the IN endpoint is free: the
    /// bridge's next report goes in.
    pub fn serve_in(&mut self) {
        if !self.usb_up {
            return;
        }
        let now = self.clock.now_ms();
        if let Some(r) = self.bridge.usb_next(now).copied() {
            if self.hid.write_report(&r.0) {
                self.bridge.usb_sent();
            }
        }
    }

    /// `ms` of virtual time: control ticks, saves the bridge hands out (as
    /// the firmware's housekeeping does), and the USB task every tick.
    pub fn run(&mut self, ms: u64) {
        for _ in 0..ms * 1000 / u64::from(TICK_US) {
            self.clock.tick(&mut self.bridge);
            let mut img = [0u8; IMAGE_LEN];
            if self.bridge.take_save(&mut img) {
                let ok = self.store.save(&img).is_ok();
                self.bridge.saved(ok);
            }
            self.pump();
        }
    }

    /// Run until every axis is settled (panics after `cap` ms).
    pub fn settle(&mut self, cap: u64) {
        crate::sim_bridge::settle(self, cap, |h| &h.bridge, |h| h.run(1));
    }

    pub fn chip(&self, k: usize) -> &stepbridge_sim::Powerstep01 {
        crate::sim_bridge::chip(&self.bridge, k)
    }

    /// The settings the store holds now.
    pub fn stored(&mut self) -> Option<Settings> {
        let mut img = [0u8; bridge_logic::persist::MAX_IMAGE];
        let n = self.store.load(&mut img).ok()?;
        Settings::from_image(img.get(..n)?).ok()
    }
}

impl UsbClass<EmulatedUsbBus> for UsbBench<'_> {
    fn get_configuration_descriptors(
        &self,
        writer: &mut DescriptorWriter,
    ) -> usb_device::Result<()> {
        self.hid.get_configuration_descriptors(writer)
    }
    fn get_string(&self, index: StringIndex, lang_id: LangID) -> Option<&str> {
        UsbClass::<EmulatedUsbBus>::get_string(&self.hid, index, lang_id)
    }
    fn reset(&mut self) {
        UsbClass::<EmulatedUsbBus>::reset(&mut self.hid);
        self.bridge.on_usb_reset();
    }
    fn control_in(&mut self, xfer: ControlIn<EmulatedUsbBus>) {
        self.hid.control_in(xfer)
    }
    fn control_out(&mut self, xfer: ControlOut<EmulatedUsbBus>) {
        self.hid.control_out(xfer)
    }
}

/// How to build the bench for one test.
pub struct UsbCtx {
    pub chips: usize,
    pub settings: Settings,
    pub run_mode: RunMode,
}

impl Default for UsbCtx {
    fn default() -> UsbCtx {
        UsbCtx {
            chips: 2,
            settings: Settings::FACTORY,
            run_mode: RunMode::Application,
        }
    }
}

impl UsbDeviceCtx for UsbCtx {
    type C<'c> = UsbBench<'c>;
    const EP0_SIZE: u8 = 64;

    fn create_class<'a>(
        &mut self,
        alloc: &'a UsbBusAllocator<EmulatedUsbBus>,
    ) -> AnyResult<UsbBench<'a>> {
        let hid = PoStepHid::new(alloc).map_err(|_| AnyUsbError::UserDefined1)?;
        let mut bridge =
            crate::sim_bridge::new_bridge(self.chips, self.settings, PowerStage::REFERENCE);
        bridge.set_unique_id(UID);
        if self.run_mode == RunMode::Boot {
            bridge.enter_boot_mode();
        }
        let mut bench = UsbBench {
            hid,
            bridge,
            clock: SimClock::new(TICK_US),
            store: Store::new(SimFlash::new()),
            usb_up: false,
        };
        bench.run(30);
        Ok(bench)
    }

    fn build_usb_device<'a>(
        &mut self,
        alloc: &'a UsbBusAllocator<EmulatedUsbBus>,
    ) -> AnyResult<UsbDevice<'a, EmulatedUsbBus>> {
        // The serial lives as long as the test process (the device borrows it).
        let serial: &'static str = Box::leak(usb::serial_number(UID).as_str().into());
        usb::device(alloc, serial).map_err(AnyUsbError::UsbDeviceBuilder)
    }

    fn hook(&mut self, cls: &mut UsbBench<'_>, _when: HookWhen) -> HookAction {
        cls.usb_up = true;
        cls.pump();
        HookAction::Default
    }
}

/// The emulated host's view of the bench.
pub type Host<'a> = Device<'a, UsbBench<'a>, UsbCtx>;

/// Write `out` to EP 0x01, then read EP 0x81: the report that came back
/// (empty when there was none).
pub fn transact<'a>(cls: &mut UsbBench<'a>, dev: &mut Host<'a>, out: &[u8]) -> Vec<u8> {
    write(cls, dev, out);
    read(cls, dev)
}

/// Write an OUT report to EP 0x01.
pub fn write<'a>(cls: &mut UsbBench<'a>, dev: &mut Host<'a>, out: &[u8]) {
    dev.ep_write(cls, 1, out).expect("EP1 OUT write");
}

/// Read EP 0x81 (empty when the device has nothing to send).
pub fn read<'a>(cls: &mut UsbBench<'a>, dev: &mut Host<'a>) -> Vec<u8> {
    cls.serve_in();
    dev.ep_read(cls, 1, REPORT_LEN as u16).unwrap_or_default()
}

/// OUT-report commands that may start or change motion (or stop it, which
/// the check treats the same: the chip may then differ from "untouched").
pub const MOTION: [u8; 10] = [0x02, 0x80, 0x83, 0x82, 0x90, 0xA1, 0xB1, 0xB2, 0xB3, 0xE1];

/// Feed arbitrary OUT reports (and control ticks) straight to the bridge's
/// USB entry points, 2 axes on simulated chips, and check: nothing panics;
/// no chip moves unless a well-formed report (64 bytes, or 63 with byte 0
/// stripped, and `OutDATA[63]` = 0) carried
/// a motion command; an ill-formed report gets no response. Returns the
/// number of reports fed. The fuzz target `usb_reports` and the proptest in
/// `usb_robustness.rs` both run this.
///
/// Input: ops of a tag byte (bit 0: 0 report, 1 tick), then for a report a
/// length byte (mod 80) and that many bytes; for a tick a count of ms (mod 30).
pub fn check_usb_stream(data: &[u8]) -> usize {
    let (mut bridge, mut clock) = crate::sim_bridge::template("usb_stream", || {
        let mut bridge = crate::sim_bridge::new_bridge(2, Settings::FACTORY, PowerStage::REFERENCE);
        let mut clock = SimClock::new(TICK_US);
        clock.run(&mut bridge, 30);
        (bridge, clock)
    });
    let mut it = data.iter().copied();
    let mut motion = false;
    let mut reports = 0;
    while let Some(tag) = it.next() {
        if tag & 1 == 0 {
            let len = usize::from(it.next().unwrap_or(0) % 80);
            let r: Vec<u8> = it.by_ref().take(len).collect();
            // 64 bytes, or 63 (OutDATA[1..63], byte 0 stripped by the host),
            // with OutDATA[63] = 0.
            let command = match r.len() {
                REPORT_LEN => r.get(1),
                n if n == REPORT_LEN - 1 => r.first(),
                _ => None,
            };
            let well_formed = command.is_some() && r.last() == Some(&0);
            if well_formed && command.is_some_and(|c| MOTION.contains(c)) {
                motion = true;
            }
            let before = bridge.diag.usb_reports;
            bridge.on_usb_report(&r, clock.now_ms());
            reports += 1;
            if !well_formed {
                assert_eq!(
                    bridge.diag.usb_reports, before,
                    "an ill-formed report was executed"
                );
            }
            while bridge.usb_next(clock.now_ms()).is_some() {
                bridge.usb_sent();
            }
        } else {
            clock.run(&mut bridge, u64::from(it.next().unwrap_or(0) % 30));
        }
    }
    clock.run(&mut bridge, 30);
    if !motion {
        for k in 0..2 {
            let c = crate::sim_bridge::chip(&bridge, k);
            assert_eq!(c.abs_pos(), 0, "chip {k} moved without a motion command");
        }
    }
    reports
}
