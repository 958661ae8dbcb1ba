//! The USB/IP wire format (Linux `Documentation/usb/usbip_protocol.rst`,
//! protocol version 1.1.1): the two operations a client starts a connection
//! with, and the four URB messages that follow an import. Everything is
//! big-endian ("network byte order").
//!
//! # What it guarantees
//!
//! * **Decoding never panics and never trusts a length**: a [`Decoder`]
//!   takes bytes as TCP hands them over (a header split across segments,
//!   several messages in one read) and yields whole messages only; a field
//!   it cannot accept (an unknown command, an OUT buffer beyond
//!   [`MAX_TRANSFER`], more than [`MAX_ISO_PACKETS`] iso descriptors, a
//!   version other than 1.1.1) is an [`Error`], after which the connection
//!   must be closed (the stream has lost its framing).
//! * **Encoding is exact**: every reply has the kernel's field sizes (48-byte
//!   URB headers, 312-byte device records, 4-byte interface records).
//!
//! # Messages
//!
//! | message | code | bytes |
//! |---|---|---|
//! | `OP_REQ_DEVLIST` / `OP_REP_DEVLIST` | 0x8005 / 0x0005 | 8 / 8 + 4 + n × (312 + 4 × interfaces) |
//! | `OP_REQ_IMPORT` / `OP_REP_IMPORT` | 0x8003 / 0x0003 | 8 + 32 / 8 (+ 312 when the status is 0) |
//! | `USBIP_CMD_SUBMIT` / `USBIP_RET_SUBMIT` | 1 / 3 | 48 + OUT data (+ 16 per iso packet) / 48 + IN data |
//! | `USBIP_CMD_UNLINK` / `USBIP_RET_UNLINK` | 2 / 4 | 48 / 48 |

/// Protocol version 1.1.1, as the kernel's `usbip` tools send it.
pub const VERSION: u16 = 0x0111;
pub const OP_REQ_DEVLIST: u16 = 0x8005;
pub const OP_REP_DEVLIST: u16 = 0x0005;
pub const OP_REQ_IMPORT: u16 = 0x8003;
pub const OP_REP_IMPORT: u16 = 0x0003;
pub const CMD_SUBMIT: u32 = 1;
pub const CMD_UNLINK: u32 = 2;
pub const RET_SUBMIT: u32 = 3;
pub const RET_UNLINK: u32 = 4;
/// Every URB message's header.
pub const HEADER_LEN: usize = 48;
/// An operation's header (version, code, status).
pub const OP_HEADER_LEN: usize = 8;
/// `busid` field length.
pub const BUSID_LEN: usize = 32;
/// `path` field length.
pub const PATH_LEN: usize = 256;
/// A device record: path, busid, then 24 bytes of numbers.
pub const DEVICE_RECORD_LEN: usize = PATH_LEN + BUSID_LEN + 24;
/// The longest OUT transfer a CMD_SUBMIT may carry here (the kernel's own
/// limit for a URB is far larger; a HID device never sees more than a
/// report, a control transfer more than 64 KiB).
pub const MAX_TRANSFER: u32 = 64 * 1024;
/// The most iso packet descriptors a CMD_SUBMIT may announce.
pub const MAX_ISO_PACKETS: u32 = 1024;
/// `number_of_packets` of a transfer that is not isochronous, as older
/// kernels send it (newer ones send 0).
pub const NOT_ISO: u32 = 0xFFFF_FFFF;

/// URB direction field.
pub const DIR_OUT: u32 = 0;
pub const DIR_IN: u32 = 1;

/// `enum usb_device_speed`: full speed (12 Mbit/s), what the STM32F405's
/// OTG FS core is.
pub const SPEED_FULL: u32 = 2;

/// URB status codes (negative errno, as the kernel gives URBs back).
pub mod status {
    /// Done.
    pub const OK: i32 = 0;
    /// The endpoint stalled (`-EPIPE`): the request was refused.
    pub const STALL: i32 = -32;
    /// The URB was unlinked before it completed (`-ECONNRESET`).
    pub const UNLINKED: i32 = -104;
    /// A protocol error (`-EPROTO`): the device answered out of turn.
    pub const PROTOCOL: i32 = -71;
    /// No such endpoint or transfer type (`-EINVAL`).
    pub const INVALID: i32 = -22;
}

