//! Modbus RTU client over any byte link: a serial port (RS-485 adapter) or
//! a TCP socket carrying raw RTU frames (what `cargo qemu` serves).
//!
//! A reply's length follows from the request (FC 0x03: byte count; 0x06 and
//! 0x10: 8 bytes; an exception: 5), so frames are delimited without relying
//! on silence. Nothing a device sends can panic this code: no reply, a short
//! reply, a bad CRC, another id or another function become [`Error::Comm`]
//! with the port and id named; an exception becomes [`Error::Exception`].

use std::io::{self, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use crc::{Crc, CRC_16_MODBUS};

use crate::bus::{deadline, hex, Bus, RawReply};
use crate::error::{Error, Result};

static CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_MODBUS);

pub const READ_HOLDING: u8 = 0x03;
pub const WRITE_SINGLE: u8 = 0x06;
pub const WRITE_MULTIPLE: u8 = 0x10;

/// A byte link to the bus.
pub trait Link {
    fn send(&mut self, frame: &[u8]) -> io::Result<()>;
    /// Read into `buf` until it is full or `deadline` passes; the count read.
    fn recv(&mut self, buf: &mut [u8], deadline: Instant) -> io::Result<usize>;
    /// Throw away whatever is still arriving (after a bad reply).
    fn drain(&mut self);
    fn name(&self) -> String;
}

/// RTU frames over TCP (no MBAP header).
#[derive(Debug)]
pub struct TcpLink {
    stream: TcpStream,
    addr: String,
}

impl TcpLink {
    pub fn connect(addr: &str, timeout: Duration) -> Result<TcpLink> {
        let fail = |e: &dyn std::fmt::Display| {
            Error::Comm(format!(
                "cannot connect to tcp {addr}: {e} (is `cargo qemu` running? it serves 127.0.0.1:5020)"
            ))
        };
        let sa = addr
            .to_socket_addrs()
            .map_err(|e| fail(&e))?
            .next()
            .ok_or_else(|| fail(&"no address"))?;
        let stream = TcpStream::connect_timeout(&sa, timeout).map_err(|e| fail(&e))?;
        // One request, one reply: never wait for Nagle.
        let _ = stream.set_nodelay(true);
        Ok(TcpLink {
            stream,
            addr: addr.to_string(),
        })
    }
}

impl Link for TcpLink {
    fn send(&mut self, frame: &[u8]) -> io::Result<()> {
        self.stream.write_all(frame)
    }

    fn recv(&mut self, buf: &mut [u8], deadline: Instant) -> io::Result<usize> {
        let mut n = 0;
        while n < buf.len() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            self.stream.set_read_timeout(Some(left))?;
            let Some(rest) = buf.get_mut(n..) else { break };
            match self.stream.read(rest) {
                Ok(0) => {
                    return Err(io::Error::new(
                        io::ErrorKind::UnexpectedEof,
                        "the box closed the connection",
                    ))
                }
                Ok(k) => n = n.saturating_add(k),
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                    ) =>
                {
                    break
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(n)
    }

    fn drain(&mut self) {
        let mut junk = [0u8; 256];
        let until = deadline(Duration::from_millis(20));
        while let Ok(k) = self.recv(&mut junk, until) {
            if k < junk.len() {
                break;
            }
        }
    }

    fn name(&self) -> String {
        format!("tcp {}", self.addr)
    }
}

/// Serial parity of the RS-485 line (the box's stored setting).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum Parity {
    Even,
    Odd,
    /// No parity, two stop bits (11-bit characters, as the box sends them).
    None,
}

/// RTU over a serial port.
pub struct SerialLink {
    port: Box<dyn serialport::SerialPort>,
    path: String,
    /// t3.5 at this baud rate: the silence before a request.
    t35: Duration,
    last: Instant,
}

