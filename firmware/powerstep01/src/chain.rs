//! The daisy chain: one owner schedules every byte (AN4290 §2).
//!
//! # What this module guarantees
//!
//! * **Framing.** Every CS-low window carries exactly one byte per device. The
//!   first byte clocked out reaches the device farthest from the MCU (device
//!   N−1), the last byte reaches device 0; received bytes map the same way
//!   (byte j of a window came from device N−1−j).
//! * **Synchronous execution.** Given up to [`MAX_COMMANDS`] commands per
//!   device, the [`Plan`] right-aligns every device's command bytes so that
//!   the last command of every device completes in the same window: devices
//!   with less to send get leading NOPs, never trailing ones, so all axes
//!   start in the same CS rise. A device's leading read (its first
//!   command, if it reads) goes in window 0 instead: it needs no sync, and
//!   its response then overlaps the others' commands.
//! * **Window budget.** A [`Batch`] given a budget
//!   ([`Batch::set_window_budget`]) refuses a command that would make its
//!   plan longer (`TooManyWindows`): what a control tick's period holds.
//! * **No NOP mid-argument.** A device's commands are laid out back to back,
//!   so no filler byte ever lands inside another command's argument bytes.
//! * **Responses.** A GetParam/GetStatus response comes out in the windows
//!   after its command byte, MSB first. A second response-producing command
//!   for the same device is delayed (NOP padding) until the first response
//!   has been clocked out completely, because the chip would abandon it.
//!   Non-response commands (e.g. the argument bytes of Run) overlap a pending
//!   response freely — that is how position read-back costs no extra window.
//! * **Recovery.** If the bus fails inside a batch the chain is marked out of
//!   step; the next call first clocks three NOP windows, which finish any
//!   half-received command. What the chips must do next (the axes set every
//!   chip up again, starting with HardHiZ) is decided above this layer; the
//!   chain reads no STATUS on its own, so no latched flag is lost.
//!
//! Assumptions: a batch completes every command it starts, and the bus
//! driver raises CS for ≥ 800 ns (t_disCS) between windows.

use heapless::Vec;

use super::commands::{opcode, Command, Direction, SPEED_MAX};
use super::registers::Register;
use super::status::Status;

/// Longest supported chain (the product rules (`docs/PRODUCT.md`): 1 ≤ N ≤ 8).
pub const MAX_DEVICES: usize = 8;
/// Commands one device may get in one batch.
pub const MAX_COMMANDS: usize = 3;
/// Windows one batch may take (3 commands of 4 bytes plus response padding).
pub const MAX_WINDOWS: usize = 16;

/// CS windows of a streaming tick's batch (a read and a Run per device).
pub const STREAM_WINDOWS: usize = 5;

/// Bytes of one batch, window by window (only the first N of each row are sent).
pub type Frames = [[u8; MAX_DEVICES]; MAX_WINDOWS];

/// The chip-select/SPI transfer the chain runs on. The firmware implements it
/// on SPI1 + a CS GPIO; the simulator implements it on a model chain.
pub trait ChainBus {
    /// (Clone: a bridge on a simulated chain can be cloned, e.g. by the
    /// fuzz targets, which start every input from one configured bridge.)
    type Error: Clone;
    /// One CS-low window: shift out `tx` (`tx[0]` first), store what comes
    /// back in `rx` (same length), then raise CS for at least 800 ns.
    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), Self::Error>;
}

/// A chain driver that clocks a plan's windows on its own (by DMA) reports
/// its batch to the next control tick as this: the contract between such a
/// driver and the control tick that plans and absorbs its batches.
#[derive(Debug)]
pub enum BatchState<'a, E> {
    /// No batch started since the last one was handed over (or none ever).
    Idle,
    /// The windows are still going out.
    Running,
    /// Over: what came back (row w = window w's N bytes), or the bus error
    /// that ended it.
    Done(Result<&'a Frames, E>),
}

impl Lay {
    /// The layout with `cmd` appended, and where `cmd` goes: window 0 for
    /// the leading read, else its position in the rest's stream.
    // Every value ≤ 3 · (4 + 3) + 3: a device holds at most MAX_COMMANDS.
    #[allow(clippy::arithmetic_side_effects)]
    fn with(self, cmd: Command) -> (Lay, u8) {
        let resp = cmd.response_len();
        let mut lay = Lay {
            count: self.count + 1,
            ..self
        };
        if self.count == 0 && resp > 0 {
            lay.head = resp;
            return (lay, 0);
        }
        // A second response waits until the one before it is out (the
        // chip would abandon it); other bytes overlap a response.
        let mut pos = self.len;
        if resp > 0 && pos < self.free_at {
            pos = self.free_at;
        }
        lay.len = pos + cmd.wire_len();
        if resp > 0 {
            if lay.first_read == u8::MAX {
                lay.first_read = pos;
            }
            lay.free_at = pos + resp;
            lay.end = lay.end.max(pos + 1 + resp);
        }
        (lay, pos)
    }

    const NEW: Lay = Lay {
        count: 0,
        head: 0,
        len: 0,
        end: 0,
        free_at: 0,
        first_read: u8::MAX,
    };

    /// The device has commands after its leading read: it is aligned on
    /// the sync window.
    fn aligned(&self) -> bool {
        self.len > 0
    }

    /// The window after the leading read's response.
    fn head_end(&self) -> u8 {
        if self.head > 0 {
            self.head.saturating_add(1)
        } else {
            0
        }
    }

    /// The earliest window the rest may start in: after the leading
    /// read's command byte, and its first response not before the leading
    /// read's is out.
    fn min_start(&self) -> u8 {
        if self.head == 0 {
            return 0;
        }
        let after_read = self.head.saturating_sub(self.first_read);
        after_read.max(1)
    }

    /// Windows the rest's responses take past its last byte.
    fn tail(&self) -> u8 {
        self.end.max(self.len).saturating_sub(self.len)
    }
}

/// Why a batch cannot be scheduled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScheduleError {
    /// Device index ≥ chain length.
    NoSuchDevice(u8),
    /// More than [`MAX_COMMANDS`] commands for one device.
    TooManyCommands,
    /// The layout would need more than [`MAX_WINDOWS`] windows.
    TooManyWindows,
}