/// Why a byte stream is not USB/IP.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// An operation with another protocol version.
    Version(u16),
    /// An operation code this server does not know.
    UnknownOp(u16),
    /// A URB command other than CMD_SUBMIT / CMD_UNLINK.
    UnknownCommand(u32),
    /// A direction field other than 0 or 1.
    Direction(u32),
    /// An OUT transfer longer than [`MAX_TRANSFER`] or a negative length.
    TransferLength(u32),
    /// More iso descriptors than [`MAX_ISO_PACKETS`].
    IsoPackets(u32),
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Error::Version(v) => write!(f, "protocol version {v:#06x}, 0x0111 expected"),
            Error::UnknownOp(c) => write!(f, "unknown operation {c:#06x}"),
            Error::UnknownCommand(c) => write!(f, "unknown URB command {c:#x}"),
            Error::Direction(d) => write!(f, "URB direction {d}"),
            Error::TransferLength(n) => write!(f, "transfer length {n} beyond {MAX_TRANSFER}"),
            Error::IsoPackets(n) => write!(f, "{n} iso packets beyond {MAX_ISO_PACKETS}"),
        }
    }
}

impl std::error::Error for Error {}

/// A connection's first message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Op {
    /// List the exported devices.
    Devlist,
    /// Import the device with this bus id (the NUL-padded field, trimmed).
    Import { busid: String },
}

/// A USBIP_CMD_SUBMIT: one URB.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Submit {
    pub seqnum: u32,
    pub devid: u32,
    /// [`DIR_OUT`] or [`DIR_IN`].
    pub direction: u32,
    /// Endpoint number 0..=15.
    pub ep: u32,
    pub transfer_flags: u32,
    /// OUT: the length of `data`; IN: how much the host can take.
    pub transfer_buffer_length: u32,
    pub start_frame: u32,
    pub number_of_packets: u32,
    pub interval: u32,
    /// The SETUP packet (control transfers on endpoint 0).
    pub setup: [u8; 8],
    /// OUT data.
    pub data: Vec<u8>,
}

impl Submit {
    /// A plain (not isochronous) transfer as a host submits it: no flags,
    /// start frame or interval; `len` is `transfer_buffer_length`.
    pub fn transfer(
        seqnum: u32,
        devid: u32,
        (ep, direction): (u32, u32),
        len: u32,
        setup: [u8; 8],
        data: &[u8],
    ) -> Submit {
        Submit {
            seqnum,
            devid,
            direction,
            ep,
            transfer_flags: 0,
            transfer_buffer_length: len,
            start_frame: 0,
            number_of_packets: 0,
            interval: 0,
            setup,
            data: data.to_vec(),
        }
    }

    /// The transfer is isochronous (it announced packet descriptors).
    pub fn is_iso(&self) -> bool {
        self.number_of_packets != 0 && self.number_of_packets != NOT_ISO
    }

    pub fn is_in(&self) -> bool {
        self.direction == DIR_IN
    }
}

/// A USBIP_CMD_UNLINK: cancel the URB `unlink_seqnum`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unlink {
    pub seqnum: u32,
    pub devid: u32,
    pub direction: u32,
    pub ep: u32,
    pub unlink_seqnum: u32,
}

/// A URB message from the client.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Command {
    Submit(Submit),
    Unlink(Unlink),
}

/// A reply to the client.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Reply {
    /// USBIP_RET_SUBMIT: the URB `seqnum` completed with `status`; `data`
    /// is what an IN transfer read (its length is `actual_length`), for OUT
    /// `actual_length` says how much was taken.
    Submit {
        seqnum: u32,
        status: i32,
        actual_length: u32,
        data: Vec<u8>,
    },
    /// USBIP_RET_UNLINK for the CMD_UNLINK `seqnum`: `status` is
    /// [`status::UNLINKED`] when the URB was cancelled, 0 when it had
    /// already completed.
    Unlink { seqnum: u32, status: i32 },
}

