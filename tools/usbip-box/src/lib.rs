//! The bridge's USB device against a real host stack, without a USB port.
//!
//! A USB/IP device server of our own ([`protocol`], [`bus`], [`server`];
//! [`vhci`] is the client side an import needs, as `usbip attach` does it):
//! [`bus::UsbIpBus`] implements usb-device's `UsbBus`, so the logic crate's
//! PoStep60 HID class and device descriptors run on it unchanged, with the
//! bridge behind them as the firmware runs it ([`postep_box`]). A Linux
//! kernel imports the device through vhci-hcd; usbhid, hid-generic and
//! hidraw then see a full-speed USB device, and hidapi programs (stepctl)
//! talk to it through `/dev/hidraw*`.
//!
//! Binaries: `usbip-box` (the box on 127.0.0.1:3240) and
//! `usbip-kernel-check` (run as root inside a Linux guest with vhci-hcd:
//! attaches the box and checks descriptors, every USB command and stepctl
//! through the kernel; `scripts/usbip-kernel` boots the guest).

// Tests are not bus input: they may index, unwrap and panic.
#![cfg_attr(test, allow(clippy::indexing_slicing, clippy::arithmetic_side_effects))]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod bus;
pub mod postep_box;
pub mod protocol;
pub mod server;
pub mod vhci;
