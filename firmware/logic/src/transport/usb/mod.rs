//! USB HID: what a PC sees of the bridge, byte for byte as the PoStep60
//! manual's section 10 prints it, and the class that carries its reports.
//!
//! # What a host sees
//!
//! * **Device** (10.1): bcdUSB 0x0200, class 0/0/0, EP0 64 bytes, VID 0x1DC3,
//!   PID 0x0641, bcdDevice 0x0100, strings 1 "PoLabs", 2 "PoStep60-256",
//!   3 the serial number ([`serial_number`]), one configuration.
//! * **Configuration** (41 bytes): bmAttributes 0xC0, MaxPower 0x32; one
//!   interface 3/0/0 with string 4 "HID"; the HID descriptor (bcdHID 0x0111,
//!   one report descriptor of 33 bytes); EP 0x81 interrupt IN 64 bytes
//!   bInterval 10, then EP 0x01 interrupt OUT 64 bytes bInterval 2.
//! * **Reports**: [`REPORT_DESCRIPTOR`] declares one input and one output
//!   report, both with report id 2 and 63 data bytes, so a hidapi / Windows
//!   HID host reads and writes 64-byte buffers whose byte 0 is the report id:
//!   exactly the manual's `InDATA[0..63]` (`InDATA[0]` = 0x02, its
//!   "IN_REPORT_ID") and `OutDATA[0..63]` (`OutDATA[0]` = 0x02 on Windows; the
//!   bridge ignores that byte, so hidraw hosts may send anything there).
//!   Output reports sent through the control pipe (HID SET_REPORT) are taken
//!   like the OUT endpoint's.
//!
//! # The report descriptor, byte by byte
//!
//! | bytes | item | why |
//! |---|---|---|
//! | `06 00 FF` | Usage Page (vendor 0xFF00) | a vendor device: no OS driver claims it, hidapi opens it |
//! | `09 01` | Usage (1) | the application collection's usage |
//! | `A1 01` | Collection (Application) | |
//! | `85 02` | Report ID (2) | the manual's IN_REPORT_ID: `InDATA[0]` = 0x02 |
//! | `75 08` | Report Size (8) | bytes |
//! | `95 3F` | Report Count (63) | `InDATA[1..63]`: with the id, 64 bytes = one packet |
//! | `15 00` | Logical Minimum (0) | |
//! | `26 FF 00` | Logical Maximum (255) | unsigned bytes (a 1-byte 0xFF would be −1) |
//! | `09 01` | Usage (1) | |
//! | `81 02` | Input (Data, Variable, Absolute) | the IN report |
//! | `85 02` | Report ID (2) | restated, so the output report reads on its own: `OutDATA[0]` |
//! | `75 08` | Report Size (8) | restated |
//! | `95 3F` | Report Count (63) | restated: `OutDATA[1..63]` |
//! | `09 01` | Usage (1) | |
//! | `91 02` | Output (Data, Variable, Absolute) | the OUT report |
//! | `C0` | End Collection | 33 bytes, the manual's wDescriptorLength |

pub mod class;
pub mod codec;

pub use class::PoStepHid;
pub use codec::{decode, InReport, UsbError, UsbRequest, REPORT_LEN};

use heapless::String;
use usb_device::bus::{UsbBus, UsbBusAllocator};
use usb_device::descriptor::lang_id::LangID;
use usb_device::device::{StringDescriptors, UsbDevice, UsbDeviceBuilder, UsbRev, UsbVidPid};
use usb_device::prelude::BuilderError;

/// PoLabs' vendor id.
pub const VID: u16 = 0x1DC3;
/// The PoStep60's product id.
pub const PID: u16 = 0x0641;
/// bcdDevice.
pub const DEVICE_RELEASE: u16 = 0x0100;
pub const MANUFACTURER: &str = "PoLabs";
pub const PRODUCT: &str = "PoStep60-256";
/// String 4, the interface's.
pub const INTERFACE_STRING: &str = "HID";
/// bMaxPower 0x32 = 100 mA.
pub const MAX_POWER_MA: usize = 100;
/// IN endpoint's bInterval, ms: also the 0xA0 stream's period.
pub const IN_INTERVAL_MS: u8 = 10;
/// OUT endpoint's bInterval, ms.
pub const OUT_INTERVAL_MS: u8 = 2;

