//! A `usb_device` bus whose host is a USB/IP client: URBs in, packets to
//! and from the device's endpoints, completions out.
//!
//! [`UsbIpBus`] implements `usb_device::bus::UsbBus` (what a device's
//! hardware driver implements, e.g. synopsys-usb-otg on the STM32F405), so
//! `UsbDevice` and its classes run on it unchanged. [`Port`] is the network
//! side's handle on the same state: it hands URBs in
//! ([`Port::submit`], [`Port::unlink`]) and takes the replies out
//! ([`Port::take_replies`]). Both share one [`Core`] behind a mutex; the
//! server and the device are polled by one thread.
//!
//! # What it guarantees
//!
//! * **Control transfers run in their three stages, in order.** A control
//!   URB is one transfer: its SETUP packet goes to EP0 OUT (`ep_setup`), an
//!   OUT data stage in packets of the endpoint's size, then the URB waits
//!   for the device's zero-length status IN and completes only when the
//!   device has written it; an IN transfer collects the device's packets
//!   until a short one or the URB's length, then the host's zero-length
//!   status OUT is handed to the device and the URB completes once the
//!   device has read it. A packet the device writes to EP0 outside a data or
//!   status stage is dropped (counted in [`Core::stray_ep0_writes`]): it can
//!   never become the answer to the next request. One control transfer at a
//!   time; the next starts at the next poll.
//! * **A STALL answers at once**: the device stalling EP0 during a
//!   transfer completes its URB with `-EPIPE` (−32); a SETUP clears EP0's
//!   stall, as on the wire. A stalled interrupt endpoint fails its pending
//!   and new URBs with `-EPIPE` until the host clears the halt.
//! * **Unlink**: CMD_UNLINK of a URB that has not completed removes it (no
//!   RET_SUBMIT is ever sent for it) and answers `-ECONNRESET` (−104); of
//!   one that already completed, status 0. An IN packet the device had
//!   written stays in its endpoint for the next URB, as in a FIFO.
//! * **Interrupt endpoints**: an OUT URB is delivered in packets of the
//!   endpoint's size and completes when the device has read the last; an
//!   IN URB takes the device's packets until a short one or its length. A
//!   written IN packet with no URB waiting stays in the endpoint (the next
//!   write is `WouldBlock`), as a real endpoint NAKs until the host polls.
//! * **Speed**: full speed, EP0 64 bytes; the device's address is kept but
//!   has no effect (the USB/IP client, vhci-hcd, handles SET_ADDRESS
//!   itself and never sends it).
//! * **Link**: [`Port::attach`] makes the next poll a bus reset;
//!   [`Port::detach`] (the client went away) drops every URB and makes the
//!   next poll a suspend (a self-powered device's "disconnected").
//!
//! Isochronous URBs are refused (`-EINVAL`): no class here has such an
//! endpoint.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

use usb_device::bus::PollResult;
use usb_device::endpoint::{EndpointAddress, EndpointType};
use usb_device::{UsbDirection, UsbError};

use crate::protocol::{status, Reply, Submit, Unlink};

/// Endpoint numbers 0..=15.
pub const ENDPOINTS: usize = 16;
// `submit` takes an URB's endpoint number as `ep & 0x0F`: one slot each.
const _: () = assert!(ENDPOINTS == 16);

/// A hub-class request to a port: SET_FEATURE(PORT_RESET). The kernel's
/// USB/IP server takes this as "reset the device"; so does this bus.
const PORT_RESET_SETUP: (u8, u8, u16) = (0x23, 0x03, 4);

#[derive(Clone, Copy, Debug)]
struct EpConfig {
    ep_type: EndpointType,
    max_packet: usize,
}

/// A control transfer's stage.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    /// The SETUP packet waits in EP0 OUT.
    Setup,
    /// OUT data waits in EP0 OUT from `pos`.
    DataOut,
    /// The device writes IN data.
    DataIn,
    /// The host's zero-length status OUT waits in EP0 OUT.
    StatusOut,
    /// The host waits for the device's zero-length status IN.
    StatusIn,
}

#[derive(Debug)]
struct Control {
    urb: Submit,
    stage: Stage,
    pos: usize,
    data_in: Vec<u8>,
}

impl Control {
    fn length(&self) -> usize {
        usize::from(u16::from_le_bytes([self.urb.setup[6], self.urb.setup[7]]))
    }
    fn setup_is_in(&self) -> bool {
        self.urb.setup[0] & 0x80 != 0
    }
}