/// Why a chain operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ChainError<E> {
    /// The SPI transfer failed; the chain is marked out of step.
    Bus(E),
    Schedule(ScheduleError),
    /// No chain detected yet (call [`Chain::detect`]).
    NotDetected,
    /// The detection pattern never came back: broken wiring or a dead device.
    NoEcho,
    /// MISO is wired straight to MOSI: zero devices.
    Empty,
}

/// Commands for one batch, per device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Batch {
    n: u8,
    cmds: [Vec<Command, MAX_COMMANDS>; MAX_DEVICES],
    /// The most windows the batch may take ([`Batch::set_window_budget`]).
    budget: u8,
    /// What the layout gives each device so far, and the batch's windows.
    lay: [Lay; MAX_DEVICES],
    span: Span,
}

/// A device's commands as [`Plan::schedule`] lays them out, in windows:
/// a leading read (the first command, if it reads) in window 0, the rest
/// as one stream right-aligned on the batch's sync window. Built one
/// command at a time ([`Lay::with`]); the plan and the window budget use
/// the same rule.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Lay {
    /// Commands so far.
    count: u8,
    /// Response bytes of the leading read (0: none).
    head: u8,
    /// The rest's stream: its length, the end of its last response (both
    /// relative to its start), where its next response may start, and
    /// where its first response starts (`u8::MAX`: none).
    len: u8,
    end: u8,
    free_at: u8,
    first_read: u8,
}

/// The batch's windows, from running maxima over its devices (each only
/// grows, so the count is never below the plan's): the latest end of an
/// aligned stream (the sync window + 1), the longest response tail past
/// one, the last response of a leading read.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Span {
    sync: u8,
    tail: u8,
    reads_end: u8,
}

impl Span {
    fn windows(&self) -> u8 {
        self.sync.saturating_add(self.tail).max(self.reads_end)
    }

    /// With `lay`'s device in it.
    fn with(self, lay: &Lay) -> Span {
        let mut span = Span {
            reads_end: self.reads_end.max(lay.head_end()),
            ..self
        };
        if lay.aligned() {
            span.sync = span.sync.max(lay.min_start().saturating_add(lay.len));
            span.tail = span.tail.max(lay.tail());
        }
        span
    }
}

impl Batch {
    /// An empty batch for a chain of `n` devices (clamped to [`MAX_DEVICES`]).
    pub fn new(n: usize) -> Batch {
        Batch {
            n: n.min(MAX_DEVICES) as u8,
            cmds: Default::default(),
            budget: MAX_WINDOWS as u8,
            lay: [Lay::NEW; MAX_DEVICES],
            span: Span::default(),
        }
    }

    /// At most `windows` CS windows (at least the 5 of a read and a Run,
    /// at most [`MAX_WINDOWS`]): a command that would make the batch
    /// longer is refused with [`ScheduleError::TooManyWindows`] (the
    /// caller sends it in a later batch). A batch's windows are what a
    /// control tick's period can hold on a long chain. Kept by
    /// [`Batch::reset`].
    pub fn set_window_budget(&mut self, windows: usize) {
        self.budget = windows.clamp(STREAM_WINDOWS, MAX_WINDOWS) as u8;
    }

    /// The windows [`Plan::schedule`] gives this batch, or more (an
    /// upper bound from running maxima), for a batch with a window budget
    /// below [`MAX_WINDOWS`] (`None`: not kept).
    pub fn windows_at_most(&self) -> Option<usize> {
        (self.budget < MAX_WINDOWS as u8).then_some(usize::from(self.span.windows()))
    }

    /// The same command for every device.
    pub fn all(n: usize, cmd: Command) -> Batch {
        let mut b = Batch::new(n);
        for d in 0..usize::from(b.n) {
            // One command per device: within every budget, cannot fail.
            let _ = b.push(d, cmd);
        }
        b
    }

    pub fn len(&self) -> usize {
        usize::from(self.n)
    }

    pub fn is_empty(&self) -> bool {
        self.cmds.iter().all(|c| c.is_empty())
    }

    /// Append a command for `device` (if the batch stays within its
    /// window budget).
    #[inline]
    pub fn push(&mut self, device: usize, cmd: Command) -> Result<(), ScheduleError> {
        if device >= usize::from(self.n) {
            return Err(ScheduleError::NoSuchDevice(device.min(255) as u8));
        }
        // Only a batch with a budget below what the layout allows anyway
        // keeps its span (the streaming tick at 1 kHz pays nothing).
        if self.budget < MAX_WINDOWS as u8 {
            return self.push_within_budget(device, cmd);
        }
        self.cmds
            .get_mut(device)
            .ok_or(ScheduleError::NoSuchDevice(device.min(255) as u8))?
            .push(cmd)
            .map_err(|_| ScheduleError::TooManyCommands)
    }

    /// [`Batch::push`] for a batch with a window budget.
    fn push_within_budget(&mut self, device: usize, cmd: Command) -> Result<(), ScheduleError> {
        let (Some(list), Some(lay)) = (self.cmds.get_mut(device), self.lay.get_mut(device)) else {
            return Err(ScheduleError::NoSuchDevice(device.min(255) as u8));
        };
        if list.is_full() {
            return Err(ScheduleError::TooManyCommands);
        }
        let resp = cmd.response_len();
        if lay.count == 0 && resp > 0 {
            // A leading read: window 0 and its response, at most 4 windows
            // of a budget of at least 5 (the control tick's every batch).
            lay.count = 1;
            lay.head = resp;
            self.span.reads_end = self.span.reads_end.max(resp.saturating_add(1));
            return list.push(cmd).map_err(|_| ScheduleError::TooManyCommands);
        }
        if lay.count == 1 && lay.head > 0 && resp == 0 && self.span.tail == 0 {
            // A write after the leading read (the streaming tick's Run):
            // windows 1 to 4, so the batch stays at most 5 windows long
            // while no stream ends in a response.
            let k = cmd.wire_len();
            lay.count = 2;
            lay.len = k;
            self.span.sync = self.span.sync.max(k.saturating_add(1));
            return list.push(cmd).map_err(|_| ScheduleError::TooManyCommands);
        }
        let (new, _) = lay.with(cmd);
        let span = self.span.with(&new);
        if span.windows() > self.budget {
            return Err(ScheduleError::TooManyWindows);
        }
        *lay = new;
        self.span = span;
        list.push(cmd).map_err(|_| ScheduleError::TooManyCommands)
    }

