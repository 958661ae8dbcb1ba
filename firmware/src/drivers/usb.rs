//! USB OTG FS (PA11/PA12) as the PoStep60 HID device: the logic crate's
//! device descriptors (`transport::usb::device`) and HID class
//! (`PoStepHid`) on stm32f4xx-hal's Synopsys OTG bus. Moves reports; what
//! they mean is the bridge's (`bridge::usb`).
//!
//! # What it guarantees
//!
//! * **Start** builds the bus allocator, the class and the device once; any
//!   refusal is an error, never a panic: the endpoint memory is sized at
//!   compile time for exactly the OUT endpoints the device has (EP0 and
//!   EP1, 64 bytes each), and a second start gets
//!   [`UsbStartError::AlreadyStarted`].
//! * **Link**: [`UsbPort::poll`] reports [`Link::Lost`] once whenever the
//!   device stops being configured (bus reset, suspend, SET_CONFIGURATION 0,
//!   cable pulled), so the caller can drop the bridge's stream and unread
//!   responses (`Bridge::on_usb_reset`).
//! * **Reports** are only written while the device is configured.
//!
//! # Assumptions
//!
//! * The 48 MHz PLL48CLK runs (`platform::freeze_clocks` asserts it with
//!   `require_pll48clk`): the OTG FS core's full-speed timing needs it.
//! * One task (the app's `OTG_FS` task) owns the port and calls `poll` on
//!   every `OTG_FS` interrupt and at least every 10 ms.
//! * Board only: QEMU 7.2 maps OTG FS as an unimplemented device, and the
//!   allocator's core reset waits for ever there (`platform/qemu.rs` never
//!   starts it).

use bridge_logic::transport::usb::{self as hid, PoStepHid, Serial, REPORT_LEN};
use stm32f4xx_hal::otg_fs::{UsbBus, USB};
use usb_device::bus::UsbBusAllocator;
use usb_device::device::{UsbDevice, UsbDeviceState};
use usb_device::UsbError;

/// EP0's max packet size (`transport::usb::device` sets 64).
pub const EP0_PACKET: usize = 64;
/// Words of OUT-endpoint memory the Synopsys driver needs: one buffer of
/// max-packet size per OUT endpoint, EP0 and EP1 (the IN endpoints use the
/// core's own FIFO RAM).
pub const EP_MEMORY_WORDS: usize = (EP0_PACKET + REPORT_LEN) / 4;
/// The core's FIFO RAM (RM0090 35.11: 1.25 KB = 320 words) must hold what
/// synopsys-usb-otg 0.4 puts there: 30 words of set-up, the RX FIFO (the
/// OUT buffers) and one TX FIFO of at least 16 words per IN endpoint.
pub const FIFO_WORDS_USED: usize = 30 + EP_MEMORY_WORDS + 2 * (REPORT_LEN / 4);
const _: () = assert!(EP_MEMORY_WORDS * 4 >= EP0_PACKET + REPORT_LEN);
const _: () = assert!(FIFO_WORDS_USED <= 320);

/// The bus type.
pub type Bus = UsbBus<USB>;

/// Why USB did not start.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum UsbStartError {
    /// Its static memory is taken: started before.
    AlreadyStarted,
    /// The class's interface or endpoints were refused.
    Class(UsbError),
    /// The device builder refused the descriptors (bad EP0 size, power,
    /// too many string languages).
    Descriptors,
}

/// The device's link, after a poll.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Link {
    /// Configured by a host: reports flow.
    Up,
    /// Not configured (no host, enumerating, suspended).
    Down,
    /// Configured until this poll, not any more: bus reset, suspend,
    /// deconfigured or unplugged.
    Lost,
}

/// The PoStep60 HID device on OTG FS.
pub struct UsbPort {
    device: UsbDevice<'static, Bus>,
    hid: PoStepHid<'static, Bus>,
    configured: bool,
}

impl UsbPort {
    /// Build the bus, the class and the device (serial number from `uid`),
    /// and connect (the core pulls D+ up).
    pub fn start(usb: USB, uid: [u32; 3]) -> Result<UsbPort, UsbStartError> {
        let memory = cortex_m::singleton!(: [u32; EP_MEMORY_WORDS] = [0; EP_MEMORY_WORDS])
            .ok_or(UsbStartError::AlreadyStarted)?;
        let alloc = cortex_m::singleton!(: UsbBusAllocator<Bus> = UsbBus::new(usb, memory))
            .ok_or(UsbStartError::AlreadyStarted)?;
        let serial = cortex_m::singleton!(: Serial = hid::serial_number(uid))
            .ok_or(UsbStartError::AlreadyStarted)?;
        // The class first: its endpoints get numbers 1 (0x81, 0x01); the
        // device then takes EP0.
        let class = PoStepHid::new(alloc).map_err(UsbStartError::Class)?;
        let device = hid::device(alloc, serial.as_str()).map_err(|_| UsbStartError::Descriptors)?;
        Ok(UsbPort {
            device,
            hid: class,
            configured: false,
        })
    }

    /// Poll the stack (control transfers, endpoint events) and report the
    /// link.
    pub fn poll(&mut self) -> Link {
        self.device.poll(&mut [&mut self.hid]);
        let configured = self.device.state() == UsbDeviceState::Configured;
        let was = core::mem::replace(&mut self.configured, configured);
        match (was, configured) {
            (_, true) => Link::Up,
            (true, false) => Link::Lost,
            (false, false) => Link::Down,
        }
    }

    /// The device's state as usb-device sees it.
    pub fn state(&self) -> UsbDeviceState {
        self.device.state()
    }

    /// The next OUT report (endpoint 0x01 or SET_REPORT), if one came: its
    /// length in `buf`.
    pub fn read_report(&mut self, buf: &mut [u8; REPORT_LEN]) -> Option<usize> {
        self.hid.read_report(buf)
    }

    /// Put an IN report into endpoint 0x81; false while the previous one
    /// waits for the host, or while the device is not configured.
    pub fn write_report(&mut self, report: &[u8; REPORT_LEN]) -> bool {
        self.configured && self.hid.write_report(report)
    }
}
