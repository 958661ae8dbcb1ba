//! The box: the bridge on simulated powerSTEP01 chips, behind the PoStep60
//! HID class and device descriptors, on a [`UsbIpBus`] — the logic crate's
//! USB exactly as the firmware uses it, with a USB/IP client as its host.
//!
//! # What it does as the firmware does
//!
//! * **Start** (`firmware/src/main.rs` `init`): settings from the store
//!   (`boot_settings`), `Bridge::new_fitted` on the chain at the build's
//!   tick rate, the unique id, boot mode if the last run restarted into it,
//!   then the class (`PoStepHid::new`, endpoints 0x81/0x01) before the
//!   device (`transport::usb::device`, EP0) on one allocator.
//! * **USB task** (`usb_hid`, run after every control tick and whenever the
//!   host sent something): poll the device; a link that stops being
//!   configured ends the stream (`Bridge::on_usb_reset`); every OUT report
//!   to `Bridge::on_usb_report` with the tick's ms; `Bridge::usb_next` into
//!   EP 0x81, `Bridge::usb_sent` once the endpoint took it.
//! * **Control tick** every `rate.us` µs of virtual time
//!   ([`SimClock::tick`]), **housekeeping** every 100 ms: the ADC sample, a
//!   handed-out save into the settings store, a requested restart.
//! * **Restart** (0x02, 0xDF, Modbus/I2C system reset): the device is
//!   unplugged and a new run starts on the same settings store, in boot
//!   mode after a first 0x02 (a ROM DFU request starts the application:
//!   there is no ROM bootloader here, as under QEMU).
//!
//! What differs from the board: the chain is simulated and ticked by
//! [`SimClock`] (the same stand-in as the QEMU image and the host tests),
//! the clock follows the host's real time ([`PoStepBox::run_until`]), and
//! the host's interrupt IN polling has no 10 ms bInterval (vhci-hcd
//! resubmits at once): the stream's cadence is the bridge's own.

use bridge_logic::bridge::{boot_settings, Bridge, ResetCause, ResetTarget, RunMode};
use bridge_logic::persist::sim::SimFlash;
use bridge_logic::persist::{Store, StoreError, MAX_IMAGE};
use bridge_logic::postep60::analog::AnalogSample;
use bridge_logic::postep60::settings::IMAGE_LEN;
use bridge_logic::postep60::PowerStage;
use bridge_logic::rate::TICK_HZ;
use bridge_logic::transport::usb::{self as hid, PoStepHid, REPORT_LEN};
use host_tests::clock::SimClock;
use stepbridge_sim::SimChain;
use usb_device::bus::UsbBusAllocator;
use usb_device::device::{UsbDevice, UsbDeviceState};

use crate::bus::{self, Port, UsbIpBus};
use crate::protocol::{DeviceInfo, SPEED_FULL};

/// The settings flash: the firmware's two 128 KiB sectors would do, but the
/// image is 154 bytes; two 4 KiB sectors exercise the same store.
pub type Flash = SimFlash<4096, 2>;

/// The unique id the box's MCU reports (serial number, 0x01's IAP_UID).
pub const UID: [u32; 3] = [0x0045_0021, 0x3133_5111, 0x3538_3530];

/// Housekeeping period, ms (the firmware spawns it at 10 Hz).
pub const HOUSEKEEPING_MS: u64 = 100;

/// The link as the firmware's `UsbPort::poll` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Link {
    Up,
    Down,
    Lost,
}

/// The USB device as the firmware's `drivers::usb::UsbPort` holds it.
struct UsbPort {
    device: UsbDevice<'static, UsbIpBus>,
    hid: PoStepHid<'static, UsbIpBus>,
    configured: bool,
}

impl UsbPort {
    // The class's endpoints and the descriptors are fixed in this crate, not
    // input: their failing is a bug here, found by every test that starts a box.
    #[allow(clippy::panic)]
    fn start(uid: [u32; 3]) -> (UsbPort, Port) {
        let (bus, port) = bus::new();
        // The device borrows its allocator and serial for its whole life;
        // a restart makes new ones (a few hundred bytes per restart).
        let alloc: &'static UsbBusAllocator<UsbIpBus> =
            Box::leak(Box::new(UsbBusAllocator::new(bus)));
        let serial: &'static str = Box::leak(hid::serial_number(uid).as_str().into());
        // The class first: its endpoints get numbers 1 (0x81, 0x01).
        let class = match PoStepHid::new(alloc) {
            Ok(c) => c,
            Err(e) => panic!("the HID class's endpoints: {e:?}"),
        };
        let device = match hid::device(alloc, serial) {
            Ok(d) => d,
            Err(e) => panic!("the device descriptors: {e:?}"),
        };
        (
            UsbPort {
                device,
                hid: class,
                configured: false,
            },
            port,
        )
    }

    fn poll(&mut self) -> (bool, Link) {
        let events = self.device.poll(&mut [&mut self.hid]);
        let configured = self.device.state() == UsbDeviceState::Configured;
        let was = core::mem::replace(&mut self.configured, configured);
        let link = match (was, configured) {
            (_, true) => Link::Up,
            (true, false) => Link::Lost,
            (false, false) => Link::Down,
        };
        (events, link)
    }

    fn write_report(&mut self, report: &[u8; REPORT_LEN]) -> bool {
        self.configured && self.hid.write_report(report)
    }
}

impl std::fmt::Debug for UsbPort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UsbPort")
            .field("state", &self.device.state())
            .field("configured", &self.configured)
            .finish_non_exhaustive()
    }
}