/// The 33-byte report descriptor (module doc).
pub const REPORT_DESCRIPTOR: [u8; 33] = [
    0x06, 0x00, 0xFF, // Usage Page (vendor 0xFF00)
    0x09, 0x01, // Usage (1)
    0xA1, 0x01, // Collection (Application)
    0x85, 0x02, //   Report ID (2)
    0x75, 0x08, //   Report Size (8)
    0x95, 0x3F, //   Report Count (63)
    0x15, 0x00, //   Logical Minimum (0)
    0x26, 0xFF, 0x00, //   Logical Maximum (255)
    0x09, 0x01, //   Usage (1)
    0x81, 0x02, //   Input (Data, Variable, Absolute)
    0x85, 0x02, //   Report ID (2)
    0x75, 0x08, //   Report Size (8)
    0x95, 0x3F, //   Report Count (63)
    0x09, 0x01, //   Usage (1)
    0x91, 0x02, //   Output (Data, Variable, Absolute)
    0xC0, // End Collection
];

/// The HID descriptor's body (after bLength and bDescriptorType 0x21):
/// bcdHID 0x0111, country 0, one descriptor, type 0x22 (report), 33 bytes.
pub const HID_DESCRIPTOR_BODY: [u8; 7] = [
    0x11,
    0x01,
    0x00,
    0x01,
    0x22,
    REPORT_DESCRIPTOR.len() as u8,
    0x00,
];

/// The serial number string: four groups of eight upper-case hex digits,
/// as the manual's example "19012026-AEF79868-578C8A78-F5001987": the
/// CRC-32 of the STM32's 96-bit unique id, then its three words.
pub type Serial = String<35>;

/// The serial number of a bridge with unique id `uid` (the three words at
/// 0x1FFF7A10).
pub fn serial_number(uid: [u32; 3]) -> Serial {
    let mut s = Serial::new();
    let words = [uid_crc(uid), uid[0], uid[1], uid[2]];
    for (k, w) in words.iter().enumerate() {
        if k > 0 {
            let _ = s.push('-');
        }
        for byte in w.to_be_bytes() {
            for nibble in [byte >> 4, byte & 0xF] {
                let c = b"0123456789ABCDEF"
                    .get(usize::from(nibble))
                    .copied()
                    .unwrap_or(b'?');
                let _ = s.push(char::from(c));
            }
        }
    }
    s
}

/// CRC-32 (ISO-HDLC) of the unique id's 12 bytes, little-endian words.
pub fn uid_crc(uid: [u32; 3]) -> u32 {
    const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
    let mut d = CRC32.digest();
    for w in uid {
        d.update(&w.to_le_bytes());
    }
    d.finalize()
}

/// The 0x01 reply's IAP_UID: five 32-bit words. The STM32 has 96 bits:
/// words 0–2 are the unique id, word 3 its CRC-32 (the serial number's first
/// group), word 4 is 0.
pub fn iap_uid(uid: [u32; 3]) -> [u32; 5] {
    [uid[0], uid[1], uid[2], uid_crc(uid), 0]
}

/// The USB device exactly as manual 10.1 describes it (the class's
/// interface, HID descriptor and endpoints come from [`PoStepHid`]).
pub fn device<'a, B: UsbBus>(
    alloc: &'a UsbBusAllocator<B>,
    serial: &'a str,
) -> Result<UsbDevice<'a, B>, BuilderError> {
    Ok(UsbDeviceBuilder::new(alloc, UsbVidPid(VID, PID))
        .usb_rev(UsbRev::Usb200)
        .device_class(0)
        .device_sub_class(0)
        .device_protocol(0)
        .device_release(DEVICE_RELEASE)
        .self_powered(true)
        .strings(&[StringDescriptors::new(LangID::EN_US)
            .manufacturer(MANUFACTURER)
            .product(PRODUCT)
            .serial_number(serial)])?
        .max_packet_size_0(64)?
        .max_power(MAX_POWER_MA)?
        .build())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_report_descriptor_is_33_bytes_as_the_hid_descriptor_says() {
        assert_eq!(REPORT_DESCRIPTOR.len(), 33);
        assert_eq!(HID_DESCRIPTOR_BODY[5], 0x21);
    }

    #[test]
    fn the_serial_number_has_the_manual_s_shape() {
        let s = serial_number([0x0045_0021, 0x3133_5111, 0x3538_3530]);
        assert_eq!(s.len(), 35);
        let parts: heapless::Vec<&str, 4> = s.split('-').collect();
        assert_eq!(parts.len(), 4);
        assert!(parts.iter().all(|p| p.len() == 8));
        assert_eq!(parts[1], "00450021");
        assert_eq!(parts[3], "35383530");
        assert!(s
            .chars()
            .all(|c| c == '-' || c.is_ascii_hexdigit() && !c.is_ascii_lowercase()));
    }

    #[test]
    fn iap_uid_is_the_id_then_its_crc_then_zero() {
        let uid = [1, 2, 3];
        assert_eq!(iap_uid(uid), [1, 2, 3, uid_crc(uid), 0]);
    }
}