/// A non-control URB in progress.
#[derive(Debug)]
struct Transfer {
    urb: Submit,
    /// OUT: bytes delivered so far; IN: bytes received (in `data_in`).
    pos: usize,
    data_in: Vec<u8>,
}

/// What [`Port::take_trace`] reports when tracing is on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trace {
    /// A control transfer ended: its SETUP, status, and the bytes moved.
    Control {
        setup: [u8; 8],
        status: i32,
        length: usize,
    },
    /// CMD_UNLINK of `seqnum`: whether the URB was still pending.
    Unlink { seqnum: u32, pending: bool },
}

impl core::fmt::Display for Trace {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Trace::Control {
                setup,
                status,
                length,
            } => {
                write!(f, "control")?;
                for b in setup {
                    write!(f, " {b:02x}")?;
                }
                write!(f, ": status {status}, {length} bytes")
            }
            Trace::Unlink { seqnum, pending } => write!(
                f,
                "unlink of URB {seqnum}: {}",
                if *pending {
                    "cancelled"
                } else {
                    "already done"
                }
            ),
        }
    }
}

/// The state both sides share.
#[derive(Debug, Default)]
pub struct Core {
    ep_in: [Option<EpConfig>; ENDPOINTS],
    ep_out: [Option<EpConfig>; ENDPOINTS],
    stalled_in: u16,
    stalled_out: u16,
    /// Packets the device wrote that no URB has taken yet.
    in_packet: [Option<Vec<u8>>; ENDPOINTS],
    /// IN endpoints whose packet a URB took since the last poll.
    in_complete: u16,
    control: Option<Control>,
    control_queue: VecDeque<Submit>,
    out_queue: [VecDeque<Transfer>; ENDPOINTS],
    in_queue: [VecDeque<Transfer>; ENDPOINTS],
    replies: VecDeque<Reply>,
    reset_pending: bool,
    suspend_pending: bool,
    attached: bool,
    address: u8,
    /// EP0 writes outside a data or status stage (dropped).
    pub stray_ep0_writes: u32,
    /// Bus resets the device has been given.
    pub resets: u32,
    tracing: bool,
    trace: Vec<Trace>,
}

impl Core {
    fn complete(&mut self, seqnum: u32, status: i32, actual_length: usize, data: Vec<u8>) {
        self.replies.push_back(Reply::Submit {
            seqnum,
            status,
            actual_length: u32::try_from(actual_length).unwrap_or(u32::MAX),
            data,
        });
    }

    fn fail(&mut self, urb: &Submit, status: i32) {
        self.complete(urb.seqnum, status, 0, Vec::new());
    }

    fn finish_control(&mut self, status: i32) {
        if let Some(c) = self.control.take() {
            if self.tracing {
                let length = if c.urb.is_in() {
                    c.data_in.len().min(c.urb.transfer_buffer_length as usize)
                } else {
                    c.urb.data.len()
                };
                self.trace.push(Trace::Control {
                    setup: c.urb.setup,
                    status,
                    length: if status == status::OK { length } else { 0 },
                });
            }
            if status != status::OK {
                self.fail(&c.urb, status);
            } else if c.urb.is_in() {
                let mut data = c.data_in;
                data.truncate(c.urb.transfer_buffer_length as usize);
                let n = data.len();
                self.complete(c.urb.seqnum, status::OK, n, data);
            } else {
                let n = c.urb.data.len();
                self.complete(c.urb.seqnum, status::OK, n, Vec::new());
            }
        }
    }

    fn ep0_max(&self) -> usize {
        self.ep_in[0].map_or(64, |c| c.max_packet)
    }

    /// Start the next control transfer if none runs: its SETUP into EP0.
    fn start_control(&mut self) {
        if self.control.is_some() {
            return;
        }
        let Some(urb) = self.control_queue.pop_front() else {
            return;
        };
        // A SETUP clears a stall of EP0 and flushes what EP0 IN held.
        self.stalled_in &= !1;
        self.stalled_out &= !1;
        self.in_packet[0] = None;
        self.control = Some(Control {
            urb,
            stage: Stage::Setup,
            pos: 0,
            data_in: Vec::new(),
        });
    }