/// What a step of the box did that its server must know.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Restart {
    /// The box restarted into `RunMode`: unplug the old port (the new one
    /// is [`PoStepBox::port`]).
    Into(RunMode),
}

/// The box.
#[derive(Debug)]
pub struct PoStepBox {
    pub bridge: Bridge<SimChain>,
    pub clock: SimClock,
    store: Store<Flash>,
    usb: UsbPort,
    port: Port,
    axes: usize,
    next_housekeeping_ms: u64,
    /// Runs so far (1 = since power-up).
    pub runs: u32,
}

impl PoStepBox {
    /// Power-up with `axes` chips and an empty settings store.
    pub fn power_up(axes: usize) -> PoStepBox {
        let store = Store::new(Flash::new());
        Self::start(axes, store, None, ResetCause::PowerOn, 1)
    }

    fn start(
        axes: usize,
        mut store: Store<Flash>,
        handoff: Option<ResetTarget>,
        cause: ResetCause,
        runs: u32,
    ) -> PoStepBox {
        let mut image = [0u8; MAX_IMAGE];
        let loaded = store
            .load(&mut image)
            .map(|n| image.get(..n).unwrap_or(&[]));
        let (settings, source) = boot_settings(loaded, |e| *e == StoreError::Empty);
        let (mut bridge, rate) = Bridge::new_fitted(
            SimChain::new(axes),
            PowerStage::REFERENCE,
            settings,
            source,
            TICK_HZ,
        );
        bridge.set_reset_cause(cause);
        bridge.set_unique_id(UID);
        if handoff == Some(ResetTarget::BootMode) {
            bridge.enter_boot_mode();
        }
        bridge.on_analog(AnalogSample::NOMINAL_24V_25C);
        let (usb, port) = UsbPort::start(UID);
        PoStepBox {
            bridge,
            clock: SimClock::new(rate.us),
            store,
            usb,
            port,
            axes,
            next_housekeeping_ms: HOUSEKEEPING_MS,
            runs,
        }
    }

    /// The USB/IP side of the current run's bus.
    pub fn port(&self) -> &Port {
        &self.port
    }

    /// The record OP_REP_DEVLIST / OP_REP_IMPORT give for this device.
    pub fn device_info() -> DeviceInfo {
        DeviceInfo {
            path: "/sys/devices/platform/usbip-box/usb1/1-1".into(),
            busid: "1-1".into(),
            busnum: 1,
            devnum: 2,
            speed: SPEED_FULL,
            vendor: hid::VID,
            product: hid::PID,
            bcd_device: hid::DEVICE_RELEASE,
            class: 0,
            subclass: 0,
            protocol: 0,
            configuration_value: 0,
            num_configurations: 1,
            interfaces: vec![(3, 0, 0)],
        }
    }

    /// The device is configured by its host.
    pub fn configured(&self) -> bool {
        self.usb.configured
    }

    /// The firmware's USB task: poll (again while the stack has events, as
    /// the OTG interrupt fires once per event), OUT reports in, the next IN
    /// report out.
    pub fn usb_task(&mut self) {
        let now_ms = self.clock.now_ms();
        for _ in 0..16 {
            let (events, link) = self.usb.poll();
            if link == Link::Lost {
                self.bridge.on_usb_reset();
            }
            let mut report = [0u8; REPORT_LEN];
            while let Some(n) = self.usb.hid.read_report(&mut report) {
                let bytes = report.get(..n).unwrap_or(&[]);
                self.bridge.on_usb_report(bytes, now_ms);
            }
            if let Some(r) = self.bridge.usb_next(now_ms).copied() {
                if self.usb.write_report(&r.0) {
                    self.bridge.usb_sent();
                }
            }
            if !events {
                break;
            }
        }
    }

    /// One control tick, the USB task it pends, and housekeeping when due.
    pub fn tick(&mut self) -> Option<Restart> {
        self.clock.tick(&mut self.bridge);
        self.usb_task();
        if self.clock.now_ms() >= self.next_housekeeping_ms {
            self.next_housekeeping_ms = self.next_housekeeping_ms.saturating_add(HOUSEKEEPING_MS);
            return self.housekeeping();
        }
        None
    }

    /// Ticks until the virtual clock reaches `us` (at most `max_ticks`, so
    /// a slow host falls behind instead of stalling the network); how many
    /// ran and a restart if one happened.
    pub fn run_until(&mut self, us: u64, max_ticks: u32) -> (u32, Option<Restart>) {
        let mut n: u32 = 0;
        while self.clock.next_tick_us() <= us && n < max_ticks {
            n = n.saturating_add(1);
            if let Some(r) = self.tick() {
                return (n, Some(r));
            }
        }
        (n, None)
    }

    fn housekeeping(&mut self) -> Option<Restart> {
        self.bridge.on_analog(AnalogSample::NOMINAL_24V_25C);
        let mut image = [0u8; IMAGE_LEN];
        if self.bridge.take_save(&mut image) {
            let ok = self.store.save(&image).is_ok();
            self.bridge.saved(ok);
        }
        let target = self.bridge.take_reset()?;
        let handoff = match target {
            ResetTarget::BootMode => Some(ResetTarget::BootMode),
            // No ROM bootloader here: the application starts (as under QEMU).
            ResetTarget::Application | ResetTarget::RomDfu => None,
        };
        let store = std::mem::replace(&mut self.store, Store::new(Flash::new()));
        let next = Self::start(
            self.axes,
            store,
            handoff,
            ResetCause::Software,
            self.runs.saturating_add(1),
        );
        *self = next;
        let mode = if handoff.is_some() {
            RunMode::Boot
        } else {
            RunMode::Application
        };
        Some(Restart::Into(mode))
    }
}
