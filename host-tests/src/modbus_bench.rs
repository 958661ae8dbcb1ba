//! A simulated Modbus RTU master on the bridge's RS-485 line: bytes go to
//! the same `RtuServer` the firmware's USART interrupt feeds, each stamped
//! with the time its stop bit ends, on one virtual clock (µs) that also
//! ticks the bridge and the simulated chips once per millisecond and polls
//! the server at its deadlines, as the firmware does.
//!
//! The CRC here is a bitwise CRC-16/MODBUS written from the spec, not the
//! `crc` crate the server uses, so the two check each other.

use crate::clock::SimClock;
use bridge_logic::bridge::Bridge;
use bridge_logic::postep60::settings::Serial;
use bridge_logic::postep60::{PowerStage, Settings};
use bridge_logic::transport::modbus::{RtuServer, Timing};
use stepbridge_sim::SimChain;

pub use crate::sim_bridge::TICK_US;

/// CRC-16/MODBUS (poly 0xA001 reflected, init 0xFFFF), bit by bit.
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for b in bytes {
        crc ^= u16::from(*b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    crc
}

/// `body` followed by its CRC, low byte first.
pub fn adu(body: &[u8]) -> Vec<u8> {
    let mut v = body.to_vec();
    v.extend_from_slice(&crc16(body).to_le_bytes());
    v
}

/// True if the last two bytes are the CRC of the rest.
pub fn crc_ok(adu: &[u8]) -> bool {
    match adu.len().checked_sub(2) {
        Some(n) if n > 0 => crc16(&adu[..n]).to_le_bytes() == adu[n..],
        _ => false,
    }
}

/// Character time for 11-bit characters, µs (rounded up).
pub fn character_us(serial: Serial) -> u64 {
    (11_000_000u64).div_ceil(u64::from(serial.baud))
}

/// Bridge + simulated chain + RTU server + virtual clock.
#[derive(Clone)]
pub struct ModbusBench {
    pub bridge: Bridge<SimChain>,
    pub server: RtuServer,
    pub timing: Timing,
    /// One character on the wire, µs.
    pub char_us: u64,
    /// Virtual time, µs.
    pub now_us: u64,
    /// The control loop's virtual clock (ticks every [`TICK_US`]).
    pub clock: SimClock,
    /// Responses the server produced, with the time `poll` returned them.
    pub sent: Vec<(u64, Vec<u8>)>,
}

impl ModbusBench {
    /// A bridge on `n` simulated chips with `settings`, run until configured.
    pub fn new(n: usize, settings: Settings) -> ModbusBench {
        Self::with_board(n, settings, PowerStage::REFERENCE)
    }

    pub fn with_board(n: usize, settings: Settings, board: PowerStage) -> ModbusBench {
        let bridge = crate::sim_bridge::new_bridge(n, settings, board);
        let timing = Timing::for_serial(bridge.serial());
        let mut line = ModbusBench {
            char_us: character_us(bridge.serial()),
            server: RtuServer::new(timing),
            timing,
            bridge,
            now_us: 0,
            clock: SimClock::new(TICK_US),
            sent: Vec::new(),
        };
        line.run(20);
        line
    }

    /// Let virtual time pass until `t`: control ticks at every whole
    /// millisecond and server polls at its deadlines, in time order.
    pub fn advance_to(&mut self, t: u64) {
        while let Some(d) = self.step_until(t) {
            if let Some(resp) = self.server.poll(d, &mut self.bridge) {
                self.sent.push((d, resp.to_vec()));
            }
            // As the firmware's Modbus task: the counters go to the bridge.
            self.bridge.set_modbus_stats(self.server.stats());
        }
    }

    /// Tick the bridge up to `t`, stopping early at a server deadline ≤ `t`
    /// that is due before the next tick: returns it (the caller polls).
    pub fn step_until(&mut self, t: u64) -> Option<u64> {
        loop {
            let next_tick = self.clock.next_tick_us();
            match self.server.deadline().filter(|d| *d <= t) {
                Some(d) if d <= next_tick => {
                    self.now_us = d.max(self.now_us);
                    return Some(self.now_us);
                }
                _ if next_tick <= t => {
                    self.now_us = self.now_us.max(next_tick);
                    self.clock.tick(&mut self.bridge);
                }
                _ => {
                    self.now_us = self.now_us.max(t);
                    return None;
                }
            }
        }
    }

    /// Silence on the line for `us`.
    pub fn pause(&mut self, us: u64) {
        self.advance_to(self.now_us + us);
    }

    /// Put `bytes` on the line back to back (each byte ends one character
    /// after the previous one), no silence before or after.
    pub fn put(&mut self, bytes: &[u8]) {
        for b in bytes {
            let t = self.now_us + self.char_us;
            self.advance_to(t);
            self.server.on_byte(*b, t);
        }
    }

    /// Wait until the line has been silent long enough for the server to
    /// end the frame, then collect what it sent (in order).
    pub fn collect(&mut self) -> Vec<Vec<u8>> {
        self.pause(u64::from(self.timing.t35_us) + 1);
        // A deferred extension read answers a few ms later.
        while self.sent.is_empty() {
            match self.server.deadline() {
                Some(d) if d <= self.now_us + 100_000 => self.advance_to(d.max(self.now_us + 1)),
                _ => break,
            }
        }
        let out: Vec<Vec<u8>> = self.sent.drain(..).map(|(_, r)| r).collect();
        // Model the reply on the wire and the turnaround before the master
        // talks again.
        let busy: u64 = out.iter().map(|r| r.len() as u64 * self.char_us).sum();
        self.pause(busy + u64::from(self.timing.t35_us));
        out
    }

    /// One master transaction: send `request` (a complete ADU with CRC) as
    /// one frame and return the response ADU, if any. Checks the CRC of
    /// both with the harness's own CRC.
    pub fn transact(&mut self, request: &[u8]) -> Option<Vec<u8>> {
        assert!(crc_ok(request), "bad CRC in the test vector {request:02X?}");
        self.put(request);
        let mut out = self.collect();
        assert!(out.len() <= 1, "more than one response: {out:02X?}");
        let resp = out.pop()?;
        assert!(crc_ok(&resp), "bad CRC in the response {resp:02X?}");
        Some(resp)
    }

    /// FC 0x03 of `quantity` registers at `address` of server `id`:
    /// the registers, or the exception code.
    pub fn read(&mut self, id: u8, address: u16, quantity: u16) -> Result<Vec<u16>, u8> {
        let [a0, a1] = address.to_be_bytes();
        let [q0, q1] = quantity.to_be_bytes();
        let resp = self
            .transact(&adu(&[id, 0x03, a0, a1, q0, q1]))
            .expect("no response");
        assert_eq!(resp[0], id);
        if resp[1] == 0x83 {
            return Err(resp[2]);
        }
        assert_eq!(resp[1], 0x03);
        assert_eq!(usize::from(resp[2]), 2 * usize::from(quantity));
        Ok(resp[3..resp.len() - 2]
            .chunks(2)
            .map(|c| u16::from_be_bytes([c[0], c[1]]))
            .collect())
    }

    /// FC 0x06: Ok if the echo came back, else the exception code.
    pub fn write(&mut self, id: u8, address: u16, value: u16) -> Result<(), u8> {
        let [a0, a1] = address.to_be_bytes();
        let [v0, v1] = value.to_be_bytes();
        let req = adu(&[id, 0x06, a0, a1, v0, v1]);
        let resp = self.transact(&req).expect("no response");
        if resp[1] == 0x86 {
            return Err(resp[2]);
        }
        assert_eq!(resp, req, "FC 0x06 echoes the request");
        Ok(())
    }

    /// FC 0x10 of `regs` at `address`.
    pub fn write_multiple(&mut self, id: u8, address: u16, regs: &[u16]) -> Result<(), u8> {
        let [a0, a1] = address.to_be_bytes();
        let [q0, q1] = (regs.len() as u16).to_be_bytes();
        let mut body = vec![id, 0x10, a0, a1, q0, q1, (regs.len() * 2) as u8];
        for r in regs {
            body.extend_from_slice(&r.to_be_bytes());
        }
        let resp = self.transact(&adu(&body)).expect("no response");
        if resp[1] == 0x90 {
            return Err(resp[2]);
        }
        assert_eq!(resp, adu(&[id, 0x10, a0, a1, q0, q1]));
        Ok(())
    }

    /// Set position (0x50, FC 0x10, two registers high word first).
    pub fn set_position(&mut self, id: u8, pos: i32) -> Result<(), u8> {
        let p = pos as u32;
        self.write_multiple(id, 0x50, &[(p >> 16) as u16, p as u16])
    }

    /// Read position (0x40, two registers high word first).
    pub fn position(&mut self, id: u8) -> i32 {
        let r = self.read(id, 0x40, 2).expect("read position");
        ((u32::from(r[0]) << 16) | u32::from(r[1])) as i32
    }

    /// Run the control loop for `ms` milliseconds of virtual time.
    pub fn run(&mut self, ms: u64) {
        self.pause(ms * 1000);
    }

    /// Run until every axis is settled (panics after `cap` ms).
    pub fn settle(&mut self, cap: u64) {
        crate::sim_bridge::settle(self, cap, |h| &h.bridge, |h| h.run(1));
    }

    pub fn chip(&self, k: usize) -> &stepbridge_sim::Powerstep01 {
        crate::sim_bridge::chip(&self.bridge, k)
    }

    pub fn chip_mut(&mut self, k: usize) -> &mut stepbridge_sim::Powerstep01 {
        crate::sim_bridge::chip_mut(&mut self.bridge, k)
    }
}

// ------------------------------------------------------------------------
// Arbitrary streams (the proptest in tests/modbus_robustness.rs and the
// cargo-fuzz target `modbus_stream`): an independent model of the framing
// rules decides which frames are intact; the server may only execute
// requests from intact frames that carry them, may only answer intact
// unicast frames for our ids, and no chip may move unless a motion request
// was executed.
// ------------------------------------------------------------------------

use bridge_logic::postep60::{CommandError, Effect, Query, Request, Value};
use bridge_logic::transport::modbus::ModbusTarget;

/// The framing rules restated for a stream whose frames are polled at every
/// deadline: a frame ends t3.5 after its last byte; a byte ending more than
/// one character + t1.5 after the previous one breaks the frame.
#[derive(Debug)]
pub struct FrameModel {
    t15: u64,
    t35: u64,
    char_us: u64,
    bytes: Vec<u8>,
    broken: bool,
    last: u64,
}

impl FrameModel {
    pub fn new(timing: Timing) -> FrameModel {
        FrameModel {
            t15: u64::from(timing.t15_us),
            t35: u64::from(timing.t35_us),
            // ⅔·t1.5, as the server's module doc says
            char_us: (u64::from(timing.t15_us) * 2).div_ceil(3),
            bytes: Vec::new(),
            broken: false,
            last: 0,
        }
    }

    pub fn push(&mut self, byte: u8, t: u64) {
        if !self.bytes.is_empty() && t - self.last > self.char_us + self.t15 {
            self.broken = true;
        }
        self.bytes.push(byte);
        self.last = t;
    }

    /// When the frame in progress ends.
    pub fn deadline(&self) -> Option<u64> {
        (!self.bytes.is_empty()).then_some(self.last + self.t35)
    }

    /// The ended frame: its bytes without CRC if it is intact (no gap,
    /// 4..=256 bytes, CRC right by the bitwise CRC), else None.
    pub fn take(&mut self) -> Option<Vec<u8>> {
        let bytes = std::mem::take(&mut self.bytes);
        let broken = std::mem::replace(&mut self.broken, false);
        (!broken && (4..=256).contains(&bytes.len()) && crc_ok(&bytes))
            .then(|| bytes[..bytes.len() - 2].to_vec())
    }
}

/// (server id, PoStep60 command byte) of an intact write frame body
/// (FC 0x06 or 0x10 at an address 0x00nn); None for anything else.
pub fn write_command(body: &[u8]) -> Option<(u8, u8)> {
    match body {
        [id, 0x06, 0x00, cmd, _, _] => Some((*id, *cmd)),
        [id, 0x10, 0x00, cmd, _, _, _, data @ ..] if !data.is_empty() => Some((*id, *cmd)),
        _ => None,
    }
}

/// The manual 9.3 command byte a request comes from.
pub fn command_of(req: &Request) -> Option<u8> {
    Some(match req {
        Request::RunSleep(_) => 0x03,
        Request::SetAddress { .. } => 0x04,
        Request::SetMode(_) => 0x05,
        Request::SetPwm => 0x06,
        Request::SetFullScaleCurrent(_) => 0x30,
        Request::SetIdleCurrent(_) => 0x31,
        Request::SetOverheatCurrent(_) => 0x32,
        Request::SetStepMode(_) => 0x33,
        Request::SetTemperatureLimit(_) => 0x34,
        Request::ResetFaults => 0x35,
        Request::WriteSettings => 0x3F,
        Request::SetPosition(_) => 0x50,
        Request::SetMaxSpeed(_) => 0x51,
        Request::SetAcceleration(_) => 0x52,
        Request::SetDeceleration(_) => 0x53,
        Request::SetRequestedSpeed(_) => 0x54,
        Request::SetInvert(_) => 0x55,
        Request::SetZero => 0x5E,
        Request::Stop => 0x5F,
        Request::SystemReset => 0x60,
        Request::Loopback(_)
        | Request::SoftStop
        | Request::SetModeUsb(_)
        | Request::SetDriverRegisters(_)
        | Request::StepDir { .. }
        | Request::Trajectory(_)
        | Request::SetName(_) => return None,
    })
}

/// Requests that may start or redirect motion.
pub fn may_move(req: &Request) -> bool {
    matches!(
        req,
        Request::SetPosition(_)
            | Request::SetRequestedSpeed(_)
            | Request::SetMode(_)
            | Request::SetInvert(_)
            | Request::SoftStop
            | Request::SetModeUsb(_)
            | Request::SetDriverRegisters(_)
            | Request::StepDir { .. }
            | Request::Trajectory(_)
    )
}

/// A target that records every request on its way to the bridge.
pub struct Recording<'a, T: ModbusTarget> {
    pub inner: &'a mut T,
    pub log: Vec<(usize, Request)>,
}