impl SerialLink {
    pub fn open(path: &str, baud: u32, parity: Parity) -> Result<SerialLink> {
        let (p, stop) = match parity {
            Parity::Even => (serialport::Parity::Even, serialport::StopBits::One),
            Parity::Odd => (serialport::Parity::Odd, serialport::StopBits::One),
            Parity::None => (serialport::Parity::None, serialport::StopBits::Two),
        };
        let port = serialport::new(path, baud)
            .parity(p)
            .stop_bits(stop)
            .data_bits(serialport::DataBits::Eight)
            .timeout(Duration::from_millis(100))
            .open()
            .map_err(|e| {
                let hint = if e.to_string().contains("ermission") {
                    " (add yourself to the `dialout` group: docs/stepctl.md, serial port permissions)"
                } else {
                    ""
                };
                Error::Comm(format!("cannot open serial port {path}: {e}{hint}"))
            })?;
        // 11-bit characters; 3.5 of them (at least 1.75 ms, the spec's floor).
        let per_baud = 38_500_000_u64
            .checked_div(u64::from(baud))
            .unwrap_or(38_500_000);
        let t35 = Duration::from_micros(per_baud.max(1750));
        Ok(SerialLink {
            port,
            path: path.to_string(),
            t35,
            last: Instant::now(),
        })
    }
}

impl std::fmt::Debug for SerialLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SerialLink")
            .field("path", &self.path)
            .field("t35", &self.t35)
            .finish_non_exhaustive()
    }
}

impl Link for SerialLink {
    fn send(&mut self, frame: &[u8]) -> io::Result<()> {
        let quiet = self.last.checked_add(self.t35).map_or(Duration::ZERO, |q| {
            q.saturating_duration_since(Instant::now())
        });
        if !quiet.is_zero() {
            std::thread::sleep(quiet);
        }
        let _ = self.port.clear(serialport::ClearBuffer::Input);
        self.port.write_all(frame)?;
        self.port.flush()?;
        self.last = Instant::now();
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], deadline: Instant) -> io::Result<usize> {
        let mut n = 0;
        while n < buf.len() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            self.port.set_timeout(left)?;
            let Some(rest) = buf.get_mut(n..) else { break };
            match self.port.read(rest) {
                Ok(0) => break,
                Ok(k) => {
                    n = n.saturating_add(k);
                    self.last = Instant::now();
                }
                Err(e) if e.kind() == io::ErrorKind::TimedOut => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(n)
    }

    fn drain(&mut self) {
        std::thread::sleep(self.t35);
        let _ = self.port.clear(serialport::ClearBuffer::Input);
    }

    fn name(&self) -> String {
        format!("serial {}", self.path)
    }
}

/// A Modbus RTU master on a [`Link`].
#[derive(Debug)]
pub struct Rtu<L: Link> {
    pub link: L,
    pub timeout: Duration,
    /// Print every frame on stderr (`-v`).
    pub trace: bool,
}

/// Append the CRC (low byte first).
pub fn with_crc(mut frame: Vec<u8>) -> Vec<u8> {
    let c = CRC16.checksum(&frame);
    frame.extend_from_slice(&c.to_le_bytes());
    frame
}

fn crc_ok(frame: &[u8]) -> bool {
    match frame
        .len()
        .checked_sub(2)
        .and_then(|n| frame.split_at_checked(n))
    {
        Some((body, crc)) if !body.is_empty() => CRC16.checksum(body).to_le_bytes() == crc,
        _ => false,
    }
}

/// What a request expects back after the id and function bytes.
enum Expect {
    /// FC 0x03: a byte count, then that many bytes.
    Registers(u16),
    /// FC 0x06 / 0x10: an echo of these 4 bytes (address, value or quantity).
    Echo([u8; 4]),
}

impl<L: Link> Rtu<L> {
    pub fn new(link: L, timeout: Duration) -> Rtu<L> {
        Rtu {
            link,
            timeout,
            trace: false,
        }
    }