impl Reply {
    /// The bytes on the wire.
    pub fn encode(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(HEADER_LEN);
        match self {
            Reply::Submit {
                seqnum,
                status,
                actual_length,
                data,
            } => {
                put32(&mut b, RET_SUBMIT);
                put32(&mut b, *seqnum);
                // devid, direction, ep: 0 in replies.
                put32(&mut b, 0);
                put32(&mut b, 0);
                put32(&mut b, 0);
                put32(&mut b, *status as u32);
                put32(&mut b, *actual_length);
                put32(&mut b, 0); // start_frame
                put32(&mut b, 0); // number_of_packets: not iso
                put32(&mut b, 0); // error_count
                b.extend_from_slice(&[0; 8]);
                b.extend_from_slice(data);
            }
            Reply::Unlink { seqnum, status } => {
                put32(&mut b, RET_UNLINK);
                put32(&mut b, *seqnum);
                put32(&mut b, 0);
                put32(&mut b, 0);
                put32(&mut b, 0);
                put32(&mut b, *status as u32);
                b.extend_from_slice(&[0; 24]);
            }
        }
        b
    }
}

/// What OP_REP_DEVLIST and OP_REP_IMPORT say about the device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceInfo {
    /// A sysfs-like path (informative only).
    pub path: String,
    /// The bus id a client imports, e.g. "1-1".
    pub busid: String,
    pub busnum: u32,
    pub devnum: u32,
    /// `enum usb_device_speed` ([`SPEED_FULL`]).
    pub speed: u32,
    pub vendor: u16,
    pub product: u16,
    pub bcd_device: u16,
    pub class: u8,
    pub subclass: u8,
    pub protocol: u8,
    pub configuration_value: u8,
    pub num_configurations: u8,
    /// Class, subclass, protocol of each interface.
    pub interfaces: Vec<(u8, u8, u8)>,
}

impl DeviceInfo {
    /// `busnum << 16 | devnum`, the `devid` of every URB the client sends.
    pub fn devid(&self) -> u32 {
        self.busnum << 16 | (self.devnum & 0xFFFF)
    }

    fn encode_record(&self, b: &mut Vec<u8>) {
        put_padded(b, &self.path, PATH_LEN);
        put_padded(b, &self.busid, BUSID_LEN);
        put32(b, self.busnum);
        put32(b, self.devnum);
        put32(b, self.speed);
        put16(b, self.vendor);
        put16(b, self.product);
        put16(b, self.bcd_device);
        b.extend_from_slice(&[
            self.class,
            self.subclass,
            self.protocol,
            self.configuration_value,
            self.num_configurations,
            u8::try_from(self.interfaces.len()).unwrap_or(u8::MAX),
        ]);
    }

    /// OP_REP_DEVLIST with this one device.
    pub fn encode_devlist(&self) -> Vec<u8> {
        let mut b = Vec::new();
        put16(&mut b, VERSION);
        put16(&mut b, OP_REP_DEVLIST);
        put32(&mut b, 0);
        put32(&mut b, 1);
        self.encode_record(&mut b);
        for (class, subclass, protocol) in &self.interfaces {
            b.extend_from_slice(&[*class, *subclass, *protocol, 0]);
        }
        b
    }

    /// OP_REP_IMPORT: status 0 and the device, or status 1 alone.
    pub fn encode_import(info: Option<&DeviceInfo>) -> Vec<u8> {
        let mut b = Vec::new();
        put16(&mut b, VERSION);
        put16(&mut b, OP_REP_IMPORT);
        match info {
            Some(d) => {
                put32(&mut b, 0);
                d.encode_record(&mut b);
            }
            None => put32(&mut b, 1),
        }
        b
    }