impl<T: ModbusTarget> ModbusTarget for Recording<'_, T> {
    fn axis_for_id(&self, id: u8) -> Option<usize> {
        self.inner.axis_for_id(id)
    }
    fn axes(&self) -> usize {
        self.inner.axes()
    }
    fn request(&mut self, axis: usize, req: Request) -> Result<Effect, CommandError> {
        self.log.push((axis, req));
        self.inner.request(axis, req)
    }
    fn query(&mut self, axis: usize, q: Query) -> Option<Value> {
        self.inner.query(axis, q)
    }
    fn ext_read(
        &mut self,
        axis: usize,
        address: u16,
        out: &mut [u16],
    ) -> Result<(), bridge_logic::ext_space::ExtError> {
        self.inner.ext_read(axis, address, out)
    }
    fn ext_write(
        &mut self,
        axis: usize,
        address: u16,
        data: &[u16],
    ) -> Result<(), bridge_logic::ext_space::ExtError> {
        self.inner.ext_write(axis, address, data)
    }
}

/// What a stream did.
#[derive(Debug, Default)]
pub struct StreamReport {
    pub intact_frames: u32,
    pub requests: u32,
    pub responses: u32,
    pub moved: bool,
}

/// Feed `(byte, µs since the previous byte ended)` to a 2-axis bridge at
/// 9600 baud, polling at every deadline, and check the promises of the
/// server (panics on a violation). With `fix_crc`, every run of bytes that
/// the timing makes a frame of ≥ 4 bytes gets a correct CRC first, so that
/// most frames reach the command layer.
pub fn check_stream(records: &[(u8, u64)], fix_crc: bool) -> StreamReport {
    let mut line =
        crate::sim_bridge::template("modbus_stream", || ModbusBench::new(2, Settings::FACTORY));
    let timing = line.timing;
    let mut records = records.to_vec();
    if fix_crc {
        fix_crcs(&mut records, u64::from(timing.t35_us));
    }
    let mut model = FrameModel::new(timing);
    let mut report = StreamReport::default();
    let mut motion = false;
    let mut waiting = None;
    let start = line.now_us;
    for (byte, dt) in records {
        let t = line.now_us + dt;
        while let Some(d) = line.step_until(t) {
            checked_poll(
                &mut line,
                &mut model,
                d,
                &mut report,
                &mut motion,
                &mut waiting,
            );
        }
        line.server.on_byte(byte, t);
        model.push(byte, t);
        deadlines_agree(&line, &model, &waiting);
    }
    // Frames, and extension reads that wait for the chip (≤ 50 ms).
    let end = line.now_us + u64::from(timing.t35_us) + 60_000;
    while let Some(d) = line.step_until(end) {
        checked_poll(
            &mut line,
            &mut model,
            d,
            &mut report,
            &mut motion,
            &mut waiting,
        );
    }
    assert_eq!(line.server.deadline(), None);
    line.run(50);
    report.moved = (0..2).any(|k| line.chip(k).abs_pos() != 0 || line.chip(k).speed_reg() != 0);
    assert!(
        motion || !report.moved,
        "a chip moved without a motion request ({} µs of stream)",
        line.now_us - start
    );
    report
}

