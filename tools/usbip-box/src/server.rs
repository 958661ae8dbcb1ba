//! The USB/IP device server: a TCP listener (127.0.0.1:3240 by default, the
//! port `usbip` uses) that exports one device.
//!
//! # What it guarantees
//!
//! * **Operations**: a connection's first message is OP_REQ_DEVLIST
//!   (answered with the one device, then closed) or OP_REQ_IMPORT of the
//!   device's bus id (answered with status 0 and the device record; the
//!   connection then carries URBs and the [`Port`] is attached). An import
//!   of another bus id, or while the device is imported, gets status 1 and
//!   is closed.
//! * **URBs**: commands are read as TCP delivers them (any split) and
//!   handed to the port in order; replies go out in completion order. A
//!   byte stream that is not USB/IP (see `protocol::Error`) or an end of
//!   stream closes the connection and detaches the port: the device is
//!   unplugged, as the kernel sees it when the socket closes.
//! * **Never blocks**: every socket is non-blocking; [`Server::poll`] does
//!   what can be done now and returns, so one thread can also run the
//!   device and its control loop.

use std::io::{self, ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};

use crate::bus::Port;
use crate::protocol::{Command, Decoder, DeviceInfo, Op};

/// What a poll changed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Event {
    /// A client listed the devices.
    Listed,
    /// A client imported the device.
    Imported(SocketAddr),
    /// An import was refused (wrong bus id, or already imported).
    Refused(String),
    /// The imported connection ended (why).
    Detached(String),
}

#[derive(Debug)]
struct Conn {
    stream: TcpStream,
    peer: SocketAddr,
    decoder: Decoder,
    out: Vec<u8>,
}

impl Conn {
    fn new(stream: TcpStream, peer: SocketAddr) -> io::Result<Conn> {
        stream.set_nonblocking(true)?;
        stream.set_nodelay(true)?;
        Ok(Conn {
            stream,
            peer,
            decoder: Decoder::new(),
            out: Vec::new(),
        })
    }

    /// Read what is there; false at end of stream.
    fn fill(&mut self) -> io::Result<bool> {
        let mut buf = [0u8; 4096];
        loop {
            match self.stream.read(&mut buf) {
                Ok(0) => return Ok(false),
                Ok(n) => self.decoder.push(buf.get(..n).unwrap_or(&[])),
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(true),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
    }

    /// Write what is queued, as far as the socket takes it.
    fn flush(&mut self) -> io::Result<()> {
        while !self.out.is_empty() {
            match self.stream.write(&self.out) {
                Ok(0) => return Err(ErrorKind::WriteZero.into()),
                Ok(n) => {
                    self.out.drain(..n);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(()),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// Queue `bytes` and write them out before the connection is closed
    /// (a short blocking write: the reply to an operation is small).
    fn send_and_close(mut self, bytes: &[u8]) {
        self.out.extend_from_slice(bytes);
        let _ = self.stream.set_nonblocking(false);
        let _ = self.flush();
        let _ = self.stream.shutdown(std::net::Shutdown::Both);
    }
}

/// The server.
#[derive(Debug)]
pub struct Server {
    listener: TcpListener,
    info: DeviceInfo,
    /// Connections that have not sent their operation yet.
    fresh: Vec<Conn>,
    /// The connection the device is imported on.
    link: Option<Conn>,
}

impl Server {
    /// Listen on `addr` for clients of the device `info`.
    pub fn bind(addr: &str, info: DeviceInfo) -> io::Result<Server> {
        let listener = TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        Ok(Server {
            listener,
            info,
            fresh: Vec::new(),
            link: None,
        })
    }

    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    /// The device record (bConfigurationValue changes once configured).
    pub fn info_mut(&mut self) -> &mut DeviceInfo {
        &mut self.info
    }

    pub fn is_imported(&self) -> bool {
        self.link.is_some()
    }

    /// Accept, answer operations, and hand the imported connection's
    /// commands to `port`.
    pub fn poll(&mut self, port: &Port) -> Vec<Event> {
        let mut events = Vec::new();
        loop {
            match self.listener.accept() {
                Ok((stream, peer)) => {
                    if let Ok(c) = Conn::new(stream, peer) {
                        self.fresh.push(c);
                    }
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => break,
            }
        }
        for mut c in std::mem::take(&mut self.fresh) {
            let open = matches!(c.fill(), Ok(true));
            match c.decoder.next_op() {
                Ok(Some(Op::Devlist)) => {
                    c.send_and_close(&self.info.encode_devlist());
                    events.push(Event::Listed);
                }
                Ok(Some(Op::Import { busid })) => {
                    if busid == self.info.busid && self.link.is_none() {
                        c.out
                            .extend_from_slice(&DeviceInfo::encode_import(Some(&self.info)));
                        events.push(Event::Imported(c.peer));
                        port.attach();
                        // Commands may have come in the same segment.
                        self.link = Some(c);
                    } else {
                        c.send_and_close(&DeviceInfo::encode_import(None));
                        events.push(Event::Refused(busid));
                    }
                }
                Ok(None) if open => self.fresh.push(c),
                Ok(None) | Err(_) => {}
            }
        }
        if let Some(why) = self.serve_link(port) {
            self.drop_link(port);
            events.push(Event::Detached(why));
        }
        events
    }

    /// The imported connection's commands into the port; why it ended, if
    /// it did.
    fn serve_link(&mut self, port: &Port) -> Option<String> {
        let link = self.link.as_mut()?;
        let open = match link.fill() {
            Ok(open) => open,
            Err(e) => return Some(format!("read: {e}")),
        };
        loop {
            match link.decoder.next_command() {
                Ok(Some(Command::Submit(s))) => port.submit(s),
                Ok(Some(Command::Unlink(u))) => port.unlink(u),
                Ok(None) => break,
                Err(e) => return Some(format!("not USB/IP: {e}")),
            }
        }
        if open {
            None
        } else {
            Some("end of stream".into())
        }
    }

    /// The port's replies onto the imported connection.
    pub fn flush(&mut self, port: &Port) -> Option<Event> {
        let link = self.link.as_mut()?;
        for r in port.take_replies() {
            link.out.extend_from_slice(&r.encode());
        }
        match link.flush() {
            Ok(()) => None,
            Err(e) => {
                self.drop_link(port);
                Some(Event::Detached(format!("write: {e}")))
            }
        }
    }

    /// Unplug: close the imported connection (a device restart).
    pub fn unplug(&mut self, port: &Port) {
        if let Some(mut link) = self.link.take() {
            for r in port.take_replies() {
                link.out.extend_from_slice(&r.encode());
            }
            link.send_and_close(&[]);
        }
        port.detach();
    }

    fn drop_link(&mut self, port: &Port) {
        if let Some(link) = self.link.take() {
            let _ = link.stream.shutdown(std::net::Shutdown::Both);
        }
        port.detach();
    }
}
