//! The PoStep60 HID class on any `usb_device` bus: one interface, the HID
//! descriptor, EP 0x81 IN and EP 0x01 OUT (addresses, sizes, intervals and
//! their order as manual 10.1), the report descriptor on request, and
//! 64-byte reports in both directions.
//!
//! Control requests: GET_DESCRIPTOR (HID 0x21, report 0x22) to the
//! interface; the class requests SET_IDLE / GET_IDLE (kept, no effect: the
//! device only sends reports it has), SET_PROTOCOL (accepted), and
//! SET_REPORT of an output report, which is taken like an OUT-endpoint
//! report. Everything else is rejected (STALL).

use usb_device::class_prelude::*;
use usb_device::control::{Recipient, RequestType};
use usb_device::endpoint::{EndpointAddress, EndpointType};

use super::codec::REPORT_LEN;
use super::{
    HID_DESCRIPTOR_BODY, INTERFACE_STRING, IN_INTERVAL_MS, OUT_INTERVAL_MS, REPORT_DESCRIPTOR,
};

const HID_DESCRIPTOR: u8 = 0x21;
const REPORT_DESCRIPTOR_TYPE: u8 = 0x22;
const GET_DESCRIPTOR: u8 = 0x06;
const GET_IDLE: u8 = 0x02;
const SET_REPORT: u8 = 0x09;
const SET_IDLE: u8 = 0x0A;
const SET_PROTOCOL: u8 = 0x0B;
/// SET_REPORT's wValue high byte for an output report.
const REPORT_TYPE_OUTPUT: u8 = 0x02;

/// The class.
pub struct PoStepHid<'a, B: UsbBus> {
    interface: InterfaceNumber,
    name: StringIndex,
    ep_in: EndpointIn<'a, B>,
    ep_out: EndpointOut<'a, B>,
    idle: u8,
    /// An output report that came by SET_REPORT, not yet taken.
    /// A report that came by SET_REPORT on EP0, and its length.
    control_report: Option<([u8; REPORT_LEN], usize)>,
}

impl<B: UsbBus> core::fmt::Debug for PoStepHid<'_, B> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("PoStepHid").finish_non_exhaustive()
    }
}

impl<'a, B: UsbBus> PoStepHid<'a, B> {
    /// Allocate the interface, its string and the two endpoints (0x81, 0x01).
    pub fn new(alloc: &'a UsbBusAllocator<B>) -> usb_device::Result<PoStepHid<'a, B>> {
        let interface = alloc.interface();
        let name = alloc.string();
        let ep_in = alloc.alloc(
            Some(EndpointAddress::from(0x81)),
            EndpointType::Interrupt,
            REPORT_LEN as u16,
            IN_INTERVAL_MS,
        )?;
        let ep_out = alloc.alloc(
            Some(EndpointAddress::from(0x01)),
            EndpointType::Interrupt,
            REPORT_LEN as u16,
            OUT_INTERVAL_MS,
        )?;
        Ok(PoStepHid {
            interface,
            name,
            ep_in,
            ep_out,
            idle: 0,
            control_report: None,
        })
    }

    /// The next output report, if one arrived: its bytes in `buf` and its
    /// length (a transfer of another length than 64 is passed on as it is;
    /// the codec refuses it).
    pub fn read_report(&mut self, buf: &mut [u8; REPORT_LEN]) -> Option<usize> {
        if let Some((r, n)) = self.control_report.take() {
            *buf = r;
            return Some(n);
        }
        self.ep_out.read(buf).ok()
    }

    /// Queue an input report; false while the previous one is still in the
    /// endpoint (try again after the next poll).
    pub fn write_report(&mut self, report: &[u8; REPORT_LEN]) -> bool {
        self.ep_in.write(report).is_ok()
    }

    fn hid_descriptor(&self) -> [u8; 9] {
        let b = HID_DESCRIPTOR_BODY;
        [9, HID_DESCRIPTOR, b[0], b[1], b[2], b[3], b[4], b[5], b[6]]
    }
}

impl<B: UsbBus> UsbClass<B> for PoStepHid<'_, B> {
    fn get_configuration_descriptors(
        &self,
        writer: &mut DescriptorWriter,
    ) -> usb_device::Result<()> {
        writer.interface_alt(self.interface, 0, 0x03, 0x00, 0x00, Some(self.name))?;
        writer.write(HID_DESCRIPTOR, &HID_DESCRIPTOR_BODY)?;
        writer.endpoint(&self.ep_in)?;
        writer.endpoint(&self.ep_out)?;
        Ok(())
    }

    fn get_string(&self, index: StringIndex, _lang_id: LangID) -> Option<&str> {
        (index == self.name).then_some(INTERFACE_STRING)
    }

    fn reset(&mut self) {
        self.control_report = None;
        self.idle = 0;
    }

    fn control_in(&mut self, xfer: ControlIn<B>) {
        let req = *xfer.request();
        if req.recipient != Recipient::Interface || req.index != u16::from(u8::from(self.interface))
        {
            return;
        }
        match (req.request_type, req.request) {
            (RequestType::Standard, GET_DESCRIPTOR) => {
                let _ = match (req.value >> 8) as u8 {
                    REPORT_DESCRIPTOR_TYPE => xfer.accept_with_static(&REPORT_DESCRIPTOR),
                    HID_DESCRIPTOR => xfer.accept_with(&self.hid_descriptor()),
                    _ => xfer.reject(),
                };
            }
            (RequestType::Class, GET_IDLE) => {
                let _ = xfer.accept_with(&[self.idle]);
            }
            (RequestType::Class, _) => {
                let _ = xfer.reject();
            }
            _ => {}
        }
    }

    fn control_out(&mut self, xfer: ControlOut<B>) {
        let req = *xfer.request();
        if req.request_type != RequestType::Class
            || req.recipient != Recipient::Interface
            || req.index != u16::from(u8::from(self.interface))
        {
            return;
        }
        let _ = match req.request {
            SET_IDLE => {
                self.idle = (req.value >> 8) as u8;
                xfer.accept()
            }
            SET_PROTOCOL => xfer.accept(),
            SET_REPORT if (req.value >> 8) as u8 == REPORT_TYPE_OUTPUT => {
                // 64 bytes, or 63 (byte 0 stripped: the codec takes both).
                let mut r = [0u8; REPORT_LEN];
                let data = xfer.data();
                if (REPORT_LEN - 1..=REPORT_LEN).contains(&data.len()) {
                    for (dst, src) in r.iter_mut().zip(data.iter()) {
                        *dst = *src;
                    }
                    self.control_report = Some((r, data.len()));
                    xfer.accept()
                } else {
                    xfer.reject()
                }
            }
            _ => xfer.reject(),
        };
    }
}