/// The server polls at the model's frame ends, and — while an extension
/// read waits for the chip — at its retry times too.
fn deadlines_agree(line: &ModbusBench, model: &FrameModel, waiting: &Option<(Vec<u8>, u8)>) {
    let server = line.server.deadline();
    if waiting.is_some() {
        match (server, model.deadline()) {
            (Some(s), Some(m)) => assert!(s <= m, "server deadline after the frame end"),
            (s, m) => assert!(s.is_some() || m.is_none()),
        }
    } else {
        assert_eq!(server, model.deadline());
    }
}

/// An extension write that may start motion (homing, 0x04nn).
fn ext_motion(body: &[u8]) -> bool {
    matches!(body, [_, 0x06 | 0x10, 0x04, ..])
}

fn checked_poll(
    line: &mut ModbusBench,
    model: &mut FrameModel,
    at: u64,
    report: &mut StreamReport,
    motion: &mut bool,
    waiting: &mut Option<(Vec<u8>, u8)>,
) {
    let frame_end = Some(at) == model.deadline();
    assert!(
        frame_end || waiting.is_some(),
        "poll at the model's frame end"
    );
    let body = if frame_end { model.take() } else { None };
    if frame_end && waiting.is_some() {
        // A new frame: the waiting read is dropped.
        *waiting = None;
    }
    if let Some(b) = body.as_ref() {
        *motion |= ext_motion(b);
    }
    let deferred_before = line.server.stats().deferred;
    // Which ids are ours is decided before the frame runs (0x04 may move them).
    let ours = body.as_ref().and_then(|b| {
        let id = b[0];
        (id == 0 || ((1..=247).contains(&id) && line.bridge.axis_at(id).is_some())).then_some(id)
    });
    let mut target = Recording {
        inner: &mut line.bridge,
        log: Vec::new(),
    };
    let resp = line.server.poll(at, &mut target).map(<[u8]>::to_vec);
    let log = target.log;
    if body.is_some() {
        report.intact_frames += 1;
    }
    let (body, ours) = if !frame_end {
        // A retry of the waiting extension read: it answers now or later.
        let w = waiting.clone();
        if resp.is_some() {
            *waiting = None;
        }
        match w {
            Some((b, id)) => (Some(b), Some(id)),
            None => (None, None),
        }
    } else {
        if line.server.stats().deferred > deferred_before {
            let b = body
                .clone()
                .expect("a deferred read of a frame that is not intact");
            *waiting = Some((b, ours.expect("a deferred read for another id")));
        }
        (body, ours)
    };
    if !log.is_empty() {
        check_requests(&log, body.as_deref(), ours, report, motion);
    }
    if let Some(resp) = resp {
        check_response(&resp, body.as_deref(), ours, report);
    }
}