    fn what(&self, id: u8, pdu: &[u8]) -> String {
        let byte = |i: usize| pdu.get(i).copied().unwrap_or(0);
        let address = u16::from_be_bytes([byte(1), byte(2)]);
        let fc = byte(0);
        let verb = match fc {
            READ_HOLDING => "read",
            _ => "write",
        };
        format!("id {id}: {verb} 0x{address:04X} (FC 0x{fc:02X})")
    }

    /// Send `pdu` to `id`; the reply's ADU (CRC checked).
    fn transact(&mut self, id: u8, pdu: &[u8], expect: Expect) -> Result<Vec<u8>> {
        let request = with_crc([&[id], pdu].concat());
        let (_, reply) = self.exchange(id, &request, pdu, expect)?;
        Ok(reply)
    }

    fn exchange(
        &mut self,
        id: u8,
        request: &[u8],
        pdu: &[u8],
        expect: Expect,
    ) -> Result<(Vec<u8>, Vec<u8>)> {
        let name = self.link.name();
        let what = self.what(id, pdu);
        if self.trace {
            eprintln!("stepctl: {name} -> {}", hex(request));
        }
        self.link
            .send(request)
            .map_err(|e| Error::Comm(format!("{what}: cannot send on {name}: {e}")))?;
        let fc = pdu.first().copied().unwrap_or(0);
        let reply = self.receive(id, fc, &expect, &what, &name)?;
        if self.trace {
            eprintln!("stepctl: {name} <- {}", hex(&reply));
        }
        self.check_reply(id, fc, &expect, what, &name, &reply)?;
        Ok((request.to_vec(), reply))
    }

    /// A malformed reply: the rest of it is drained, the error names it.
    fn fail(&mut self, what: &str, id: u8, name: &str, reply: &[u8], why: &str) -> Error {
        self.link.drain();
        Error::Comm(format!(
            "{what}: {why} from id {id} on {name}: {} (line noise or a second master?)",
            hex(reply)
        ))
    }

    /// Receive one reply ADU to function `fc`: id and function, then what
    /// follows them (an exception's code, a byte count and that many bytes,
    /// or an echo) and the CRC, as far as it comes before the timeout.
    fn receive(
        &mut self,
        id: u8,
        fc: u8,
        expect: &Expect,
        what: &str,
        name: &str,
    ) -> Result<Vec<u8>> {
        let deadline = deadline(self.timeout);
        let comm = |e: io::Error| Error::Comm(format!("{what}: {name}: {e}"));
        let mut reply = vec![0u8; 2];
        let n = self.link.recv(&mut reply, deadline).map_err(comm)?;
        let ms = self.timeout.as_millis();
        if n == 0 {
            return Err(Error::Comm(format!(
                "{what}: no reply from id {id} on {name} within {ms} ms (wrong id, port or serial settings? try `stepctl scan`)"
            )));
        }
        if n < 2 {
            let got = reply.get(..n).unwrap_or_default().to_vec();
            return Err(self.fail(what, id, name, &got, "short reply"));
        }
        let function = reply.get(1).copied().unwrap_or(0);
        let rest = if function == fc | 0x80 {
            3
        } else if function != fc {
            return Err(self.fail(what, id, name, &reply, "reply with another function"));
        } else {
            match expect {
                Expect::Registers(_) => {
                    let mut count = [0u8; 1];
                    let k = self.link.recv(&mut count, deadline).map_err(comm)?;
                    if k == 0 {
                        return Err(self.fail(what, id, name, &reply, "short reply"));
                    }
                    let [count] = count;
                    reply.push(count);
                    usize::from(count).saturating_add(2)
                }
                Expect::Echo(_) => 6,
            }
        };
        let at = reply.len();
        reply.resize(at.saturating_add(rest), 0);
        let k = match reply.get_mut(at..) {
            Some(tail) => self.link.recv(tail, deadline).map_err(comm)?,
            None => 0,
        };
        reply.truncate(at.saturating_add(k));
        if k < rest {
            if self.trace {
                eprintln!("stepctl: {name} <- {}", hex(&reply));
            }
            return Err(self.fail(what, id, name, &reply, "short reply"));
        }
        Ok(reply)
    }