    /// Commands queued for `device`.
    pub fn commands(&self, device: usize) -> &[Command] {
        self.cmds.get(device).map(|v| v.as_slice()).unwrap_or(&[])
    }

    pub fn clear(&mut self) {
        for c in self.cmds.iter_mut() {
            c.clear();
        }
        if self.budget < MAX_WINDOWS as u8 {
            self.lay = [Lay::NEW; MAX_DEVICES];
            self.span = Span::default();
        }
    }

    /// Empty the batch and make it one for `n` devices (clamped to [`MAX_DEVICES`]).
    pub fn reset(&mut self, n: usize) {
        self.clear();
        self.n = n.min(MAX_DEVICES) as u8;
    }
}

/// Where a response will come out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct ReadSlot {
    device: u8,
    index: u8,
    first_window: u8,
    len: u8,
    command: Command,
}

/// The read of a streaming tick's batch ([`Plan::stream_put`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StreamRead {
    /// GetStatus.
    Status,
    /// GetParam of a register (every register is 1 to 3 bytes).
    Param(Register),
}

impl StreamRead {
    /// The read as a command.
    pub const fn command(self) -> Command {
        match self {
            StreamRead::Status => Command::GetStatus,
            StreamRead::Param(r) => Command::GetParam(r),
        }
    }
}

/// A scheduled batch: the bytes of every window and where replies come out.
///
/// A plan can be refilled in place ([`Plan::schedule`]) so the control tick
/// builds it without copying.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Plan {
    n: u8,
    windows: u8,
    /// Window in which every device's last command completes.
    sync_window: u8,
    tx: Frames,
    reads: Vec<ReadSlot, { MAX_DEVICES * MAX_COMMANDS }>,
    /// A plan written by [`Plan::stream_put`]: the longest command after a
    /// read so far (bytes).
    stream_len: u8,
}

impl Default for Plan {
    fn default() -> Plan {
        Plan {
            n: 0,
            windows: 0,
            sync_window: 0,
            tx: [[0; MAX_DEVICES]; MAX_WINDOWS],
            reads: Vec::new(),
            stream_len: 0,
        }
    }
}

impl Plan {
    /// Schedule `batch` (see the module docs for the rules).
    pub fn new(batch: &Batch) -> Result<Plan, ScheduleError> {
        let mut plan = Plan::default();
        plan.schedule(batch)?;
        Ok(plan)
    }

    /// Refill this plan with `batch`. On error the plan is left empty.
    ///
    /// Every device's commands are first laid out in a stream of its own
    /// (command bytes back to back, NOP padding before a second response;
    /// a leading read apart, in window 0), then the streams are
    /// right-aligned on the longest one and transposed into windows. The control tick runs this every tick: each command is
    /// encoded once and every index is bounded by a constant array length;
    /// its common batch, a read and a Run per device, is laid out directly
    /// (the same plan).
    pub fn schedule(&mut self, batch: &Batch) -> Result<(), ScheduleError> {
        if self.schedule_streaming(batch) {
            return Ok(());
        }
        self.schedule_general(batch)
    }

    /// [`Plan::schedule`] for any batch (the layout the module docs give).
    // Positions are bounded by the constants before any sum: a device's
    // layout is at most MAX_COMMANDS commands of ≤ 4 bytes and ≤ 3
    // response bytes, and the windows are checked against MAX_WINDOWS
    // before any byte is placed.
    #[allow(clippy::arithmetic_side_effects)]
    fn schedule_general(&mut self, batch: &Batch) -> Result<(), ScheduleError> {
        let n = usize::from(batch.n).min(MAX_DEVICES);
        self.n = n as u8;
        self.windows = 0;
        self.sync_window = 0;
        self.reads.clear();
        let mut lays = [Lay::NEW; MAX_DEVICES];
        let mut span = Span::default();
        for (lay, cmds) in lays.iter_mut().zip(batch.cmds.iter()).take(n) {
            for cmd in cmds {
                *lay = lay.with(*cmd).0;
            }
            span = span.with(lay);
        }
        // The running maxima are exact over whole devices.
        let windows = usize::from(span.windows());
        if windows > MAX_WINDOWS {
            return Err(self.too_many_windows());
        }
        self.windows = windows as u8;
        self.sync_window = span.sync.saturating_sub(1);
        for row in self.tx.iter_mut() {
            *row = [0; MAX_DEVICES];
        }
        for (d, (lay, cmds)) in lays.iter().zip(batch.cmds.iter()).enumerate().take(n) {
            // The rest starts where it ends on the sync window.
            let off = span.sync.saturating_sub(lay.len);
            let mut at = Lay::NEW;
            for (index, cmd) in cmds.iter().enumerate() {
                let (next, pos) = at.with(*cmd);
                let start = if at.count == 0 && next.head > 0 {
                    0
                } else {
                    usize::from(off + pos)
                };
                at = next;
                self.place(d, n, start, *cmd);
                let resp = cmd.response_len();
                if resp > 0 {
                    let _ = self.reads.push(ReadSlot {
                        device: d as u8,
                        index: index as u8,
                        first_window: (start + 1) as u8,
                        len: resp,
                        command: *cmd,
                    });
                }
            }
        }
        Ok(())
    }

    /// A batch that does not fit: the plan is left empty (no devices, no
    /// read slots).
    fn too_many_windows(&mut self) -> ScheduleError {
        self.n = 0;
        self.windows = 0;
        self.reads.clear();
        ScheduleError::TooManyWindows
    }

    /// `cmd`'s bytes for device `d` of `n` from window `start` on (the
    /// last device of the chain first in each window).
    fn place(&mut self, d: usize, n: usize, start: usize, cmd: Command) {
        let col = n.saturating_sub(1).saturating_sub(d);
        let (bytes, k) = cmd.encode().raw();
        for (row, b) in self.tx.iter_mut().skip(start).zip(bytes).take(k) {
            if let Some(cell) = row.get_mut(col) {
                *cell = b;
            }
        }
    }