    /// The device record of an OP_REP_IMPORT body (a client's view; the
    /// interfaces are not in it).
    pub fn decode_record(r: &[u8]) -> Option<DeviceInfo> {
        // The numeric fields follow the path and the bus id.
        let fields = r.get(PATH_LEN..)?.get(BUSID_LEN..)?;
        let n = |at: usize| get32(fields, at);
        let h = |at: usize| get16(fields, at);
        let byte = |at: usize| fields.get(at).copied();
        Some(DeviceInfo {
            path: padded_str(r.get(..PATH_LEN)?),
            busid: padded_str(r.get(PATH_LEN..PATH_LEN + BUSID_LEN)?),
            busnum: n(0)?,
            devnum: n(4)?,
            speed: n(8)?,
            vendor: h(12)?,
            product: h(14)?,
            bcd_device: h(16)?,
            class: byte(18)?,
            subclass: byte(19)?,
            protocol: byte(20)?,
            configuration_value: byte(21)?,
            num_configurations: byte(22)?,
            interfaces: Vec::new(),
        })
    }
}

/// Client side: the devices of an OP_REP_DEVLIST (`None` while it is
/// incomplete or when it is not one).
pub fn decode_devlist(b: &[u8]) -> Option<Vec<DeviceInfo>> {
    if get16(b, 0)? != VERSION || get16(b, 2)? != OP_REP_DEVLIST || get32(b, 4)? != 0 {
        return None;
    }
    let n = get32(b, 8)?;
    let mut at = OP_HEADER_LEN + 4;
    let mut devices = Vec::new();
    for _ in 0..n.min(64) {
        let record = b.get(at..)?.get(..DEVICE_RECORD_LEN)?;
        let mut d = DeviceInfo::decode_record(record)?;
        let interfaces = usize::from(*record.last()?);
        at = at.checked_add(DEVICE_RECORD_LEN)?;
        for _ in 0..interfaces {
            let i = b.get(at..)?.get(..4)?;
            d.interfaces.push((*i.first()?, *i.get(1)?, *i.get(2)?));
            at = at.checked_add(4)?;
        }
        devices.push(d);
    }
    Some(devices)
}

/// Client side (tests, the kernel check's attach): OP_REQ_DEVLIST.
pub fn encode_req_devlist() -> Vec<u8> {
    let mut b = Vec::new();
    put16(&mut b, VERSION);
    put16(&mut b, OP_REQ_DEVLIST);
    put32(&mut b, 0);
    b
}

/// Client side: OP_REQ_IMPORT of `busid`.
pub fn encode_req_import(busid: &str) -> Vec<u8> {
    let mut b = Vec::new();
    put16(&mut b, VERSION);
    put16(&mut b, OP_REQ_IMPORT);
    put32(&mut b, 0);
    put_padded(&mut b, busid, BUSID_LEN);
    b
}

/// Client side (tests): a CMD_SUBMIT's bytes.
pub fn encode_submit(s: &Submit) -> Vec<u8> {
    let mut b = Vec::with_capacity(HEADER_LEN.saturating_add(s.data.len()));
    for v in [
        CMD_SUBMIT,
        s.seqnum,
        s.devid,
        s.direction,
        s.ep,
        s.transfer_flags,
        s.transfer_buffer_length,
        s.start_frame,
        s.number_of_packets,
        s.interval,
    ] {
        put32(&mut b, v);
    }
    b.extend_from_slice(&s.setup);
    b.extend_from_slice(&s.data);
    b
}

/// Client side (tests): a CMD_UNLINK's bytes.
pub fn encode_unlink(u: &Unlink) -> Vec<u8> {
    let mut b = Vec::with_capacity(HEADER_LEN);
    for v in [
        CMD_UNLINK,
        u.seqnum,
        u.devid,
        u.direction,
        u.ep,
        u.unlink_seqnum,
    ] {
        put32(&mut b, v);
    }
    b.extend_from_slice(&[0; 24]);
    b
}

/// Client side (tests): one reply decoded from the front of `b`, and how
/// many bytes it took (`None` while incomplete). `in_lengths` is not needed:
/// a RET_SUBMIT's data length is its `actual_length` for IN transfers, and
/// the caller says whether `seqnum` was IN through `is_in`.
pub fn decode_reply(b: &[u8], is_in: impl Fn(u32) -> bool) -> Option<(Reply, usize)> {
    let head = b.get(..HEADER_LEN)?;
    let command = get32(head, 0)?;
    let seqnum = get32(head, 4)?;
    let status = get32(head, 20)? as i32;
    match command {
        RET_SUBMIT => {
            let actual_length = get32(head, 24)?;
            let n = if is_in(seqnum) {
                actual_length as usize
            } else {
                0
            };
            let data = b.get(HEADER_LEN..)?.get(..n)?.to_vec();
            Some((
                Reply::Submit {
                    seqnum,
                    status,
                    actual_length,
                    data,
                },
                HEADER_LEN.checked_add(n)?,
            ))
        }
        RET_UNLINK => Some((Reply::Unlink { seqnum, status }, HEADER_LEN)),
        _ => None,
    }
}