/// The requests a frame made of the bridge: from an intact write frame for
/// one of our ids, each of that command, on axis 0 or 1.
fn check_requests(
    log: &[(usize, Request)],
    body: Option<&[u8]>,
    ours: Option<u8>,
    report: &mut StreamReport,
    motion: &mut bool,
) {
    let body = body.expect("a request from a frame that is not intact");
    let (id, cmd) = write_command(body).expect("a request from a frame that is no write");
    assert_eq!(Some(id), ours, "a request from a frame for another id");
    for (axis, req) in log {
        assert_eq!(
            command_of(req),
            Some(cmd),
            "{req:?} from command {cmd:#04x}"
        );
        assert!(*axis < 2);
        *motion |= may_move(req);
    }
    report.requests += log.len() as u32;
}

/// An answer: to an intact frame for one of our ids (never a broadcast),
/// CRC right, same function or its exception (codes 1..4, 5 bytes).
fn check_response(resp: &[u8], body: Option<&[u8]>, ours: Option<u8>, report: &mut StreamReport) {
    let body = body.expect("an answer to a frame that is not intact");
    let id = ours.expect("an answer to a frame for another id");
    assert_ne!(id, 0, "an answer to a broadcast");
    assert!(crc_ok(resp), "response CRC");
    assert_eq!(resp[0], id);
    assert!(resp[1] == body[1] || resp[1] == body[1] | 0x80);
    if resp[1] & 0x80 != 0 {
        assert_eq!(resp.len(), 5);
        assert!((1..=4).contains(&resp[2]));
    }
    report.responses += 1;
}

