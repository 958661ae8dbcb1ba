//! A scripted USB/IP client against the box over loopback TCP: the
//! messages vhci-hcd sends when it imports and enumerates a device, byte
//! for byte, and what the server must answer — including the points where
//! usbip-device 0.2 failed a real kernel (the status ZLP of a no-data OUT
//! answered as the next IN's data, an EP0 STALL never answered, high speed,
//! CMD_UNLINK unanswered, a header split across TCP segments).
//!
//! The client and the server run in one thread: the client writes, then the
//! test pumps the server and the box (network, USB task, control ticks)
//! until the replies it waits for have come.
// A test: it may index, unwrap and panic.
#![allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used
)]
#![allow(clippy::expect_used, clippy::panic)]

use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::time::Duration;

use host_tests::usb_manual::{out, MANUAL_CONFIG, MANUAL_DEVICE};
use usbip_box::postep_box::PoStepBox;
use usbip_box::protocol::{
    self, decode_reply, encode_submit, encode_unlink, status, DeviceInfo, Reply, Submit, Unlink,
    DIR_IN, DIR_OUT, SPEED_FULL,
};
use usbip_box::server::{Event, Server};

const DEVID: u32 = 0x0001_0002;

struct Rig {
    server: Server,
    pbox: PoStepBox,
    client: TcpStream,
    inbuf: Vec<u8>,
    seq: u32,
    /// Seqnums of IN URBs (their replies carry data).
    ins: Vec<u32>,
    events: Vec<Event>,
}

impl Rig {
    /// A rig whose device is imported and enumerated (SET_CONFIGURATION
    /// done), ready for reports.
    fn enumerated() -> Rig {
        let mut rig = Rig::new();
        rig.import();
        rig.enumerate();
        rig
    }

    fn new() -> Rig {
        let server = Server::bind("127.0.0.1:0", PoStepBox::device_info()).unwrap();
        let addr = server.local_addr().unwrap();
        let mut pbox = PoStepBox::power_up(2);
        // Configure the simulated chips before a host comes.
        for _ in 0..30 {
            pbox.tick();
        }
        let client = TcpStream::connect(addr).unwrap();
        client.set_nodelay(true).unwrap();
        client
            .set_read_timeout(Some(Duration::from_millis(1)))
            .unwrap();
        Rig {
            server,
            pbox,
            client,
            inbuf: Vec::new(),
            seq: 0,
            ins: Vec::new(),
            events: Vec::new(),
        }
    }

    /// Server, box and network one turn; `ticks` control ticks.
    fn pump(&mut self, ticks: u32) {
        let port = self.pbox.port().clone();
        self.events.extend(self.server.poll(&port));
        self.pbox.usb_task();
        for _ in 0..ticks {
            self.pbox.tick();
        }
        if let Some(e) = self.server.flush(self.pbox.port()) {
            self.events.push(e);
        }
        let mut buf = [0u8; 4096];
        match self.client.read(&mut buf) {
            Ok(n) => self.inbuf.extend_from_slice(&buf[..n]),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(e) => panic!("client read: {e}"),
        }
    }

    /// Raw bytes of exactly `n`, pumping until they came.
    fn raw(&mut self, n: usize) -> Vec<u8> {
        for _ in 0..500 {
            if self.inbuf.len() >= n {
                return self.inbuf.drain(..n).collect();
            }
            self.pump(0);
        }
        panic!("{} of {n} bytes came", self.inbuf.len());
    }

    fn send(&mut self, bytes: &[u8]) {
        self.client.write_all(bytes).unwrap();
    }

    fn import(&mut self) {
        self.send(&protocol::encode_req_import("1-1"));
        let r = self.raw(8 + 312);
        assert_eq!(&r[..8], &[0x01, 0x11, 0x00, 0x03, 0, 0, 0, 0]);
        let info = DeviceInfo::decode_record(&r[8..]).unwrap();
        assert_eq!(info.speed, SPEED_FULL, "full speed, as OTG FS");
        assert_eq!(info.devid(), DEVID);
    }

    fn next_seq(&mut self) -> u32 {
        self.seq += 1;
        self.seq
    }