    /// A whole reply against the request: CRC, id, exception, and the byte
    /// count or echo `expect` says.
    fn check_reply(
        &mut self,
        id: u8,
        fc: u8,
        expect: &Expect,
        what: String,
        name: &str,
        reply: &[u8],
    ) -> Result<()> {
        if !crc_ok(reply) {
            return Err(self.fail(&what, id, name, reply, "bad CRC in the reply"));
        }
        if reply.first() != Some(&id) {
            return Err(self.fail(&what, id, name, reply, "a reply for another id"));
        }
        let byte = |i: usize| reply.get(i).copied().unwrap_or(0);
        if byte(1) == fc | 0x80 {
            return Err(Error::Exception {
                code: byte(2),
                what,
                reason: None,
            });
        }
        match expect {
            Expect::Registers(count)
                if usize::from(byte(2)) != usize::from(*count).saturating_mul(2) =>
            {
                Err(self.fail(&what, id, name, reply, "a wrong register count"))
            }
            Expect::Echo(echo) if reply.get(2..6) != Some(&echo[..]) => {
                Err(self.fail(&what, id, name, reply, "a wrong echo"))
            }
            _ => Ok(()),
        }
    }

    pub fn read_registers(&mut self, id: u8, address: u16, count: u16) -> Result<Vec<u16>> {
        let [a, b] = address.to_be_bytes();
        let [c, d] = count.to_be_bytes();
        let reply = self.transact(id, &[READ_HOLDING, a, b, c, d], Expect::Registers(count))?;
        Ok(registers_of(&reply))
    }

    pub fn write_registers(&mut self, id: u8, address: u16, values: &[u16]) -> Result<()> {
        let pdu = write_pdu(address, values);
        let echo = echo_of(&pdu);
        self.transact(id, &pdu, Expect::Echo(echo)).map(|_| ())
    }
}

/// The registers of a FC 0x03 reply ADU.
fn registers_of(reply: &[u8]) -> Vec<u16> {
    let n = usize::from(reply.get(2).copied().unwrap_or(0));
    reply
        .get(3..n.saturating_add(3))
        .unwrap_or(&[])
        .chunks_exact(2)
        .filter_map(|w| <[u8; 2]>::try_from(w).ok().map(u16::from_be_bytes))
        .collect()
}

/// The 4 bytes a write's reply echoes (address, value or quantity) of a
/// write PDU.
fn echo_of(pdu: &[u8]) -> [u8; 4] {
    pdu.get(1..5)
        .and_then(|e| <[u8; 4]>::try_from(e).ok())
        .unwrap_or_default()
}

/// FC 0x06 for one register, FC 0x10 for more.
fn write_pdu(address: u16, values: &[u16]) -> Vec<u8> {
    let [a, b] = address.to_be_bytes();
    match values {
        [v] => {
            let [c, d] = v.to_be_bytes();
            vec![WRITE_SINGLE, a, b, c, d]
        }
        _ => {
            let [c, d] = (values.len() as u16).to_be_bytes();
            let bytes = values.len().saturating_mul(2) as u8;
            let mut pdu = vec![WRITE_MULTIPLE, a, b, c, d, bytes];
            for v in values {
                pdu.extend_from_slice(&v.to_be_bytes());
            }
            pdu
        }
    }
}

impl<L: Link> Bus for Rtu<L> {
    fn read(&mut self, unit: u8, address: u16, count: u16) -> Result<Vec<u16>> {
        self.read_registers(unit, address, count)
    }

    fn write(&mut self, unit: u8, address: u16, values: &[u16]) -> Result<()> {
        // Commands of more than one register (0x06 PWM, 0x50) need FC 0x10.
        self.write_registers(unit, address, values)
    }

    fn name(&self) -> String {
        self.link.name()
    }

    fn is_modbus(&self) -> bool {
        true
    }

    fn set_timeout_ms(&mut self, ms: u64) {
        self.timeout = Duration::from_millis(ms);
    }