    /// An IN endpoint's waiting packet into its first URB.
    #[allow(clippy::indexing_slicing)] // k < ENDPOINTS: every caller masks or checks it
    fn match_in(&mut self, k: usize) {
        let Some(packet) = self.in_packet[k].take() else {
            return;
        };
        let max = self.ep_in[k].map_or(64, |c| c.max_packet);
        let Some(t) = self.in_queue[k].front_mut() else {
            self.in_packet[k] = Some(packet);
            return;
        };
        let room = (t.urb.transfer_buffer_length as usize).saturating_sub(t.data_in.len());
        if packet.len() > room {
            // Babble: more than the host asked for.
            if let Some(t) = self.in_queue[k].pop_front() {
                self.fail(&t.urb, status::PROTOCOL);
            }
            self.in_complete |= 1 << k;
            return;
        }
        t.data_in.extend_from_slice(&packet);
        t.pos = t.data_in.len();
        let done = packet.len() < max || t.pos >= t.urb.transfer_buffer_length as usize;
        self.in_complete |= 1 << k;
        if done {
            if let Some(t) = self.in_queue[k].pop_front() {
                let n = t.data_in.len();
                self.complete(t.urb.seqnum, status::OK, n, t.data_in);
            }
        }
    }

    #[allow(clippy::indexing_slicing)] // k = ep & 0x0F < 16 = ENDPOINTS (asserted below)
    fn submit(&mut self, urb: Submit) {
        if !self.attached {
            return;
        }
        let k = (urb.ep & 0x0F) as usize;
        if urb.is_iso() {
            self.fail(&urb, status::INVALID);
            return;
        }
        if k == 0 {
            let s = urb.setup;
            let request = (s[0], s[1], u16::from_le_bytes([s[2], s[3]]));
            if request == PORT_RESET_SETUP {
                self.reset_pending = true;
                self.complete(urb.seqnum, status::OK, 0, Vec::new());
                return;
            }
            self.control_queue.push_back(urb);
            return;
        }
        let t = Transfer {
            urb,
            pos: 0,
            data_in: Vec::new(),
        };
        if t.urb.is_in() {
            if self.ep_in[k].is_none() || self.stalled_in & (1 << k) != 0 {
                self.fail(&t.urb, status::STALL);
                return;
            }
            self.in_queue[k].push_back(t);
            self.match_in(k);
        } else {
            if self.ep_out[k].is_none() || self.stalled_out & (1 << k) != 0 {
                self.fail(&t.urb, status::STALL);
                return;
            }
            self.out_queue[k].push_back(t);
        }
    }

    fn unlink(&mut self, u: Unlink) {
        let target = u.unlink_seqnum;
        let mut found = false;
        if self
            .control
            .as_ref()
            .is_some_and(|c| c.urb.seqnum == target)
        {
            self.control = None;
            self.in_packet[0] = None;
            found = true;
        }
        let before = self.control_queue.len();
        self.control_queue.retain(|s| s.seqnum != target);
        found |= self.control_queue.len() != before;
        for q in self.out_queue.iter_mut().chain(self.in_queue.iter_mut()) {
            let before = q.len();
            q.retain(|t| t.urb.seqnum != target);
            found |= q.len() != before;
        }
        if self.tracing {
            self.trace.push(Trace::Unlink {
                seqnum: target,
                pending: found,
            });
        }
        self.replies.push_back(Reply::Unlink {
            seqnum: u.seqnum,
            status: if found { status::UNLINKED } else { status::OK },
        });
    }

    fn drop_urbs(&mut self) {
        self.control = None;
        self.control_queue.clear();
        for q in self.out_queue.iter_mut().chain(self.in_queue.iter_mut()) {
            q.clear();
        }
        self.replies.clear();
    }

    #[allow(clippy::indexing_slicing)] // k < ENDPOINTS: checked first
    fn write(&mut self, ep: EndpointAddress, buf: &[u8]) -> usb_device::Result<usize> {
        let k = ep.index();
        if ep.direction() != UsbDirection::In || k >= ENDPOINTS {
            return Err(UsbError::InvalidEndpoint);
        }
        let Some(cfg) = self.ep_in[k] else {
            return Err(UsbError::InvalidEndpoint);
        };
        if buf.len() > cfg.max_packet {
            return Err(UsbError::BufferOverflow);
        }
        if k == 0 {
            return Ok(self.write_ep0(buf));
        }
        if self.in_packet[k].is_some() {
            return Err(UsbError::WouldBlock);
        }
        self.in_packet[k] = Some(buf.to_vec());
        self.match_in(k);
        Ok(buf.len())
    }