    fn submit_bytes(
        &mut self,
        ep: u32,
        dir: u32,
        len: u32,
        setup: [u8; 8],
        data: &[u8],
    ) -> (u32, Vec<u8>) {
        let seqnum = self.next_seq();
        if dir == DIR_IN {
            self.ins.push(seqnum);
        }
        let bytes = encode_submit(&Submit::transfer(
            seqnum,
            DEVID,
            (ep, dir),
            len,
            setup,
            data,
        ));
        (seqnum, bytes)
    }

    /// Send a URB; its seqnum.
    fn submit(&mut self, ep: u32, dir: u32, len: u32, setup: [u8; 8], data: &[u8]) -> u32 {
        let (seqnum, bytes) = self.submit_bytes(ep, dir, len, setup, data);
        self.send(&bytes);
        seqnum
    }

    fn unlink(&mut self, target: u32) -> u32 {
        let seqnum = self.next_seq();
        self.send(&encode_unlink(&Unlink {
            seqnum,
            devid: DEVID,
            direction: DIR_IN,
            ep: 1,
            unlink_seqnum: target,
        }));
        seqnum
    }

    /// The next reply, pumping `ticks` control ticks per turn while waiting.
    fn reply_ticking(&mut self, ticks: u32) -> Reply {
        for _ in 0..2000 {
            let ins = self.ins.clone();
            if let Some((r, n)) = decode_reply(&self.inbuf, |s| ins.contains(&s)) {
                self.inbuf.drain(..n);
                return r;
            }
            self.pump(ticks);
        }
        panic!("no reply (events {:?})", self.events);
    }

    fn reply(&mut self) -> Reply {
        self.reply_ticking(0)
    }

    /// No reply comes within `turns` pumps (with a tick each).
    fn assert_quiet(&mut self, turns: u32) {
        for _ in 0..turns {
            self.pump(1);
        }
        let ins = self.ins.clone();
        assert_eq!(decode_reply(&self.inbuf, |s| ins.contains(&s)), None);
    }

    /// A control IN transfer: (status, data).
    fn control_in(&mut self, setup: [u8; 8]) -> (i32, Vec<u8>) {
        let len = u32::from(u16::from_le_bytes([setup[6], setup[7]]));
        let s = self.submit(0, DIR_IN, len, setup, &[]);
        let (status, actual_length, data) = self.submit_reply(s);
        assert_eq!(actual_length as usize, data.len());
        (status, data)
    }

    /// The next reply, which must be URB `s`'s RET_SUBMIT: (status,
    /// actual_length, data).
    fn submit_reply(&mut self, s: u32) -> (i32, u32, Vec<u8>) {
        match self.reply() {
            Reply::Submit {
                seqnum,
                status,
                actual_length,
                data,
            } => {
                assert_eq!(seqnum, s);
                (status, actual_length, data)
            }
            r => panic!("{r:?}"),
        }
    }

    /// A control OUT transfer: (status, actual_length).
    fn control_out(&mut self, setup: [u8; 8], data: &[u8]) -> (i32, u32) {
        let s = self.submit(0, DIR_OUT, data.len() as u32, setup, data);
        let (status, actual_length, data) = self.submit_reply(s);
        assert!(data.is_empty());
        (status, actual_length)
    }

    fn get_descriptor(&mut self, kind: u8, index: u8, len: u16) -> Vec<u8> {
        let [l0, l1] = len.to_le_bytes();
        let lang = if kind == 3 && index != 0 { 0x09 } else { 0 };
        let lang_hi = if lang != 0 { 0x04 } else { 0 };
        let (st, data) = self.control_in([0x80, 0x06, index, kind, lang, lang_hi, l0, l1]);
        assert_eq!(st, status::OK, "GET_DESCRIPTOR {kind}/{index}");
        data
    }

    /// What hub_port_connect and usb_new_device send, in their order.
    fn enumerate(&mut self) {
        let d = self.get_descriptor(1, 0, 64);
        assert_eq!(d.len(), 18);
        let d = self.get_descriptor(1, 0, 18);
        assert_eq!(d, MANUAL_DEVICE);
        assert_eq!(self.get_descriptor(2, 0, 9), MANUAL_CONFIG[..9]);
        assert_eq!(self.get_descriptor(2, 0, 41), MANUAL_CONFIG);
        assert_eq!(self.get_descriptor(3, 0, 255), [4, 3, 0x09, 0x04]);
        assert_eq!(
            self.control_out([0x00, 0x09, 1, 0, 0, 0, 0, 0], &[]),
            (0, 0)
        );
        assert!(self.pbox.configured());
    }