    fn raw(
        &mut self,
        unit: u8,
        command: u16,
        data: &[u16],
        count: Option<u16>,
    ) -> Result<RawReply> {
        let [a, b] = command.to_be_bytes();
        if data.is_empty() {
            let count = count.unwrap_or(1);
            let [c, d] = count.to_be_bytes();
            let pdu = [READ_HOLDING, a, b, c, d];
            let request = with_crc([&[unit][..], &pdu].concat());
            let (request, reply) = self.exchange(unit, &request, &pdu, Expect::Registers(count))?;
            let registers = registers_of(&reply);
            Ok(RawReply {
                request,
                reply,
                registers,
            })
        } else {
            let pdu = write_pdu(command, data);
            let echo = echo_of(&pdu);
            let request = with_crc([&[unit][..], &pdu].concat());
            let (request, reply) = self.exchange(unit, &request, &pdu, Expect::Echo(echo))?;
            Ok(RawReply {
                request,
                reply,
                registers: Vec::new(),
            })
        }
    }
}

#[cfg(test)]
pub mod fake {
    //! A scripted link: each request must be the expected bytes, and gets
    //! the given reply (whole, cut short, or nothing).
    use super::*;
    use std::collections::VecDeque;

    #[derive(Debug, Default)]
    pub struct FakeLink {
        pub script: VecDeque<(Vec<u8>, Vec<u8>)>,
        pending: Vec<u8>,
        pub sent: Vec<Vec<u8>>,
    }

    /// Bytes from "01 03 00 0A ..." (spaces ignored).
    pub fn bytes(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).expect("test vector"))
            .collect()
    }

    impl FakeLink {
        pub fn new(script: &[(&str, &str)]) -> FakeLink {
            FakeLink {
                script: script.iter().map(|(q, r)| (bytes(q), bytes(r))).collect(),
                ..FakeLink::default()
            }
        }
        pub fn done(&self) -> bool {
            self.script.is_empty()
        }
    }

    impl Link for FakeLink {
        fn send(&mut self, frame: &[u8]) -> io::Result<()> {
            self.sent.push(frame.to_vec());
            let (want, reply) = self
                .script
                .pop_front()
                .unwrap_or_else(|| panic!("unexpected request {}", hex(frame)));
            assert_eq!(hex(frame), hex(&want), "request bytes");
            self.pending = reply;
            Ok(())
        }
        fn recv(&mut self, buf: &mut [u8], _deadline: Instant) -> io::Result<usize> {
            let n = buf.len().min(self.pending.len());
            buf[..n].copy_from_slice(&self.pending[..n]);
            self.pending.drain(..n);
            Ok(n)
        }
        fn drain(&mut self) {
            self.pending.clear();
        }
        fn name(&self) -> String {
            "tcp fake:5020".into()
        }
    }

    /// `bytes` as a frame with its CRC: the Modbus spec's bitwise CRC-16
    /// (poly 0xA001, init 0xFFFF, low byte first), written out here as a
    /// test oracle independent of the `crc` crate stepctl sends with.
    pub fn framed(bytes: &[u8]) -> String {
        let mut c = 0xFFFFu16;
        for x in bytes {
            c ^= u16::from(*x);
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    (c >> 1) ^ 0xA001
                } else {
                    c >> 1
                };
            }
        }
        format!("{} {:02X} {:02X}", hex(bytes), c & 0xFF, c >> 8)
    }

    /// Generated script lines ending in a "CC CC" placeholder get their CRC.
    pub fn fixed(script: &[(String, String)]) -> Vec<(String, String)> {
        let fix = |s: &String| match s.strip_suffix(" CC CC") {
            Some(b) => framed(&bytes(b)),
            None => s.clone(),
        };
        script.iter().map(|(a, b)| (fix(a), fix(b))).collect()
    }

    pub fn rtu(script: &[(&str, &str)]) -> Rtu<FakeLink> {
        Rtu::new(FakeLink::new(script), Duration::from_millis(10))
    }
}