    fn write_ep0(&mut self, buf: &[u8]) -> usize {
        let max = self.ep0_max();
        let Some(c) = self.control.as_mut() else {
            self.stray_ep0_writes = self.stray_ep0_writes.saturating_add(1);
            return buf.len();
        };
        match c.stage {
            Stage::DataIn => {
                c.data_in.extend_from_slice(buf);
                if buf.len() < max || c.data_in.len() >= c.length() {
                    c.stage = Stage::StatusOut;
                }
                self.in_complete |= 1;
            }
            Stage::StatusIn if buf.is_empty() => {
                self.in_complete |= 1;
                self.finish_control(status::OK);
            }
            Stage::StatusIn => {
                // Data where the status belongs.
                self.in_complete |= 1;
                self.finish_control(status::PROTOCOL);
            }
            Stage::Setup | Stage::DataOut | Stage::StatusOut => {
                self.stray_ep0_writes = self.stray_ep0_writes.saturating_add(1);
            }
        }
        buf.len()
    }

    #[allow(clippy::indexing_slicing)] // k < ENDPOINTS: checked first
    fn read(&mut self, ep: EndpointAddress, buf: &mut [u8]) -> usb_device::Result<usize> {
        let k = ep.index();
        if ep.direction() != UsbDirection::Out || k >= ENDPOINTS || self.ep_out[k].is_none() {
            return Err(UsbError::InvalidEndpoint);
        }
        if k == 0 {
            return self.read_ep0(buf);
        }
        let max = self.ep_out[k].map_or(64, |c| c.max_packet);
        let Some(t) = self.out_queue[k].front_mut() else {
            return Err(UsbError::WouldBlock);
        };
        let left = t.urb.data.get(t.pos..).unwrap_or_default();
        let n = left.len().min(max);
        let dst = buf.get_mut(..n).ok_or(UsbError::BufferOverflow)?;
        dst.copy_from_slice(left.get(..n).unwrap_or_default());
        t.pos = t.pos.saturating_add(n);
        if t.pos >= t.urb.data.len() {
            if let Some(t) = self.out_queue[k].pop_front() {
                let len = t.urb.data.len();
                self.complete(t.urb.seqnum, status::OK, len, Vec::new());
            }
        }
        Ok(n)
    }

    fn read_ep0(&mut self, buf: &mut [u8]) -> usb_device::Result<usize> {
        let max = self.ep0_max();
        let Some(c) = self.control.as_mut() else {
            return Err(UsbError::WouldBlock);
        };
        match c.stage {
            Stage::Setup => {
                let dst = buf.get_mut(..8).ok_or(UsbError::BufferOverflow)?;
                dst.copy_from_slice(&c.urb.setup);
                c.stage = if c.setup_is_in() {
                    Stage::DataIn
                } else if c.length() > 0 && !c.urb.data.is_empty() {
                    Stage::DataOut
                } else {
                    Stage::StatusIn
                };
                Ok(8)
            }
            Stage::DataOut => {
                let left = c.urb.data.get(c.pos..).unwrap_or_default();
                let n = left.len().min(max);
                let dst = buf.get_mut(..n).ok_or(UsbError::BufferOverflow)?;
                dst.copy_from_slice(left.get(..n).unwrap_or_default());
                c.pos = c.pos.saturating_add(n);
                if c.pos >= c.urb.data.len() {
                    c.stage = Stage::StatusIn;
                }
                Ok(n)
            }
            Stage::StatusOut => {
                self.finish_control(status::OK);
                Ok(0)
            }
            Stage::DataIn | Stage::StatusIn => Err(UsbError::WouldBlock),
        }
    }

    #[allow(clippy::indexing_slicing)] // k < ENDPOINTS: checked first
    fn set_stalled(&mut self, ep: EndpointAddress, stalled: bool) {
        let k = ep.index();
        if k >= ENDPOINTS {
            return;
        }
        let bit = 1u16 << k;
        let in_dir = ep.direction() == UsbDirection::In;
        let flags = if in_dir {
            &mut self.stalled_in
        } else {
            &mut self.stalled_out
        };
        if !stalled {
            *flags &= !bit;
            return;
        }
        *flags |= bit;
        if k == 0 {
            if self.control.is_some() {
                self.finish_control(status::STALL);
            }
            return;
        }
        let queue = if in_dir {
            std::mem::take(&mut self.in_queue[k])
        } else {
            std::mem::take(&mut self.out_queue[k])
        };
        for t in queue {
            self.fail(&t.urb, status::STALL);
        }
    }