/// Give every would-be frame of ≥ 4 bytes a correct CRC.
fn fix_crcs(records: &mut [(u8, u64)], t35: u64) {
    let mut start = 0;
    for i in 1..=records.len() {
        if i == records.len() || records[i].1 >= t35 {
            let frame = &mut records[start..i];
            if frame.len() >= 4 {
                let n = frame.len() - 2;
                let body: Vec<u8> = frame[..n].iter().map(|r| r.0).collect();
                let [lo, hi] = crc16(&body).to_le_bytes();
                frame[n].0 = lo;
                frame[n + 1].0 = hi;
            }
            start = i;
        }
    }
}

/// Fuzzer input → records. Byte 0: bit 0 selects `fix_crc`, bit 1 the
/// frame mode. The rest:
/// * pair mode: (byte, silence code) pairs; the code × 20 µs is the time
///   from the end of the previous byte to the end of this one (0..=5.08 ms:
///   around t1.5 and t3.5 at 9600 baud); 255 is a pause of 100 ms.
/// * frame mode: frames as `[header, bytes…]`, header bits 0..=4 the byte
///   count (bytes back to back, one character apart), bits 5..=7 the silence
///   after the frame: 4100 µs, 1000, 2000, 3000, none, 100 ms, exactly t3.5
///   (4011), one µs over character + t1.5 (2866) — so that dictionary
///   tokens like `01 06 00 50` are whole frames.
pub fn records_from_fuzz(data: &[u8]) -> (Vec<(u8, u64)>, bool) {
    const CHAR: u64 = 1146;
    const SILENCE: [u64; 8] = [4100, 1000, 2000, 3000, 0, 100_000, 4011 - CHAR, 2866 - CHAR];
    let flags = data.first().copied().unwrap_or(0);
    let rest = data.get(1..).unwrap_or(&[]);
    let mut records = Vec::new();
    if flags & 2 == 0 {
        for c in rest.chunks_exact(2) {
            let dt = if c[1] == 255 {
                100_000
            } else {
                u64::from(c[1]) * 20
            };
            records.push((c[0], dt));
        }
    } else {
        let mut pending = 0;
        let mut i = 0;
        while let Some(&header) = rest.get(i) {
            let n = usize::from(header & 0x1F);
            let frame = rest.get(i + 1..).unwrap_or(&[]);
            for (k, b) in frame.iter().take(n).enumerate() {
                records.push((*b, if k == 0 { pending + CHAR } else { CHAR }));
            }
            pending = SILENCE[usize::from(header >> 5)];
            i += 1 + n;
        }
    }
    (records, flags & 1 != 0)
}