    /// The streaming tick's batch, laid out directly: every device a read
    /// (GetStatus, or GetParam of a register of 1 to 3 bytes) then a Run.
    /// The general layout gives it 5 windows, every stream starting in
    /// window 0 (the read's response comes out while Run's argument bytes
    /// go in), the read's reply from window 1: this writes that plan
    /// straight away (the control tick's common case; a test compares it
    /// with the general layout). False, with the plan untouched, for any
    /// other batch.
    // Indices are d < n ≤ MAX_DEVICES and windows 0..5 of MAX_WINDOWS.
    #[allow(clippy::arithmetic_side_effects)]
    fn schedule_streaming(&mut self, batch: &Batch) -> bool {
        let n = usize::from(batch.n).min(MAX_DEVICES);
        let Some(all) = batch.cmds.get(..n) else {
            return false;
        };
        let streaming = |cmds: &Vec<Command, MAX_COMMANDS>| match cmds.as_slice() {
            [read @ (Command::GetStatus | Command::GetParam(_)), Command::Run(..)] => {
                (1..=3).contains(&read.response_len())
            }
            _ => false,
        };
        if n == 0 || !all.iter().all(streaming) {
            return false;
        }
        self.n = n as u8;
        self.windows = STREAM_WINDOWS as u8;
        self.sync_window = STREAM_WINDOWS as u8 - 1;
        self.reads.clear();
        let Some(rows) = self.tx.get_mut(..STREAM_WINDOWS) else {
            return false;
        };
        for row in rows.iter_mut() {
            *row = [0; MAX_DEVICES];
        }
        for (d, cmds) in all.iter().enumerate() {
            let col = n - 1 - d;
            for (index, cmd) in cmds.iter().enumerate() {
                let (bytes, k) = cmd.encode().raw();
                for (row, b) in rows.iter_mut().skip(index).zip(bytes).take(k) {
                    if let Some(cell) = row.get_mut(col) {
                        *cell = b;
                    }
                }
            }
            if let Some(read) = cmds.first() {
                let _ = self.reads.push(ReadSlot {
                    device: d as u8,
                    index: 0,
                    first_window: 1,
                    len: read.response_len(),
                    command: *read,
                });
            }
        }
        true
    }

    /// The streaming tick's plan written one device at a time, without a
    /// [`Batch`]: this for a chain of `n` devices (1 to [`MAX_DEVICES`];
    /// false, and the plan untouched, for any other `n`), then
    /// [`Plan::stream_put`] for every device, then [`Plan::stream_end`].
    /// The result is the plan [`Plan::schedule`] makes of a batch of a read
    /// and at most one command without a response per device (a test
    /// compares the two).
    pub fn stream_begin(&mut self, n: usize) -> bool {
        if n == 0 || n > MAX_DEVICES {
            return false;
        }
        self.n = n as u8;
        self.windows = STREAM_WINDOWS as u8;
        self.sync_window = (STREAM_WINDOWS as u8).saturating_sub(1);
        self.stream_len = 0;
        self.reads.clear();
        for row in self.tx.iter_mut().take(STREAM_WINDOWS) {
            *row = [0; MAX_DEVICES];
        }
        true
    }

    /// Device `device`'s read (window 0, its reply from window 1) and the
    /// command after it (none: the device only reads), in a plan begun by
    /// [`Plan::stream_begin`]. The command, of 1 to 4 bytes, ends in window
    /// 4 ([`Plan::stream_end`] moves every command up if none is 4 bytes
    /// long, as the general layout does); a command with a response is
    /// refused (`TooManyCommands`: this layout has no room for it).
    // Indices: device < n ≤ MAX_DEVICES (checked); rows 1..5 of MAX_WINDOWS,
    // from 5 − k for a command of k ≤ 4 bytes.
    #[allow(clippy::arithmetic_side_effects)]
    pub fn stream_put(
        &mut self,
        device: usize,
        read: StreamRead,
        cmd: Option<Command>,
    ) -> Result<(), ScheduleError> {
        if cmd.is_some_and(|c| c.response_len() > 0) {
            return Err(ScheduleError::TooManyCommands);
        }
        let col = self.put_read(device, read)?;
        if let Some(Command::Run(dir, speed)) = cmd {
            self.put_run(col, dir, speed);
        } else if let Some(c) = cmd {
            let (bytes, k) = c.encode().raw();
            let k = k.min(STREAM_WINDOWS - 1);
            let rows = self.tx.iter_mut().skip(STREAM_WINDOWS - k).take(k);
            for (row, b) in rows.zip(bytes) {
                if let Some(cell) = row.get_mut(col) {
                    *cell = b;
                }
            }
            self.stream_len = self.stream_len.max(k as u8);
        }
        Ok(())
    }

    /// [`Plan::stream_put`] of a read and a Run (the streaming tick's
    /// every tick, its bytes written straight).
    #[inline]
    pub fn stream_put_run(
        &mut self,
        device: usize,
        read: StreamRead,
        dir: Direction,
        speed: u32,
    ) -> Result<(), ScheduleError> {
        let col = self.put_read(device, read)?;
        self.put_run(col, dir, speed);
        Ok(())
    }

    /// Device `device`'s read in window 0 of a streaming plan (its reply
    /// from window 1); its column.
    // Indices: device < n ≤ MAX_DEVICES (checked).
    #[allow(clippy::arithmetic_side_effects)]
    #[inline]
    fn put_read(&mut self, device: usize, read: StreamRead) -> Result<usize, ScheduleError> {
        let n = usize::from(self.n);
        if device >= n {
            return Err(ScheduleError::NoSuchDevice(device.min(255) as u8));
        }
        let col = n - 1 - device;
        if let Some(cell) = self.tx.first_mut().and_then(|row| row.get_mut(col)) {
            *cell = match read {
                StreamRead::Status => opcode::GET_STATUS,
                StreamRead::Param(r) => opcode::GET_PARAM | r.address(),
            };
        }
        let command = read.command();
        self.reads
            .push(ReadSlot {
                device: device as u8,
                index: 0,
                first_window: 1,
                len: command.response_len(),
                command,
            })
            .map_err(|_| ScheduleError::TooManyCommands)?;
        Ok(col)
    }