    fn poll(&mut self) -> PollResult {
        if self.reset_pending {
            self.reset_pending = false;
            self.resets = self.resets.saturating_add(1);
            return PollResult::Reset;
        }
        if self.suspend_pending {
            self.suspend_pending = false;
            return PollResult::Suspend;
        }
        if !self.attached {
            return PollResult::None;
        }
        self.start_control();
        let mut ep_setup = 0u16;
        let mut ep_out = 0u16;
        if let Some(c) = &self.control {
            match c.stage {
                Stage::Setup => ep_setup |= 1,
                Stage::DataOut | Stage::StatusOut => ep_out |= 1,
                Stage::DataIn | Stage::StatusIn => {}
            }
        }
        for (k, q) in self.out_queue.iter().enumerate().skip(1) {
            if !q.is_empty() {
                ep_out |= 1 << k;
            }
        }
        let ep_in_complete = std::mem::take(&mut self.in_complete);
        if ep_setup | ep_out | ep_in_complete == 0 {
            PollResult::None
        } else {
            PollResult::Data {
                ep_out,
                ep_in_complete,
                ep_setup,
            }
        }
    }

    fn reset_endpoints(&mut self) {
        self.stalled_in = 0;
        self.stalled_out = 0;
        self.in_packet = Default::default();
        self.in_complete = 0;
        self.address = 0;
    }
}

/// The network side's handle.
#[derive(Clone, Debug)]
pub struct Port(Arc<Mutex<Core>>);

/// The `UsbBus` the device runs on.
#[derive(Debug)]
pub struct UsbIpBus(Arc<Mutex<Core>>);

/// A bus and the port to its host.
pub fn new() -> (UsbIpBus, Port) {
    let core = Arc::new(Mutex::new(Core::default()));
    (UsbIpBus(core.clone()), Port(core))
}

fn lock(core: &Mutex<Core>) -> MutexGuard<'_, Core> {
    // One thread uses both sides; a poisoned lock only means a panic
    // elsewhere already ended the test or program.
    core.lock().unwrap_or_else(|e| e.into_inner())
}

impl Port {
    /// A client imported the device: the next poll is a bus reset.
    pub fn attach(&self) {
        let mut c = lock(&self.0);
        c.drop_urbs();
        c.attached = true;
        c.reset_pending = true;
        c.suspend_pending = false;
    }

    /// The client went away: every URB is dropped, the device is suspended.
    pub fn detach(&self) {
        let mut c = lock(&self.0);
        c.drop_urbs();
        c.attached = false;
        c.reset_pending = false;
        c.suspend_pending = true;
    }

    pub fn is_attached(&self) -> bool {
        lock(&self.0).attached
    }

    pub fn submit(&self, urb: Submit) {
        lock(&self.0).submit(urb);
    }

    pub fn unlink(&self, u: Unlink) {
        lock(&self.0).unlink(u);
    }

    /// Replies in the order the URBs completed.
    pub fn take_replies(&self) -> Vec<Reply> {
        lock(&self.0).replies.drain(..).collect()
    }

    /// EP0 writes the bus dropped (see the module doc).
    pub fn stray_ep0_writes(&self) -> u32 {
        lock(&self.0).stray_ep0_writes
    }

    /// Record control transfers and unlinks for [`Port::take_trace`].
    pub fn set_tracing(&self, on: bool) {
        lock(&self.0).tracing = on;
    }

    /// What happened since the last call (tracing on).
    pub fn take_trace(&self) -> Vec<Trace> {
        std::mem::take(&mut lock(&self.0).trace)
    }

    /// Bus resets so far.
    pub fn resets(&self) -> u32 {
        lock(&self.0).resets
    }

    /// URBs neither completed nor unlinked.
    pub fn pending_urbs(&self) -> usize {
        let c = lock(&self.0);
        let queued = |qs: &[VecDeque<Transfer>]| qs.iter().map(VecDeque::len).sum::<usize>();
        usize::from(c.control.is_some())
            .saturating_add(c.control_queue.len())
            .saturating_add(queued(&c.out_queue))
            .saturating_add(queued(&c.in_queue))
    }
}