/// Reassembles messages from a byte stream.
#[derive(Debug, Default)]
pub struct Decoder {
    buf: Vec<u8>,
}

impl Decoder {
    pub fn new() -> Decoder {
        Decoder::default()
    }

    /// Bytes as they came from the socket.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes received but not yet part of a whole message.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// The next whole operation (a connection's first message), if there
    /// is one.
    pub fn next_op(&mut self) -> Result<Option<Op>, Error> {
        let Some(head) = self.buf.get(..OP_HEADER_LEN) else {
            return Ok(None);
        };
        let version = get16(head, 0).unwrap_or(0);
        let code = get16(head, 2).unwrap_or(0);
        if version != VERSION {
            return Err(Error::Version(version));
        }
        match code {
            OP_REQ_DEVLIST => {
                self.buf.drain(..OP_HEADER_LEN);
                Ok(Some(Op::Devlist))
            }
            OP_REQ_IMPORT => {
                let end = OP_HEADER_LEN + BUSID_LEN;
                let Some(id) = self.buf.get(OP_HEADER_LEN..end) else {
                    return Ok(None);
                };
                let busid = padded_str(id);
                self.buf.drain(..end);
                Ok(Some(Op::Import { busid }))
            }
            other => Err(Error::UnknownOp(other)),
        }
    }

    /// The next whole URB command, if there is one.
    pub fn next_command(&mut self) -> Result<Option<Command>, Error> {
        let Some(head) = self.buf.get(..HEADER_LEN) else {
            return Ok(None);
        };
        let w = |i: usize| i.checked_mul(4).and_then(|at| get32(head, at)).unwrap_or(0);
        let command = w(0);
        match command {
            CMD_SUBMIT => {
                let direction = w(3);
                if direction > DIR_IN {
                    return Err(Error::Direction(direction));
                }
                let length = w(6);
                if length > MAX_TRANSFER {
                    return Err(Error::TransferLength(length));
                }
                let packets = w(8);
                let iso = packets != 0 && packets != NOT_ISO;
                if iso && packets > MAX_ISO_PACKETS {
                    return Err(Error::IsoPackets(packets));
                }
                let data_len = if direction == DIR_OUT {
                    length as usize
                } else {
                    0
                };
                // Both bounded above (MAX_TRANSFER, MAX_ISO_PACKETS); saturating
                // all the same, so no header can make the sum wrap.
                let iso_len = if iso {
                    (packets as usize).saturating_mul(16)
                } else {
                    0
                };
                let total = HEADER_LEN.saturating_add(data_len).saturating_add(iso_len);
                if self.buf.len() < total {
                    return Ok(None);
                }
                let mut setup = [0u8; 8];
                setup.copy_from_slice(head.get(40..48).unwrap_or(&[0; 8]));
                let submit = Submit {
                    seqnum: w(1),
                    devid: w(2),
                    direction,
                    ep: w(4),
                    transfer_flags: w(5),
                    transfer_buffer_length: length,
                    start_frame: w(7),
                    number_of_packets: packets,
                    interval: w(9),
                    setup,
                    data: self
                        .buf
                        .get(HEADER_LEN..)
                        .and_then(|d| d.get(..data_len))
                        .unwrap_or(&[])
                        .to_vec(),
                };
                self.buf.drain(..total);
                Ok(Some(Command::Submit(submit)))
            }
            CMD_UNLINK => {
                let unlink = Unlink {
                    seqnum: w(1),
                    devid: w(2),
                    direction: w(3),
                    ep: w(4),
                    unlink_seqnum: w(5),
                };
                self.buf.drain(..HEADER_LEN);
                Ok(Some(Command::Unlink(unlink)))
            }
            other => Err(Error::UnknownCommand(other)),
        }
    }
}