    /// A Run's bytes in column `col`, windows 1 to 4.
    #[inline]
    fn put_run(&mut self, col: usize, dir: Direction, speed: u32) {
        let s = speed.min(SPEED_MAX).to_be_bytes();
        let [_, r1, r2, r3, r4, ..] = &mut self.tx;
        for (row, b) in [
            (r1, opcode::RUN | dir.bit()),
            (r2, s[1]),
            (r3, s[2]),
            (r4, s[3]),
        ] {
            if let Some(cell) = row.get_mut(col) {
                *cell = b;
            }
        }
        self.stream_len = (STREAM_WINDOWS as u8).saturating_sub(1);
    }

    /// The end of a plan written by [`Plan::stream_put`]: the commands
    /// end in the window after the longest one (window 4 if one is 4
    /// bytes long), and the plan is as long as that or the reads' replies.
    // stream_len ≤ 4 (stream_put), rows 1..5.
    #[allow(clippy::arithmetic_side_effects)]
    pub fn stream_end(&mut self) {
        let m = usize::from(self.stream_len).min(STREAM_WINDOWS - 1);
        let shift = STREAM_WINDOWS - 1 - m;
        if shift > 0 {
            // Rows 1 + shift..5 move to 1..5 − shift; the rest is NOPs.
            for r in 1..STREAM_WINDOWS {
                let from = self
                    .tx
                    .get(r + shift)
                    .copied()
                    .filter(|_| r + shift < STREAM_WINDOWS);
                if let Some(row) = self.tx.get_mut(r) {
                    *row = from.unwrap_or([0; MAX_DEVICES]);
                }
            }
        }
        let reads_end = self
            .reads
            .iter()
            .map(|r| r.len.saturating_add(1))
            .max()
            .unwrap_or(0);
        let sync = if m > 0 { m as u8 + 1 } else { 0 };
        self.windows = reads_end.max(sync);
        self.sync_window = sync.saturating_sub(1);
    }

    /// Chain length this plan was made for.
    pub fn devices(&self) -> usize {
        usize::from(self.n)
    }

    /// Number of CS windows.
    pub fn windows(&self) -> usize {
        usize::from(self.windows)
    }

    /// Index of the window in which every device's last command completes.
    pub fn sync_window(&self) -> usize {
        usize::from(self.sync_window)
    }

    /// Total bytes clocked (windows × devices).
    pub fn bytes(&self) -> usize {
        // Both at most MAX_WINDOWS / MAX_DEVICES.
        self.windows().saturating_mul(self.devices())
    }

    /// The bytes of window `w` (N bytes, first one out first), if it exists.
    pub fn window(&self, w: usize) -> Option<&[u8]> {
        if w >= self.windows() {
            return None;
        }
        self.tx.get(w).and_then(|row| row.get(..self.devices()))
    }

    /// Every window as a whole row (a DMA driver copies rows): only the
    /// first [`Plan::devices`] bytes of the first [`Plan::windows`] rows
    /// are sent ([`Plan::window`] is that part).
    pub fn frames(&self) -> &Frames {
        &self.tx
    }

    /// Decode what came back.
    pub fn decode(&self, rx: &Frames) -> Replies {
        let mut replies = Replies::default();
        self.decode_into(rx, &mut replies);
        replies
    }

    /// Decode what came back into `replies` (cleared first).
    pub fn decode_into(&self, rx: &Frames, replies: &mut Replies) {
        replies.items = [[None; MAX_COMMANDS]; MAX_DEVICES];
        let n = self.devices();
        for r in self.reads.iter() {
            let Some(slot) = n.checked_sub(1 + usize::from(r.device)) else {
                continue;
            };
            // MSB first; every response is 1 to 3 bytes (windows past the
            // last read as 0).
            let first = usize::from(r.first_window);
            let rows = rx.get(first..).unwrap_or(&[]);
            let at = |k: usize| {
                rows.get(k)
                    .and_then(|w| w.get(slot))
                    .map_or(0, |b| u32::from(*b))
            };
            let value = match r.len {
                0 => 0,
                1 => at(0),
                2 => (at(0) << 8) | at(1),
                _ => (at(0) << 16) | (at(1) << 8) | at(2),
            };
            let reply = match r.command {
                Command::GetStatus => Reply::Status(Status(value as u16)),
                Command::GetParam(reg) => Reply::Param(reg, value & reg.mask()),
                _ => continue,
            };
            if let Some(cell) = replies
                .items
                .get_mut(usize::from(r.device))
                .and_then(|d| d.get_mut(usize::from(r.index)))
            {
                *cell = Some(reply);
            }
        }
    }
}

/// A decoded response.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reply {
    /// GetStatus (flags were cleared by the read).
    Status(Status),
    /// GetParam: raw register value, masked to the register width.
    Param(Register, u32),
}

/// All responses of one batch, per device and command index.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Replies {
    items: [[Option<Reply>; MAX_COMMANDS]; MAX_DEVICES],
}

impl Replies {
    /// Reply to the `index`-th command of `device`.
    pub fn get(&self, device: usize, index: usize) -> Option<Reply> {
        self.items.get(device)?.get(index).copied().flatten()
    }

    /// The STATUS read by GetStatus (or GetParam(STATUS)) for `device`.
    pub fn status(&self, device: usize) -> Option<Status> {
        self.items
            .get(device)?
            .iter()
            .flatten()
            .find_map(|r| match r {
                Reply::Status(s) => Some(*s),
                Reply::Param(Register::Status, v) => Some(Status(*v as u16)),
                _ => None,
            })
    }

    /// The value read by GetParam(`reg`) for `device`.
    pub fn param(&self, device: usize, reg: Register) -> Option<u32> {
        self.items
            .get(device)?
            .iter()
            .flatten()
            .find_map(|r| match r {
                Reply::Param(rr, v) if *rr == reg => Some(*v),
                _ => None,
            })
    }
}

/// Bytes shifted through the chain to measure its length: distinct, and each
/// a harmless command (GetParam of an existing register) for whichever
/// device ends up holding it.
const DETECT_LEN: usize = 2 * MAX_DEVICES;
// Evaluated at compile time (`DETECT`): an out-of-range index fails the build.
#[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
const fn detect_pattern() -> [u8; DETECT_LEN] {
    let mut p = [0u8; DETECT_LEN];
    let mut i = 0;
    while i < DETECT_LEN {
        p[i] = 0x20 | (i as u8 + 1);
        i += 1;
    }
    p
}