#[cfg(test)]
mod tests {
    use super::fake::*;
    use super::*;

    // Frames: docs/modbus.md "Modbus register map"; CRCs from the Modbus spec's
    // CRC-16 (poly 0xA001, init 0xFFFF, low byte first) computed outside
    // stepctl.

    #[test]
    fn a_read_of_hw_fw_info_returns_its_three_registers() {
        let mut m = rtu(&[(
            "01 03 00 0A 00 03 25 C9",
            "01 03 06 00 41 01 00 00 01 DD 46",
        )]);
        assert_eq!(m.read(1, 0x0A, 3), Ok(vec![0x0041, 0x0100, 0x0001]));
    }

    #[test]
    fn a_single_register_write_uses_fc_06_and_checks_the_echo() {
        let mut m = rtu(&[("01 06 00 51 07 D0 DB B7", "01 06 00 51 07 D0 DB B7")]);
        assert_eq!(m.write(1, 0x51, &[2000]), Ok(()));
    }

    #[test]
    fn a_two_register_write_uses_fc_10() {
        // Set position -1000 (docs/modbus.md: R1 high word, R2 low word).
        let mut m = rtu(&[(
            "01 10 00 50 00 02 04 FF FF FC 18 B7 BD",
            "01 10 00 50 00 02 41 D9",
        )]);
        assert_eq!(m.write(1, 0x50, &[0xFFFF, 0xFC18]), Ok(()));
    }

    #[test]
    fn an_exception_reply_becomes_an_exception_error_with_its_code() {
        let mut m = rtu(&[("01 03 00 99 00 01 54 25", "01 83 02 C0 F1")]);
        let e = m.read(1, 0x99, 1).unwrap_err();
        assert_eq!(e.exception_code(), Some(2));
        assert!(e.to_string().contains("id 1: read 0x0099"));
    }

    #[test]
    fn no_reply_is_a_communication_error_naming_port_and_id() {
        let mut m = rtu(&[("07 03 00 0A 00 03 25 AF", "")]);
        let e = m.read(7, 0x0A, 3).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        let s = e.to_string();
        assert!(s.contains("no reply from id 7 on tcp fake:5020"), "{s}");
    }

    #[test]
    fn a_short_reply_is_a_communication_error() {
        let mut m = rtu(&[("01 03 00 0A 00 03 25 C9", "01 03 06 00 41 01")]);
        let e = m.read(1, 0x0A, 3).unwrap_err();
        assert!(e.to_string().contains("short reply"), "{e}");
    }

    #[test]
    fn a_bad_crc_is_a_communication_error() {
        let mut m = rtu(&[(
            "01 03 00 0A 00 03 25 C9",
            "01 03 06 00 41 01 00 00 01 DD 47",
        )]);
        let e = m.read(1, 0x0A, 3).unwrap_err();
        assert!(e.to_string().contains("bad CRC"), "{e}");
    }

    #[test]
    fn a_reply_from_another_id_is_refused() {
        let mut m = rtu(&[("01 03 00 13 00 01 75 CF", "02 03 02 00 02 7D 85")]);
        let e = m.read(1, 0x13, 1).unwrap_err();
        assert!(e.to_string().contains("another id"), "{e}");
    }

    #[test]
    fn a_reply_with_the_wrong_count_is_refused() {
        let mut m = rtu(&[("01 03 00 13 00 01 75 CF", "01 03 04 00 02 00 00 5B F3")]);
        assert_eq!(m.read(1, 0x13, 1).unwrap_err().exit_code(), 2);
    }

    #[test]
    fn garbage_replies_never_panic() {
        for reply in [
            "01",
            "01 03",
            "01 03 FF",
            "01 90",
            "01 83",
            "FF FF FF FF FF",
        ] {
            let mut m = rtu(&[("01 03 00 0A 00 03 25 C9", reply)]);
            assert!(m.read(1, 0x0A, 3).is_err(), "{reply}");
        }
    }
}