impl usb_device::bus::UsbBus for UsbIpBus {
    #[allow(clippy::indexing_slicing)] // k < ENDPOINTS: checked, or from 1..ENDPOINTS
    fn alloc_ep(
        &mut self,
        ep_dir: UsbDirection,
        ep_addr: Option<EndpointAddress>,
        ep_type: EndpointType,
        max_packet_size: u16,
        _interval: u8,
    ) -> usb_device::Result<EndpointAddress> {
        let mut c = lock(&self.0);
        let table = match ep_dir {
            UsbDirection::In => &mut c.ep_in,
            UsbDirection::Out => &mut c.ep_out,
        };
        let k = match ep_addr {
            Some(a) => {
                let k = a.index();
                if k >= ENDPOINTS || a.direction() != ep_dir || table[k].is_some() {
                    return Err(UsbError::InvalidEndpoint);
                }
                k
            }
            None => (1..ENDPOINTS)
                .find(|k| table[*k].is_none())
                .ok_or(UsbError::EndpointOverflow)?,
        };
        if max_packet_size > 64 || (k == 0 && ep_type != EndpointType::Control) {
            // Full speed: 64 bytes at most on control and interrupt endpoints.
            return Err(UsbError::EndpointMemoryOverflow);
        }
        table[k] = Some(EpConfig {
            ep_type,
            max_packet: usize::from(max_packet_size),
        });
        Ok(EndpointAddress::from_parts(k, ep_dir))
    }

    fn enable(&mut self) {}

    fn reset(&self) {
        lock(&self.0).reset_endpoints();
    }

    fn set_device_address(&self, addr: u8) {
        lock(&self.0).address = addr;
    }

    fn write(&self, ep_addr: EndpointAddress, buf: &[u8]) -> usb_device::Result<usize> {
        lock(&self.0).write(ep_addr, buf)
    }

    fn read(&self, ep_addr: EndpointAddress, buf: &mut [u8]) -> usb_device::Result<usize> {
        lock(&self.0).read(ep_addr, buf)
    }

    fn set_stalled(&self, ep_addr: EndpointAddress, stalled: bool) {
        lock(&self.0).set_stalled(ep_addr, stalled);
    }

    fn is_stalled(&self, ep_addr: EndpointAddress) -> bool {
        let c = lock(&self.0);
        let k = ep_addr.index();
        let flags = match ep_addr.direction() {
            UsbDirection::In => c.stalled_in,
            UsbDirection::Out => c.stalled_out,
        };
        k < ENDPOINTS && flags & (1 << k) != 0
    }

    fn suspend(&self) {}

    fn resume(&self) {}

    fn poll(&self) -> PollResult {
        lock(&self.0).poll()
    }
}