/// Find the chain length from one detection window: the smallest `n` such
/// that what came back is the pattern delayed by `n` bytes. With distinct
/// pattern bytes at most one `n` can match.
pub fn length_from_echo(tx: &[u8], rx: &[u8]) -> Option<usize> {
    (0..=MAX_DEVICES).find(
        |&n| match (rx.get(n..), tx.get(..tx.len().saturating_sub(n))) {
            (Some(a), Some(b)) => !a.is_empty() && a == b,
            _ => false,
        },
    )
}

/// The one owner of the chain.
#[derive(Clone)]
pub struct Chain<B: ChainBus> {
    bus: B,
    n: u8,
    out_of_step: bool,
}

impl<B: ChainBus> core::fmt::Debug for Chain<B> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Chain")
            .field("devices", &self.n)
            .field("out_of_step", &self.out_of_step)
            .finish_non_exhaustive()
    }
}

impl<B: ChainBus> Chain<B> {
    pub const fn new(bus: B) -> Chain<B> {
        Chain {
            bus,
            n: 0,
            out_of_step: false,
        }
    }

    /// Detected chain length (0 before detection).
    pub fn len(&self) -> usize {
        usize::from(self.n)
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    pub fn bus(&self) -> &B {
        &self.bus
    }

    pub fn bus_mut(&mut self) -> &mut B {
        &mut self.bus
    }

    /// True after a bus failure until the next successful resynchronisation.
    pub fn out_of_step(&self) -> bool {
        self.out_of_step
    }

    /// Measure the chain length: three NOP windows (finish any half-received
    /// command), then one window of `DETECT_LEN` (16) distinct bytes; the offset at
    /// which they come back is N. The caller should have pulsed STBY/RESET.
    pub fn detect(&mut self) -> Result<usize, ChainError<B::Error>> {
        let nops = [0u8; DETECT_LEN];
        let mut rx = [0u8; DETECT_LEN];
        for _ in 0..3 {
            self.bus.window(&nops, &mut rx).map_err(ChainError::Bus)?;
        }
        let tx = detect_pattern();
        self.bus.window(&tx, &mut rx).map_err(ChainError::Bus)?;
        let n = length_from_echo(&tx, &rx).ok_or(ChainError::NoEcho)?;
        if n == 0 {
            return Err(ChainError::Empty);
        }
        self.n = n as u8;
        self.out_of_step = false;
        Ok(n)
    }

    /// Clock the windows of a plan made for this chain.
    pub fn run(&mut self, plan: &Plan) -> Result<Replies, ChainError<B::Error>> {
        let mut replies = Replies::default();
        self.run_into(plan, &mut replies)?;
        Ok(replies)
    }

    /// Clock the windows of a plan and decode the replies into `replies`.
    ///
    /// The same as [`Chain::begin`], every window through the blocking
    /// [`ChainBus::window`], then [`Chain::end`]: a driver that clocks the
    /// windows itself (by DMA) calls those two around its transfer.
    pub fn run_into(
        &mut self,
        plan: &Plan,
        replies: &mut Replies,
    ) -> Result<(), ChainError<B::Error>> {
        self.begin(plan)?;
        let mut rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];
        let result = self.clock(plan, &mut rx);
        self.end(plan, result.map(|()| &rx), replies)
    }

    /// Clock a plan's windows through the blocking [`ChainBus::window`]
    /// (between [`Chain::begin`] and [`Chain::end`]); row `w` of `rx` gets
    /// window `w`'s N bytes. Stops at the first bus error.
    pub fn clock(&mut self, plan: &Plan, rx: &mut Frames) -> Result<(), B::Error> {
        clock_windows(&mut self.bus, plan, usize::from(self.n), rx)
    }

    /// Before a plan's windows go out: the plan must fit this chain, and a
    /// chain out of step is brought back first (three NOP windows through
    /// the blocking [`ChainBus::window`]).
    pub fn begin(&mut self, plan: &Plan) -> Result<(), ChainError<B::Error>> {
        if self.n == 0 {
            return Err(ChainError::NotDetected);
        }
        if plan.devices() != self.len() {
            return Err(ChainError::Schedule(ScheduleError::NoSuchDevice(plan.n)));
        }
        if self.out_of_step {
            self.resync()?;
        }
        Ok(())
    }

    /// After a plan's windows: `rx` holds what came back, window by window
    /// (the first N bytes of each row), or the bus error that cut the
    /// transfer short — then the chain is out of step until the next
    /// [`Chain::begin`] resyncs it.
    pub fn end(
        &mut self,
        plan: &Plan,
        rx: Result<&Frames, B::Error>,
        replies: &mut Replies,
    ) -> Result<(), ChainError<B::Error>> {
        self.ended(rx).map(|rx| plan.decode_into(rx, replies))
    }

    /// [`Chain::end`] without the decoding: what came back, or the bus
    /// error (the chain is then out of step).
    pub fn ended<'a>(
        &mut self,
        rx: Result<&'a Frames, B::Error>,
    ) -> Result<&'a Frames, ChainError<B::Error>> {
        rx.map_err(|e| {
            self.out_of_step = true;
            ChainError::Bus(e)
        })
    }

    /// Schedule and run a batch.
    pub fn execute(&mut self, batch: &Batch) -> Result<Replies, ChainError<B::Error>> {
        if self.n == 0 {
            return Err(ChainError::NotDetected);
        }
        if batch.len() != self.len() {
            return Err(ChainError::Schedule(ScheduleError::NoSuchDevice(batch.n)));
        }
        let plan = Plan::new(batch).map_err(ChainError::Schedule)?;
        self.run(&plan)
    }

    /// Read STATUS of every device with GetStatus (3 windows; clears latched flags).
    pub fn poll_status(&mut self) -> Result<Replies, ChainError<B::Error>> {
        self.execute(&Batch::all(self.len(), Command::GetStatus))
    }

    /// Bring the chain back in step after a failed transfer: three NOP
    /// windows finish any half-received command (module docs).
    pub fn resync(&mut self) -> Result<(), ChainError<B::Error>> {
        let n = self.len();
        let nops = [0u8; MAX_DEVICES];
        let mut rx = [0u8; MAX_DEVICES];
        let (Some(tx), Some(rx)) = (nops.get(..n), rx.get_mut(..n)) else {
            return Err(ChainError::NotDetected);
        };
        for _ in 0..3 {
            self.bus.window(tx, rx).map_err(ChainError::Bus)?;
        }
        self.out_of_step = false;
        Ok(())
    }
}