fn put16(b: &mut Vec<u8>, v: u16) {
    b.extend_from_slice(&v.to_be_bytes());
}

fn put32(b: &mut Vec<u8>, v: u32) {
    b.extend_from_slice(&v.to_be_bytes());
}

/// `s` NUL-padded (and cut) to `len` bytes, the last always NUL.
fn put_padded(b: &mut Vec<u8>, s: &str, len: usize) {
    let bytes = s.as_bytes();
    let n = bytes.len().min(len.saturating_sub(1));
    b.extend_from_slice(bytes.get(..n).unwrap_or(&[]));
    b.resize(b.len().saturating_add(len.saturating_sub(n)), 0);
}

fn padded_str(b: &[u8]) -> String {
    let end = b.iter().position(|c| *c == 0).unwrap_or(b.len());
    String::from_utf8_lossy(b.get(..end).unwrap_or(&[])).into_owned()
}

fn get16(b: &[u8], at: usize) -> Option<u16> {
    let bytes = b.get(at..)?.get(..2)?;
    Some(u16::from_be_bytes(bytes.try_into().ok()?))
}

fn get32(b: &[u8], at: usize) -> Option<u32> {
    let bytes = b.get(at..)?.get(..4)?;
    Some(u32::from_be_bytes(bytes.try_into().ok()?))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info() -> DeviceInfo {
        DeviceInfo {
            path: "/sys/devices/usbip-box/1-1".into(),
            busid: "1-1".into(),
            busnum: 1,
            devnum: 2,
            speed: SPEED_FULL,
            vendor: 0x1DC3,
            product: 0x0641,
            bcd_device: 0x0100,
            class: 0,
            subclass: 0,
            protocol: 0,
            configuration_value: 1,
            num_configurations: 1,
            interfaces: vec![(3, 0, 0)],
        }
    }

    fn get_descriptor(seqnum: u32) -> Submit {
        let setup = [0x80, 0x06, 0x00, 0x01, 0x00, 0x00, 0x40, 0x00];
        Submit {
            transfer_flags: 0x200,
            ..Submit::transfer(seqnum, 0x0001_0002, (0, DIR_IN), 64, setup, &[])
        }
    }

    #[test]
    fn a_cmd_submit_is_48_bytes_big_endian_with_the_setup_at_40() {
        let b = encode_submit(&get_descriptor(7));
        assert_eq!(b.len(), 48);
        assert_eq!(&b[0..8], &[0, 0, 0, 1, 0, 0, 0, 7]);
        assert_eq!(&b[8..12], &[0, 1, 0, 2], "devid busnum << 16 | devnum");
        assert_eq!(&b[12..16], &[0, 0, 0, 1], "IN");
        assert_eq!(&b[24..28], &[0, 0, 0, 64]);
        assert_eq!(
            &b[40..48],
            &[0x80, 0x06, 0x00, 0x01, 0x00, 0x00, 0x40, 0x00]
        );
    }

    #[test]
    fn submit_and_unlink_decode_to_what_was_encoded() {
        let mut out = get_descriptor(9);
        out.direction = DIR_OUT;
        out.ep = 1;
        out.transfer_buffer_length = 3;
        out.data = vec![1, 2, 3];
        let unlink = Unlink {
            seqnum: 10,
            devid: 0x0001_0002,
            direction: DIR_IN,
            ep: 1,
            unlink_seqnum: 9,
        };
        let mut d = Decoder::new();
        d.push(&encode_submit(&get_descriptor(8)));
        d.push(&encode_submit(&out));
        d.push(&encode_unlink(&unlink));
        assert_eq!(
            d.next_command(),
            Ok(Some(Command::Submit(get_descriptor(8))))
        );
        assert_eq!(d.next_command(), Ok(Some(Command::Submit(out))));
        assert_eq!(d.next_command(), Ok(Some(Command::Unlink(unlink))));
        assert_eq!(d.next_command(), Ok(None));
        assert_eq!(d.pending(), 0);
    }

    #[test]
    fn a_message_split_at_every_byte_decodes_once_whole() {
        let mut out = get_descriptor(3);
        out.direction = DIR_OUT;
        out.ep = 1;
        out.transfer_buffer_length = 64;
        out.data = (0..64).collect();
        let bytes = encode_submit(&out);
        for cut in 1..bytes.len() {
            let mut d = Decoder::new();
            d.push(&bytes[..cut]);
            assert_eq!(d.next_command(), Ok(None), "cut at {cut}");
            d.push(&bytes[cut..]);
            assert_eq!(
                d.next_command(),
                Ok(Some(Command::Submit(out.clone()))),
                "cut at {cut}"
            );
        }
        // One byte at a time.
        let mut d = Decoder::new();
        let mut got = Vec::new();
        for b in &bytes {
            d.push(&[*b]);
            if let Some(c) = d.next_command().unwrap() {
                got.push(c);
            }
        }
        assert_eq!(got, vec![Command::Submit(out)]);
    }

    #[test]
    fn an_in_submit_carries_no_data_even_with_a_buffer_length() {
        let mut d = Decoder::new();
        d.push(&encode_submit(&get_descriptor(1)));
        assert!(matches!(d.next_command(), Ok(Some(Command::Submit(s))) if s.data.is_empty()));
    }

    #[test]
    fn iso_descriptors_are_consumed_with_the_submit() {
        let mut s = get_descriptor(4);
        s.number_of_packets = 2;
        let mut bytes = encode_submit(&s);
        bytes.extend_from_slice(&[0xAA; 32]);
        bytes.extend_from_slice(&encode_submit(&get_descriptor(5)));
        let mut d = Decoder::new();
        d.push(&bytes);
        assert!(matches!(d.next_command(), Ok(Some(Command::Submit(s))) if s.is_iso()));
        assert!(
            matches!(d.next_command(), Ok(Some(Command::Submit(s))) if s.seqnum == 5 && !s.is_iso())
        );
        // The old kernels' "not iso" marker is not iso.
        s.number_of_packets = NOT_ISO;
        assert!(!s.is_iso());
    }

    #[test]
    fn bad_fields_are_errors_not_panics() {
        let mut s = get_descriptor(1);
        s.direction = 2;
        let mut d = Decoder::new();
        d.push(&encode_submit(&s));
        assert_eq!(d.next_command(), Err(Error::Direction(2)));

        let mut s = get_descriptor(1);
        s.direction = DIR_OUT;
        s.transfer_buffer_length = MAX_TRANSFER + 1;
        let mut d = Decoder::new();
        d.push(&encode_submit(&s));
        assert_eq!(
            d.next_command(),
            Err(Error::TransferLength(MAX_TRANSFER + 1))
        );

        let mut s = get_descriptor(1);
        s.number_of_packets = MAX_ISO_PACKETS + 1;
        let mut d = Decoder::new();
        d.push(&encode_submit(&s));
        assert_eq!(
            d.next_command(),
            Err(Error::IsoPackets(MAX_ISO_PACKETS + 1))
        );

        let mut d = Decoder::new();
        d.push(&[0, 0, 0, 9]);
        d.push(&[0; 44]);
        assert_eq!(d.next_command(), Err(Error::UnknownCommand(9)));

        let mut d = Decoder::new();
        d.push(&[0x01, 0x00, 0x80, 0x05, 0, 0, 0, 0]);
        assert_eq!(d.next_op(), Err(Error::Version(0x0100)));
        let mut d = Decoder::new();
        d.push(&[0x01, 0x11, 0x80, 0x07, 0, 0, 0, 0]);
        assert_eq!(d.next_op(), Err(Error::UnknownOp(0x8007)));
    }

    #[test]
    fn random_bytes_never_panic_the_decoder() {
        // A fixed-seed xorshift: every length, every split.
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for _ in 0..2000 {
            let mut d = Decoder::new();
            let n = (x % 200) as usize;
            let mut bytes = Vec::with_capacity(n);
            for _ in 0..n {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                bytes.push(x as u8);
            }
            // Mostly small commands, so some get past the first check.
            if let Some(b) = bytes.get_mut(3) {
                *b &= 3;
            }
            for chunk in bytes.chunks(7) {
                d.push(chunk);
                while let Ok(Some(_)) = d.next_command() {}
            }
            let mut d = Decoder::new();
            d.push(&bytes);
            let _ = d.next_op();
        }
    }

    #[test]
    fn ops_decode_devlist_and_import_with_the_busid_trimmed() {
        let mut d = Decoder::new();
        let mut b = encode_req_devlist();
        b.extend_from_slice(&encode_req_import("1-1"));
        d.push(&b[..20]);
        assert_eq!(d.next_op(), Ok(Some(Op::Devlist)));
        assert_eq!(d.next_op(), Ok(None), "import split");
        d.push(&b[20..]);
        assert_eq!(
            d.next_op(),
            Ok(Some(Op::Import {
                busid: "1-1".into()
            }))
        );
    }

    #[test]
    fn rep_devlist_and_rep_import_have_the_kernel_s_sizes() {
        let i = info();
        let list = i.encode_devlist();
        assert_eq!(list.len(), 8 + 4 + 312 + 4);
        assert_eq!(&list[0..4], &[0x01, 0x11, 0x00, 0x05]);
        assert_eq!(&list[8..12], &[0, 0, 0, 1], "one device");
        let rec = &list[12..12 + 312];
        assert_eq!(&rec[256..260], b"1-1\0");
        assert_eq!(&rec[288..300], &[0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 2]);
        assert_eq!(&rec[300..306], &[0x1D, 0xC3, 0x06, 0x41, 0x01, 0x00]);
        assert_eq!(&rec[306..312], &[0, 0, 0, 1, 1, 1]);
        assert_eq!(&list[324..328], &[3, 0, 0, 0]);
        assert_eq!(decode_devlist(&list), Some(vec![i.clone()]));
        assert_eq!(decode_devlist(&list[..327]), None);

        let ok = DeviceInfo::encode_import(Some(&i));
        assert_eq!(ok.len(), 8 + 312);
        assert_eq!(&ok[0..8], &[0x01, 0x11, 0x00, 0x03, 0, 0, 0, 0]);
        let back = DeviceInfo::decode_record(&ok[8..]).unwrap();
        assert_eq!(
            back,
            DeviceInfo {
                interfaces: vec![],
                ..i.clone()
            }
        );
        assert_eq!(back.devid(), 0x0001_0002);
        assert_eq!(
            DeviceInfo::encode_import(None),
            [0x01, 0x11, 0x00, 0x03, 0, 0, 0, 1]
        );
    }

    #[test]
    fn ret_submit_and_ret_unlink_encode_status_as_negative_errno() {
        let r = Reply::Submit {
            seqnum: 5,
            status: status::STALL,
            actual_length: 0,
            data: vec![],
        }
        .encode();
        assert_eq!(r.len(), 48);
        assert_eq!(&r[0..8], &[0, 0, 0, 3, 0, 0, 0, 5]);
        assert_eq!(&r[20..24], &[0xFF, 0xFF, 0xFF, 0xE0], "-32");
        let r = Reply::Submit {
            seqnum: 6,
            status: 0,
            actual_length: 2,
            data: vec![0xAB, 0xCD],
        }
        .encode();
        assert_eq!(r.len(), 50);
        assert_eq!(&r[24..28], &[0, 0, 0, 2]);
        assert_eq!(&r[48..], &[0xAB, 0xCD]);
        assert_eq!(
            decode_reply(&r, |_| true),
            Some((
                Reply::Submit {
                    seqnum: 6,
                    status: 0,
                    actual_length: 2,
                    data: vec![0xAB, 0xCD]
                },
                50
            ))
        );
        let u = Reply::Unlink {
            seqnum: 7,
            status: status::UNLINKED,
        }
        .encode();
        assert_eq!(u.len(), 48);
        assert_eq!(&u[0..8], &[0, 0, 0, 4, 0, 0, 0, 7]);
        assert_eq!(&u[20..24], &(-104i32).to_be_bytes());
    }
}