    fn out_report(&mut self, report: &[u8]) -> u32 {
        self.submit(1, DIR_OUT, report.len() as u32, [0; 8], report)
    }

    fn in_urb(&mut self) -> u32 {
        self.submit(1, DIR_IN, 64, [0; 8], &[])
    }
}

fn string(d: &[u8]) -> String {
    let units: Vec<u16> = d[2..]
        .chunks(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    String::from_utf16(&units).unwrap()
}

#[test]
fn devlist_names_one_full_speed_device_with_one_hid_interface() {
    let mut rig = Rig::new();
    rig.send(&protocol::encode_req_devlist());
    let r = rig.raw(8 + 4 + 312 + 4);
    assert_eq!(&r[..12], &[0x01, 0x11, 0x00, 0x05, 0, 0, 0, 0, 0, 0, 0, 1]);
    let info = DeviceInfo::decode_record(&r[12..]).unwrap();
    assert_eq!(info.busid, "1-1");
    assert_eq!(
        (info.vendor, info.product, info.bcd_device),
        (0x1DC3, 0x0641, 0x0100)
    );
    assert_eq!(info.speed, SPEED_FULL);
    assert_eq!(&r[324..], &[3, 0, 0, 0], "interface HID 3/0/0");
    assert!(rig.events.contains(&Event::Listed));
}

#[test]
fn an_import_of_another_bus_id_is_refused() {
    let mut rig = Rig::new();
    rig.send(&protocol::encode_req_import("2-1"));
    assert_eq!(rig.raw(8), [0x01, 0x11, 0x00, 0x03, 0, 0, 0, 1]);
    assert!(!rig.server.is_imported());
}

#[test]
fn enumeration_reads_the_manual_s_descriptors_and_configures() {
    let mut rig = Rig::enumerated();
    assert_eq!(string(&rig.get_descriptor(3, 1, 255)), "PoLabs");
    assert_eq!(string(&rig.get_descriptor(3, 2, 255)), "PoStep60-256");
    // The serial is 72 bytes: a full 64-byte packet, then a short one.
    let serial = rig.get_descriptor(3, 3, 255);
    assert_eq!(serial.len(), 72);
    assert_eq!(string(&serial).len(), 35);
    assert_eq!(string(&rig.get_descriptor(3, 4, 255)), "HID");
    assert_eq!(rig.server.info_mut().busid, "1-1");
    assert_eq!(rig.pbox.port().stray_ep0_writes(), 0);
}

#[test]
fn a_no_data_out_completes_after_its_status_and_the_next_in_gets_its_own_data() {
    // usbip-device 0.2 completed SET_CONFIGURATION before the status ZLP was
    // queued; the ZLP then came back as the next GET_DESCRIPTOR's data.
    let mut rig = Rig::new();
    rig.import();
    rig.get_descriptor(1, 0, 18);
    for _ in 0..3 {
        assert_eq!(rig.control_out([0x00, 0x09, 1, 0, 0, 0, 0, 0], &[]), (0, 0));
        assert_eq!(rig.get_descriptor(1, 0, 18), MANUAL_DEVICE);
        assert_eq!(
            rig.control_out([0x01, 0x0B, 0, 0, 0, 0, 0, 0], &[]).0,
            0,
            "SET_INTERFACE 0"
        );
        assert_eq!(rig.get_descriptor(2, 0, 9), MANUAL_CONFIG[..9]);
    }
    assert_eq!(rig.pbox.port().stray_ep0_writes(), 0);
}

#[test]
fn a_refused_request_stalls_at_once_and_the_next_one_works() {
    let mut rig = Rig::enumerated();
    // BOS (type 15): a USB 2.00 device has none.
    let (st, data) = rig.control_in([0x80, 0x06, 0, 15, 0, 0, 5, 0]);
    assert_eq!((st, data.len()), (status::STALL, 0));
    // GET_REPORT: the class has no input report to give by control.
    let (st, _) = rig.control_in([0xA1, 0x01, 0x02, 0x01, 0, 0, 64, 0]);
    assert_eq!(st, status::STALL);
    // A class OUT the class does not know.
    assert_eq!(
        rig.control_out([0x21, 0x0C, 0, 0, 0, 0, 0, 0], &[]).0,
        status::STALL
    );
    assert_eq!(rig.get_descriptor(1, 0, 18), MANUAL_DEVICE);
}

#[test]
fn the_report_descriptor_comes_from_the_interface() {
    let mut rig = Rig::enumerated();
    assert_eq!(
        rig.control_out([0x21, 0x0A, 0, 0, 0, 0, 0, 0], &[]),
        (0, 0),
        "SET_IDLE"
    );
    let (st, d) = rig.control_in([0x81, 0x06, 0, 0x22, 0, 0, 0x61, 0]);
    assert_eq!(st, 0);
    assert_eq!(d, bridge_logic::transport::usb::REPORT_DESCRIPTOR);
}

#[test]
fn an_out_report_on_ep1_is_answered_on_ep_0x81() {
    let mut rig = Rig::enumerated();
    // The IN URB first, as usbhid keeps one submitted while hidraw is open.
    let urb = rig.in_urb();
    let sent = rig.out_report(&out(0x01));
    match rig.reply() {
        Reply::Submit {
            seqnum,
            status,
            actual_length,
            ..
        } => {
            assert_eq!((seqnum, status, actual_length), (sent, 0, 64));
        }
        r => panic!("{r:?}"),
    }
    match rig.reply() {
        Reply::Submit {
            seqnum,
            status,
            data,
            ..
        } => {
            assert_eq!((seqnum, status), (urb, 0));
            assert_eq!(data.len(), 64);
            assert_eq!(
                (data[0], data[5], data[14]),
                (0x02, 0xAB, 0),
                "device info, done"
            );
        }
        r => panic!("{r:?}"),
    }
    // The other order: the answer waits in the endpoint for the IN URB.
    let sent = rig.out_report(&out(0xC1));
    assert!(matches!(rig.reply(), Reply::Submit { seqnum, status: 0, .. } if seqnum == sent));
    rig.assert_quiet(5);
    rig.in_urb();
    assert!(matches!(rig.reply(), Reply::Submit { status: 0, data, .. } if data[15] == 0xC0));
}

#[test]
fn set_report_by_control_is_taken_like_an_out_report() {
    let mut rig = Rig::enumerated();
    let r = out(0xC1);
    assert_eq!(
        rig.control_out([0x21, 0x09, 0x02, 0x02, 0, 0, 64, 0], &r),
        (0, 64)
    );
    rig.in_urb();
    assert!(matches!(rig.reply(), Reply::Submit { status: 0, data, .. } if data[15] == 0xC0));
}

#[test]
fn unlink_cancels_a_waiting_urb_and_says_so_and_a_done_one_gets_status_0() {
    let mut rig = Rig::enumerated();
    let urb = rig.in_urb();
    rig.assert_quiet(3);
    let u = rig.unlink(urb);
    assert_eq!(
        rig.reply(),
        Reply::Unlink {
            seqnum: u,
            status: status::UNLINKED
        }
    );
    // No RET_SUBMIT for the unlinked URB, even once there is data.
    rig.out_report(&out(0x01));
    assert!(matches!(
        rig.reply(),
        Reply::Submit {
            actual_length: 64,
            ..
        }
    ));
    rig.assert_quiet(5);
    // The answer stayed in the endpoint: the next IN URB gets it.
    let urb = rig.in_urb();
    assert!(matches!(rig.reply(), Reply::Submit { seqnum, status: 0, .. } if seqnum == urb));
    let u = rig.unlink(urb);
    assert_eq!(
        rig.reply(),
        Reply::Unlink {
            seqnum: u,
            status: 0
        }
    );
    assert_eq!(rig.pbox.port().pending_urbs(), 0);
}

#[test]
fn commands_split_at_every_byte_are_served_like_whole_ones() {
    let mut rig = Rig::new();
    rig.import();
    // GET_DESCRIPTOR device, then SET_CONFIGURATION, then an OUT report: one
    // byte per TCP write, the server polled between bytes.
    let (a, mut bytes) = rig.submit_bytes(0, DIR_IN, 18, [0x80, 0x06, 0, 1, 0, 0, 18, 0], &[]);
    let (b, more) = rig.submit_bytes(0, DIR_OUT, 0, [0x00, 0x09, 1, 0, 0, 0, 0, 0], &[]);
    bytes.extend_from_slice(&more);
    let (c, more) = rig.submit_bytes(1, DIR_OUT, 64, [0; 8], &out(0x01));
    bytes.extend_from_slice(&more);
    for byte in bytes {
        rig.send(&[byte]);
        rig.pump(0);
    }
    let got: Vec<(u32, i32)> = (0..3)
        .map(|_| match rig.reply() {
            Reply::Submit { seqnum, status, .. } => (seqnum, status),
            r => panic!("{r:?}"),
        })
        .collect();
    assert_eq!(got, vec![(a, 0), (b, 0), (c, 0)]);
}

#[test]
fn the_stream_0xa0_flows_into_in_urbs_every_10_ms() {
    let mut rig = Rig::enumerated();
    rig.out_report(&out(0xA0));
    rig.reply();
    rig.in_urb();
    rig.reply_ticking(1); // the acknowledgement
    let mut at = Vec::new();
    for _ in 0..5 {
        rig.in_urb();
        match rig.reply_ticking(1) {
            Reply::Submit { data, .. } => assert_eq!(data[15], 0xA0),
            r => panic!("{r:?}"),
        }
        at.push(rig.pbox.clock.now_ms());
    }
    assert!(at.windows(2).all(|w| w[1] - w[0] == 10), "{at:?}");
}

#[test]
fn a_client_that_goes_away_unplugs_the_device_and_a_new_import_enumerates_again() {
    let mut rig = Rig::enumerated();
    rig.out_report(&out(0xA0));
    rig.reply();
    rig.client.shutdown(std::net::Shutdown::Both).unwrap();
    for _ in 0..20 {
        rig.pump(1);
    }
    assert!(rig.events.iter().any(|e| matches!(e, Event::Detached(_))));
    assert!(!rig.pbox.configured(), "suspended: not configured");
    let addr = rig.server.local_addr().unwrap();
    rig.client = TcpStream::connect(addr).unwrap();
    rig.client
        .set_read_timeout(Some(Duration::from_millis(1)))
        .unwrap();
    rig.inbuf.clear();
    rig.import();
    rig.enumerate();
    assert_eq!(rig.pbox.port().resets(), 2);
    // The stream ended with the link: only the answer to the new command comes.
    rig.out_report(&out(0x01));
    rig.reply();
    rig.in_urb();
    assert!(matches!(rig.reply_ticking(1), Reply::Submit { data, .. } if data[5] == 0xAB));
    rig.in_urb();
    rig.assert_quiet(30);
}

#[test]
fn garbage_after_an_import_closes_the_connection_without_a_panic() {
    let mut rig = Rig::new();
    rig.import();
    rig.send(&[0, 0, 0, 9]);
    rig.send(&[0xFF; 44]);
    for _ in 0..10 {
        rig.pump(0);
    }
    assert!(
        rig.events
            .iter()
            .any(|e| matches!(e, Event::Detached(w) if w.contains("not USB/IP"))),
        "{:?}",
        rig.events
    );
    assert!(!rig.server.is_imported());
}

#[test]
fn a_system_reset_0x02_unplugs_and_the_next_run_is_boot_mode() {
    let mut rig = Rig::enumerated();
    let port = rig.pbox.port().clone();
    rig.out_report(&out(0x02));
    rig.reply();
    let mut restarted = None;
    for _ in 0..500 {
        if let Some(r) = rig.pbox.tick() {
            restarted = Some(r);
            break;
        }
        rig.pump(0);
    }
    assert_eq!(
        restarted,
        Some(usbip_box::postep_box::Restart::Into(
            bridge_logic::bridge::RunMode::Boot
        ))
    );
    rig.server.unplug(&port);
    assert_eq!(rig.pbox.runs, 2);
    assert!(!rig.server.is_imported());
}

#[test]
fn a_transfer_that_ends_on_a_full_packet_at_wlength_leaves_no_zlp_behind() {
    // The serial string is 72 bytes: asked for 64, usb-device sends one full
    // packet and would follow it with a ZLP; the host is done at wLength.
    let mut rig = Rig::enumerated();
    let s = rig.get_descriptor(3, 3, 64);
    assert_eq!(s.len(), 64);
    assert_eq!(rig.get_descriptor(1, 0, 18), MANUAL_DEVICE);
    assert_eq!(rig.get_descriptor(3, 3, 255).len(), 72);
    assert_eq!(rig.pbox.port().stray_ep0_writes(), 0);
}