/// Clock `plan`'s windows through `bus`'s blocking window, the first `n`
/// bytes of each (the chain's length): row `w` of `rx` gets window `w`'s
/// reply. Stops at the first bus error. ([`Chain::clock`]; the QEMU image's
/// chain driver clocks its batches through the simulated chips with it.)
pub fn clock_windows<B: ChainBus>(
    bus: &mut B,
    plan: &Plan,
    n: usize,
    rx: &mut Frames,
) -> Result<(), B::Error> {
    for (tx, rx) in plan.tx.iter().zip(rx.iter_mut()).take(plan.windows()) {
        let (Some(tx), Some(rx)) = (tx.get(..n), rx.get_mut(..n)) else {
            break;
        };
        bus.window(tx, rx)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::commands::Direction;

    #[test]
    fn status_poll_of_n_devices_takes_three_windows() {
        for n in 1..=MAX_DEVICES {
            let plan = Plan::new(&Batch::all(n, Command::GetStatus)).unwrap();
            assert_eq!(plan.windows(), 3, "n = {n}");
            assert_eq!(plan.window(0).unwrap(), &[0xD0; MAX_DEVICES][..n]);
            assert_eq!(plan.window(1).unwrap(), &[0; MAX_DEVICES][..n]);
            assert_eq!(plan.window(2).unwrap(), &[0; MAX_DEVICES][..n]);
            assert_eq!(plan.bytes(), 3 * n);
        }
    }

    #[test]
    fn first_byte_of_a_window_goes_to_the_farthest_device() {
        let mut b = Batch::new(3);
        b.push(0, Command::HardStop).unwrap();
        b.push(2, Command::SoftStop).unwrap();
        let plan = Plan::new(&b).unwrap();
        assert_eq!(plan.windows(), 1);
        assert_eq!(plan.window(0).unwrap(), &[0xB0, 0x00, 0xB8]);
    }

    #[test]
    fn shorter_commands_are_right_aligned_with_leading_nops() {
        let mut b = Batch::new(2);
        b.push(0, Command::Run(Direction::Forward, 0x01_0203))
            .unwrap();
        b.push(1, Command::HardStop).unwrap();
        let plan = Plan::new(&b).unwrap();
        assert_eq!(plan.windows(), 4);
        assert_eq!(plan.sync_window(), 3);
        // slot 0 = device 1, slot 1 = device 0
        assert_eq!(plan.window(0).unwrap(), &[0x00, 0x51]);
        assert_eq!(plan.window(1).unwrap(), &[0x00, 0x01]);
        assert_eq!(plan.window(2).unwrap(), &[0x00, 0x02]);
        assert_eq!(plan.window(3).unwrap(), &[0xB8, 0x03]);
    }

    #[test]
    fn a_device_that_only_reads_starts_in_window_0_and_adds_no_window() {
        let mut b = Batch::new(2);
        b.push(0, Command::Run(Direction::Forward, 5)).unwrap();
        b.push(1, Command::GetParam(Register::AbsPos)).unwrap();
        let plan = Plan::new(&b).unwrap();
        // Run in windows 0..=3; GetParam in window 0, its 3 bytes in 1..=3
        // (right-aligned it would take windows 3..=6).
        assert_eq!(plan.windows(), 4);
        assert_eq!(plan.window(0).unwrap(), &[0x21, 0x51]);
        assert_eq!(plan.window(3).unwrap(), &[0x00, 0x05]);
        let mut rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];
        rx[1][0] = 0x3F;
        rx[2][0] = 0xFF;
        rx[3][0] = 0xFE;
        let replies = plan.decode(&rx);
        assert_eq!(replies.param(1, Register::AbsPos), Some(0x3F_FFFE));
        assert_eq!(replies.param(0, Register::AbsPos), None);
    }

    #[test]
    fn a_read_after_a_write_keeps_the_device_aligned() {
        let mut b = Batch::new(2);
        b.push(0, Command::Run(Direction::Forward, 5)).unwrap();
        b.push(1, Command::HardStop).unwrap();
        b.push(1, Command::GetParam(Register::AbsPos)).unwrap();
        let plan = Plan::new(&b).unwrap();
        // Device 1's stream (HardStop, GetParam) ends with Run's in window
        // 3; the response follows in 4..=6.
        assert_eq!(plan.windows(), 7);
        assert_eq!(plan.sync_window(), 3);
    }

    #[test]
    fn a_command_past_the_window_budget_is_refused_and_the_batch_stays() {
        let mut b = Batch::new(2);
        b.set_window_budget(5);
        b.push(0, Command::GetParam(Register::AbsPos)).unwrap();
        b.push(0, Command::Run(Direction::Forward, 5)).unwrap();
        b.push(1, Command::GetParam(Register::AbsPos)).unwrap();
        assert_eq!(b.push(1, Command::SetParam(Register::MaxSpeed, 10)), Ok(()));
        // A third command would make device 1's stream 8 windows long.
        assert_eq!(
            b.push(1, Command::Run(Direction::Forward, 5)),
            Err(ScheduleError::TooManyWindows)
        );
        assert_eq!(b.commands(1).len(), 2);
        let plan = Plan::new(&b).unwrap();
        assert!(plan.windows() <= 5);
        assert_eq!(Some(plan.windows()), b.windows_at_most());
    }

    #[test]
    fn read_back_overlaps_run_arguments_in_five_windows() {
        let mut b = Batch::new(8);
        for d in 0..8 {
            b.push(d, Command::GetParam(Register::AbsPos)).unwrap();
            b.push(d, Command::Run(Direction::Reverse, 1000)).unwrap();
        }
        let plan = Plan::new(&b).unwrap();
        assert_eq!(plan.windows(), 5);
        assert_eq!(plan.sync_window(), 4);
    }

    #[test]
    fn the_streaming_layout_is_the_general_one() {
        let reads = [
            Command::GetStatus,
            Command::GetParam(Register::AbsPos),
            Command::GetParam(Register::Speed),
            Command::GetParam(Register::Config),
            Command::GetParam(Register::AdcOut),
        ];
        // After the read: commands of 4, 1, 1, 3 and 2 bytes, or none.
        let after = |d: usize, pick: usize| match pick % 7 {
            0 => Some(Command::Run(
                Direction::from_bit(d as u8),
                0x12_3456 + d as u32,
            )),
            1 => Some(Command::SoftStop),
            2 => Some(Command::HardHiZ),
            3 => Some(Command::GoTo(-1000 * d as i32)),
            4 => Some(Command::SetParam(Register::MaxSpeed, 0x41 + d as u32)),
            5 => Some(Command::SetParam(Register::KvalHold, 0x29)),
            _ => None,
        };
        for n in 1..=MAX_DEVICES {
            for k in 0..reads.len() * 49 {
                // Every mix: device d's pick from k's digits.
                let pick = |d: usize| (k / reads.len() + d * (k % 5 + 1) + d * d) % 7;
                let mut b = Batch::new(n);
                for d in 0..n {
                    b.push(d, reads[(k + d) % reads.len()]).unwrap();
                    if let Some(c) = after(d, pick(d)) {
                        b.push(d, c).unwrap();
                    }
                }
                let fast = Plan::new(&b).unwrap();
                let mut slow = Plan::default();
                slow.schedule_general(&b).unwrap();
                assert_eq!(fast, slow, "n = {n}, k = {k}");
                let all_run = (0..n).all(|d| pick(d) == 0);
                assert_eq!(Plan::default().schedule_streaming(&b), all_run);
                // Written a device at a time, without the batch: the same.
                let mut put = Plan::default();
                put.schedule(&Batch::all(3, Command::HardStop)).unwrap();
                assert!(put.stream_begin(n));
                for d in 0..n {
                    let read = match reads[(k + d) % reads.len()] {
                        Command::GetParam(r) => StreamRead::Param(r),
                        _ => StreamRead::Status,
                    };
                    match after(d, pick(d)) {
                        Some(Command::Run(dir, spd)) if k % 2 == 0 => {
                            put.stream_put_run(d, read, dir, spd).unwrap()
                        }
                        cmd => put.stream_put(d, read, cmd).unwrap(),
                    }
                }
                put.stream_end();
                assert_eq!(put.windows(), slow.windows(), "n = {n}, k = {k}");
                assert_eq!(put.sync_window(), slow.sync_window(), "n = {n}, k = {k}");
                for w in 0..slow.windows() {
                    assert_eq!(put.window(w), slow.window(w), "n = {n}, k = {k}, w = {w}");
                }
                let mut rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];
                for (w, row) in rx.iter_mut().enumerate() {
                    for (c, b) in row.iter_mut().enumerate() {
                        *b = (w * 31 + c * 7 + k) as u8;
                    }
                }
                assert_eq!(put.decode(&rx), slow.decode(&rx), "n = {n}, k = {k}");
            }
        }
        // Anything else takes the general layout.
        let mut b = Batch::new(2);
        b.push(0, Command::GetStatus).unwrap();
        b.push(0, Command::Run(Direction::Forward, 5)).unwrap();
        b.push(1, Command::GetStatus).unwrap();
        assert!(!Plan::default().schedule_streaming(&b));
    }

    #[test]
    fn a_streaming_plan_refuses_a_device_past_its_chain_and_a_second_read() {
        let mut plan = Plan::default();
        assert!(!plan.stream_begin(0));
        assert!(!plan.stream_begin(MAX_DEVICES + 1));
        assert!(plan.stream_begin(2));
        assert_eq!(
            plan.stream_put(2, StreamRead::Status, Some(Command::SoftStop)),
            Err(ScheduleError::NoSuchDevice(2))
        );
        // A second read has no room in this layout.
        assert_eq!(
            plan.stream_put(0, StreamRead::Status, Some(Command::GetStatus)),
            Err(ScheduleError::TooManyCommands)
        );
        assert_eq!(plan.windows(), STREAM_WINDOWS);
    }

    #[test]
    fn two_responses_for_one_device_are_separated_by_padding() {
        let mut b = Batch::new(1);
        b.push(0, Command::GetStatus).unwrap();
        b.push(0, Command::GetParam(Register::AbsPos)).unwrap();
        let plan = Plan::new(&b).unwrap();
        // D0, 00, 21, then 3 response bytes: status out in windows 1..=2,
        // GetParam in window 2 (after the status LSB went out).
        assert_eq!(plan.window(0).unwrap(), &[0xD0]);
        assert_eq!(plan.window(1).unwrap(), &[0x00]);
        assert_eq!(plan.window(2).unwrap(), &[0x21]);
        assert_eq!(plan.windows(), 6);
    }

    #[test]
    fn too_many_commands_for_a_device_is_an_error() {
        let mut b = Batch::new(1);
        for _ in 0..MAX_COMMANDS {
            b.push(0, Command::Nop).unwrap();
        }
        assert_eq!(b.push(0, Command::Nop), Err(ScheduleError::TooManyCommands));
        assert_eq!(
            Batch::new(2).push(2, Command::Nop),
            Err(ScheduleError::NoSuchDevice(2))
        );
    }

    #[test]
    fn echo_offset_gives_the_chain_length() {
        let tx = detect_pattern();
        for n in 0..=MAX_DEVICES {
            let mut rx = [0xAAu8; DETECT_LEN];
            rx[n..].copy_from_slice(&tx[..DETECT_LEN - n]);
            assert_eq!(length_from_echo(&tx, &rx), Some(n));
        }
    }

    #[test]
    fn stuck_miso_is_no_echo() {
        let tx = detect_pattern();
        assert_eq!(length_from_echo(&tx, &[0xFF; DETECT_LEN]), None);
        assert_eq!(length_from_echo(&tx, &[0x00; DETECT_LEN]), None);
    }

    #[test]
    fn detection_pattern_bytes_are_distinct_get_params() {
        let p = detect_pattern();
        for (i, b) in p.iter().enumerate() {
            assert_eq!(
                Command::decode(&[*b]),
                Ok(Command::GetParam(
                    Register::from_address(i as u8 + 1).unwrap()
                ))
            );
            assert!(!p[..i].contains(b));
        }
    }
}
