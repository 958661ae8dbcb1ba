//! The PoStep60 manual's USB bytes (§10), written once for every USB test:
//! the descriptors of §10.1 and OUT/IN report helpers at the tables'
//! offsets. These are the oracle's bytes, typed from the manual, never the
//! project's codec (`bridge_logic::transport::usb`), so a codec mistake
//! fails the tests instead of being copied into them.
//!
//! Users: `tests/usb_commands.rs` (the bridge on the emulated bus), and
//! `tools/usbip-box`'s scripted client and kernel check (the same box
//! through USB/IP and through Linux's hidraw).

use bridge_logic::motion::axis::logical_to_physical;
use bridge_logic::powerstep::StepSel;

/// Manual 10.1: the device descriptor.
pub const MANUAL_DEVICE: [u8; 18] = [
    0x12, 0x01, // bLength, DEVICE
    0x00, 0x02, // bcdUSB 0x0200
    0x00, 0x00, 0x00, // class, subclass, protocol
    0x40, // bMaxPacketSize0 64
    0xC3, 0x1D, // idVendor 0x1DC3
    0x41, 0x06, // idProduct 0x0641
    0x00, 0x01, // bcdDevice 0x0100
    0x01, 0x02, 0x03, // iManufacturer, iProduct, iSerialNumber
    0x01, // bNumConfigurations
];

/// Manual 10.1: configuration, interface, HID, EP 0x81 IN, EP 0x01 OUT.
pub const MANUAL_CONFIG: [u8; 41] = [
    // configuration: wTotalLength 0x29, 1 interface, value 1, no string,
    // bmAttributes 0xC0, MaxPower 0x32 (100 mA)
    0x09, 0x02, 0x29, 0x00, 0x01, 0x01, 0x00, 0xC0, 0x32,
    // interface 0, alt 0, 2 endpoints, HID 3/0/0, string 4
    0x09, 0x04, 0x00, 0x00, 0x02, 0x03, 0x00, 0x00, 0x04,
    // HID: bcdHID 0x0111, country 0, 1 descriptor: report, 0x21 bytes
    0x09, 0x21, 0x11, 0x01, 0x00, 0x01, 0x22, 0x21, 0x00,
    // EP 0x81 IN interrupt, 64 bytes, bInterval 10
    0x07, 0x05, 0x81, 0x03, 0x40, 0x00, 0x0A,
    // EP 0x01 OUT interrupt, 64 bytes, bInterval 2
    0x07, 0x05, 0x01, 0x03, 0x40, 0x00, 0x02,
];

/// The report descriptor's 33 bytes (the project's, as
/// `transport::usb`'s module doc gives it; the manual gives only its
/// length, 0x21): report id 2, 63 bytes in and out.
pub const REPORT_DESCRIPTOR: [u8; 33] = [
    0x06, 0x00, 0xFF, 0x09, 0x01, 0xA1, 0x01, // vendor page, usage 1, application
    0x85, 0x02, 0x75, 0x08, 0x95, 0x3F, // id 2, 63 bytes
    0x15, 0x00, 0x26, 0xFF, 0x00, 0x09, 0x01, 0x81, 0x02, // 0..255, input
    0x85, 0x02, 0x75, 0x08, 0x95, 0x3F, 0x09, 0x01, 0x91, 0x02, // output, id 2
    0xC0,
];

/// An OUT report: `OutDATA[0]` = 0x02 (the report id, as stepctl and a
/// Windows HID host send it), the command in `[1]`, the rest zero (`[62]`
/// axis 0, `[63]` 0).
pub fn out(cmd: u8) -> [u8; 64] {
    let mut r = [0u8; 64];
    r[0] = 0x02;
    r[1] = cmd;
    r
}

/// A little-endian u32 at `at` (the trajectory and position fields).
pub fn le32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// A big-endian u32 at `at` (the status report's counters).
pub fn be32(b: &[u8], at: usize) -> u32 {
    u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// A big-endian u16 at `at`.
pub fn be16(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([b[at], b[at + 1]])
}

/// Physical microsteps of a logical position in the factory step mode
/// (1/16 on the chip's 1/128).
pub fn phys(pos: i64) -> i32 {
    logical_to_physical(pos, 4, StepSel::OneTwentyEighth) as i32
}

/// 0xB1: trajectory profile, final position, limits (LSB first, manual
/// offsets 2, 20, 24, 28, 32).
pub fn trajectory(profile: u8, pos: i32, speed: u32, acc: u32, dec: u32) -> [u8; 64] {
    let mut r = out(0xB1);
    r[2] = profile;
    r[20..24].copy_from_slice(&pos.to_le_bytes());
    r[24..28].copy_from_slice(&speed.to_le_bytes());
    r[28..32].copy_from_slice(&acc.to_le_bytes());
    r[32..36].copy_from_slice(&dec.to_le_bytes());
    r
}

/// A 0x80 report: DRV8711 registers, mode, temperature limit, currents,
/// address, baud/parity (manual 10.2.3 offsets).
pub fn write_driver_settings(
    regs: [u16; 8],
    mode: u8,
    max_temp: u8,
    address: u8,
    serial: u8,
) -> [u8; 64] {
    let mut r = out(0x80);
    for (i, v) in regs.iter().enumerate() {
        r[20 + 2 * i..22 + 2 * i].copy_from_slice(&v.to_le_bytes());
    }
    r[37] = mode;
    r[38] = max_temp;
    r[39] = 61; // idle 0.5 A: Tq 61, Ai 3
    r[40] = 3;
    r[41] = 123; // overheat 1 A: Tq 123, Ai 3
    r[42] = 3;
    r[43] = address;
    r[44] = serial;
    r
}