impl UsbIpBus {
    /// The endpoint type allocated at `ep`, if any (tests).
    pub fn endpoint_type(&self, ep: EndpointAddress) -> Option<EndpointType> {
        let c = lock(&self.0);
        let table = match ep.direction() {
            UsbDirection::In => &c.ep_in,
            UsbDirection::Out => &c.ep_out,
        };
        table.get(ep.index()).copied().flatten().map(|e| e.ep_type)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{DIR_IN, DIR_OUT};
    use usb_device::bus::UsbBus;

    const EP0_OUT: u8 = 0x00;
    const EP0_IN: u8 = 0x80;
    const EP1_OUT: u8 = 0x01;
    const EP1_IN: u8 = 0x81;
    const GET_DEVICE: [u8; 8] = [0x80, 0x06, 0x00, 0x01, 0x00, 0x00, 0x12, 0x00];

    fn ep(a: u8) -> EndpointAddress {
        EndpointAddress::from(a)
    }

    /// A bus with EP0 and EP1 in both directions, attached and reset.
    fn bus() -> (UsbIpBus, Port) {
        let (mut b, p) = new();
        for (dir, a, t) in [
            (UsbDirection::Out, EP0_OUT, EndpointType::Control),
            (UsbDirection::In, EP0_IN, EndpointType::Control),
            (UsbDirection::In, EP1_IN, EndpointType::Interrupt),
            (UsbDirection::Out, EP1_OUT, EndpointType::Interrupt),
        ] {
            b.alloc_ep(dir, Some(ep(a)), t, 64, 10).unwrap();
        }
        p.attach();
        assert!(matches!(b.poll(), PollResult::Reset));
        b.reset();
        (b, p)
    }

    fn urb(seqnum: u32, ep: u32, direction: u32, len: u32, setup: [u8; 8], data: &[u8]) -> Submit {
        Submit::transfer(seqnum, 0x0001_0002, (ep, direction), len, setup, data)
    }

    fn status_of(r: &Reply) -> (u32, i32) {
        match r {
            Reply::Submit { seqnum, status, .. } => (*seqnum, *status),
            Reply::Unlink { seqnum, status } => (*seqnum, *status),
        }
    }

    /// The device's side of a GET_DESCRIPTOR(device): SETUP, data, status.
    fn serve_get_device(b: &UsbIpBus) {
        assert!(matches!(b.poll(), PollResult::Data { ep_setup: 1, .. }));
        let mut buf = [0u8; 64];
        assert_eq!(b.read(ep(EP0_OUT), &mut buf), Ok(8));
        assert_eq!(b.write(ep(EP0_IN), &[0x12; 18]), Ok(18));
        assert!(matches!(
            b.poll(),
            PollResult::Data {
                ep_out: 1,
                ep_in_complete: 1,
                ..
            }
        ));
        assert_eq!(
            b.read(ep(EP0_OUT), &mut buf),
            Ok(0),
            "the host's status ZLP"
        );
    }

    #[test]
    fn an_ep0_write_outside_a_transfer_is_dropped_never_the_next_answer() {
        let (b, p) = bus();
        assert_eq!(b.write(ep(EP0_IN), &[]), Ok(0));
        assert_eq!(p.stray_ep0_writes(), 1);
        p.submit(urb(1, 0, DIR_IN, 18, GET_DEVICE, &[]));
        serve_get_device(&b);
        let r = p.take_replies();
        assert_eq!(
            r,
            vec![Reply::Submit {
                seqnum: 1,
                status: 0,
                actual_length: 18,
                data: vec![0x12; 18]
            }]
        );
    }

    #[test]
    fn a_no_data_out_waits_for_the_device_s_status_zlp() {
        let (b, p) = bus();
        p.submit(urb(1, 0, DIR_OUT, 0, [0, 0x09, 1, 0, 0, 0, 0, 0], &[]));
        assert!(matches!(b.poll(), PollResult::Data { ep_setup: 1, .. }));
        let mut buf = [0u8; 64];
        assert_eq!(b.read(ep(EP0_OUT), &mut buf), Ok(8));
        assert!(p.take_replies().is_empty(), "not before the status stage");
        assert_eq!(b.write(ep(EP0_IN), &[]), Ok(0));
        assert_eq!(
            p.take_replies().iter().map(status_of).collect::<Vec<_>>(),
            [(1, 0)]
        );
        assert_eq!(p.stray_ep0_writes(), 0);
    }

    #[test]
    fn an_ep0_stall_fails_the_transfer_with_epipe_and_the_next_setup_clears_it() {
        let (b, p) = bus();
        p.submit(urb(1, 0, DIR_IN, 18, GET_DEVICE, &[]));
        p.submit(urb(2, 0, DIR_IN, 18, GET_DEVICE, &[]));
        b.poll();
        let mut buf = [0u8; 64];
        b.read(ep(EP0_OUT), &mut buf).unwrap();
        // usb-device stalls both halves of EP0.
        b.set_stalled(ep(EP0_OUT), true);
        b.set_stalled(ep(EP0_IN), true);
        assert_eq!(
            p.take_replies().iter().map(status_of).collect::<Vec<_>>(),
            [(1, status::STALL)],
            "the second URB is not hit by the second stall"
        );
        serve_get_device(&b);
        assert!(!b.is_stalled(ep(EP0_IN)));
        assert_eq!(
            p.take_replies().iter().map(status_of).collect::<Vec<_>>(),
            [(2, 0)]
        );
    }

    #[test]
    fn a_stalled_interrupt_endpoint_fails_its_urbs_until_the_halt_is_cleared() {
        let (b, p) = bus();
        p.submit(urb(1, 1, DIR_IN, 64, [0; 8], &[]));
        b.set_stalled(ep(EP1_IN), true);
        p.submit(urb(2, 1, DIR_IN, 64, [0; 8], &[]));
        b.set_stalled(ep(EP1_IN), false);
        p.submit(urb(3, 1, DIR_IN, 64, [0; 8], &[]));
        assert_eq!(
            p.take_replies().iter().map(status_of).collect::<Vec<_>>(),
            [(1, status::STALL), (2, status::STALL)]
        );
        assert_eq!(b.write(ep(EP1_IN), &[7; 64]), Ok(64));
        assert_eq!(
            p.take_replies().iter().map(status_of).collect::<Vec<_>>(),
            [(3, 0)]
        );
        assert!(matches!(
            b.poll(),
            PollResult::Data {
                ep_in_complete: 2,
                ..
            }
        ));
    }

    #[test]
    fn an_in_packet_waits_in_its_endpoint_and_one_beyond_the_urb_is_babble() {
        let (b, p) = bus();
        assert_eq!(b.write(ep(EP1_IN), &[1; 64]), Ok(64));
        assert_eq!(b.write(ep(EP1_IN), &[2; 64]), Err(UsbError::WouldBlock));
        p.submit(urb(1, 1, DIR_IN, 64, [0; 8], &[]));
        assert!(matches!(&p.take_replies()[..], [Reply::Submit { data, .. }] if data == &[1; 64]));
        p.submit(urb(2, 1, DIR_IN, 8, [0; 8], &[]));
        assert_eq!(b.write(ep(EP1_IN), &[3; 64]), Ok(64));
        assert_eq!(
            p.take_replies().iter().map(status_of).collect::<Vec<_>>(),
            [(2, status::PROTOCOL)]
        );
    }

    #[test]
    fn an_out_urb_is_delivered_in_packets_of_the_endpoint_s_size() {
        let (b, p) = bus();
        let data: Vec<u8> = (0..100).collect();
        p.submit(urb(1, 1, DIR_OUT, 100, [0; 8], &data));
        assert!(matches!(b.poll(), PollResult::Data { ep_out: 2, .. }));
        let mut buf = [0u8; 64];
        assert_eq!(b.read(ep(EP1_OUT), &mut buf), Ok(64));
        assert!(p.take_replies().is_empty());
        assert_eq!(b.read(ep(EP1_OUT), &mut buf), Ok(36));
        assert_eq!(&buf[..36], &data[64..]);
        assert!(matches!(
            &p.take_replies()[..],
            [Reply::Submit {
                actual_length: 100,
                ..
            }]
        ));
        assert_eq!(b.read(ep(EP1_OUT), &mut buf), Err(UsbError::WouldBlock));
    }

    #[test]
    fn unlinking_a_control_transfer_in_progress_lets_the_next_one_run_clean() {
        let (b, p) = bus();
        p.submit(urb(1, 0, DIR_IN, 18, GET_DEVICE, &[]));
        b.poll();
        let mut buf = [0u8; 64];
        b.read(ep(EP0_OUT), &mut buf).unwrap();
        p.unlink(Unlink {
            seqnum: 2,
            devid: 0,
            direction: DIR_IN,
            ep: 0,
            unlink_seqnum: 1,
        });
        // The device answers late: dropped.
        b.write(ep(EP0_IN), &[0xEE; 18]).unwrap();
        p.submit(urb(3, 0, DIR_IN, 18, GET_DEVICE, &[]));
        serve_get_device(&b);
        let r = p.take_replies();
        assert_eq!(
            r.iter().map(status_of).collect::<Vec<_>>(),
            [(2, status::UNLINKED), (3, 0)]
        );
        assert!(matches!(&r[1], Reply::Submit { data, .. } if data == &[0x12; 18]));
    }

    #[test]
    fn endpoints_are_full_speed_sized_and_allocated_once() {
        let (mut b, _p) = new();
        assert_eq!(
            b.alloc_ep(
                UsbDirection::In,
                Some(ep(0x81)),
                EndpointType::Interrupt,
                512,
                1
            ),
            Err(UsbError::EndpointMemoryOverflow)
        );
        b.alloc_ep(
            UsbDirection::In,
            Some(ep(0x81)),
            EndpointType::Interrupt,
            64,
            1,
        )
        .unwrap();
        assert_eq!(
            b.alloc_ep(
                UsbDirection::In,
                Some(ep(0x81)),
                EndpointType::Interrupt,
                64,
                1
            ),
            Err(UsbError::InvalidEndpoint)
        );
        let next = b
            .alloc_ep(UsbDirection::In, None, EndpointType::Bulk, 64, 0)
            .unwrap();
        assert_eq!(next, ep(0x82));
        assert_eq!(b.endpoint_type(next), Some(EndpointType::Bulk));
    }
}
