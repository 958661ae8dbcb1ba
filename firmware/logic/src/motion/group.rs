//! All axes of the chain, ticked together: one batch per control tick, so
//! every axis's output command completes in the same CS window.

use heapless::Vec;

use super::axis::Axis;
use super::coordinated::{AppendError, CoordRun, StartError};
use super::profile::Limits;
use crate::powerstep::chain::{
    Batch, Chain, ChainBus, ChainError, Frames, Plan, Replies, ScheduleError, MAX_DEVICES,
    MAX_WINDOWS,
};

/// The axes of one chain; axis k drives chain device k.
#[derive(Clone, Debug)]
pub struct AxisGroup {
    axes: Vec<Axis, MAX_DEVICES>,
    /// Reused every tick (no copies of the frames on the control path).
    batch: Batch,
    /// Two plans: the one [`AxisGroup::prepare`] makes and, for the
    /// overlapped tick, the one on the bus ([`AxisGroup::launch`]).
    plans: (Plan, Plan),
    /// `plans.1` is the one being made.
    second: bool,
    replies: Replies,
    /// Ticks in which every axis streams or rests plan without the batch
    /// ([`AxisGroup::prepare`], [`Axis::plain`]).
    shortcut: bool,
    /// Ticks planned that way (wrapping).
    plained: u32,
    /// Which plan (`plans.0`, `plans.1`) was made that way: its replies
    /// are the 3 bytes from window 1 of every device's column.
    plain: [bool; 2],
    /// The last replies decoded were a plain plan's: `raw` holds them
    /// (device d's 3 bytes, MSB first), not `replies`.
    raw_decoded: bool,
    raw: [u32; MAX_DEVICES],
    /// The coordinated move (running, or the last one).
    coord: CoordRun,
}

impl Default for AxisGroup {
    fn default() -> AxisGroup {
        AxisGroup::new()
    }
}

/// The group already has [`MAX_DEVICES`] axes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GroupFull;

/// What one tick put on the chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TickReport {
    pub windows: usize,
    pub bytes: usize,
    /// Window in which every axis's output command completed.
    pub sync_window: usize,
}

impl AxisGroup {
    pub fn new() -> AxisGroup {
        AxisGroup {
            axes: Vec::new(),
            batch: Batch::new(0),
            plans: (Plan::default(), Plan::default()),
            second: false,
            replies: Replies::default(),
            shortcut: true,
            plained: 0,
            plain: [false; 2],
            raw_decoded: false,
            raw: [0; MAX_DEVICES],
            coord: CoordRun::new(),
        }
    }

    /// Add the axis for the next chain device.
    pub fn push(&mut self, axis: Axis) -> Result<(), GroupFull> {
        self.axes.push(axis).map_err(|_| GroupFull)
    }

    pub fn len(&self) -> usize {
        self.axes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.axes.is_empty()
    }

    pub fn axis(&self, k: usize) -> Option<&Axis> {
        self.axes.get(k)
    }

    pub fn axis_mut(&mut self, k: usize) -> Option<&mut Axis> {
        self.axes.get_mut(k)
    }

    pub fn iter(&self) -> impl Iterator<Item = &Axis> {
        self.axes.iter()
    }

    /// Every axis settled.
    pub fn is_settled(&self) -> bool {
        self.axes.iter().all(|a| a.is_settled())
    }

    /// At most `windows` CS windows a batch ([`Batch::set_window_budget`]:
    /// what the tick's period holds; a command past it waits for a later
    /// tick).
    pub fn set_window_budget(&mut self, windows: usize) {
        self.batch.set_window_budget(windows);
    }

    /// Whether a tick in which every axis streams or rests
    /// ([`Axis::plain`]) is planned without the batch (on by default; the
    /// tests turn it off to compare the two).
    pub fn set_plain_shortcut(&mut self, on: bool) {
        self.shortcut = on;
    }

    /// Ticks planned without the batch so far (wrapping).
    pub fn plain_ticks(&self) -> u32 {
        self.plained
    }

    /// The plan being made (`making`) or the other one.
    fn slot(&self, making: bool) -> &Plan {
        pick(&self.plans, self.second == making)
    }

    /// Start a coordinated move ([`CoordRun::start`]) of the axes
    /// `members` to `targets`, at most at the `path` limits.
    pub fn coord_start(
        &mut self,
        members: &[usize],
        targets: &[i64],
        path: Limits,
    ) -> Result<(), StartError> {
        self.coord.start(&mut self.axes, members, targets, path)
    }

    /// Queue a waypoint behind the coordinated move ([`CoordRun::append`]).
    pub fn coord_append(&mut self, targets: &[i64]) -> Result<(), AppendError> {
        self.coord.append(&mut self.axes, targets)
    }

    /// Stop the coordinated move along its line ([`CoordRun::stop`]).
    pub fn coord_stop(&mut self) {
        self.coord.stop(&mut self.axes);
    }

    /// The coordinated move running, or the last one.
    pub fn coord(&self) -> &CoordRun {
        &self.coord
    }

    /// First half of a tick: every axis plans its commands; one plan for the chain.
    pub fn prepare(&mut self) -> Result<&Plan, ScheduleError> {
        if self.coord.is_active() {
            self.coord.step(&mut self.axes);
        }
        let [a, b] = [&mut self.plans.0, &mut self.plans.1];
        let plan = if self.second { b } else { a };
        let plain_slot = usize::from(self.second);
        // The common tick, every axis streaming or resting: each writes
        // its read and its Run (or SoftStop) straight into the plan (the
        // same plan as below).
        let n = self.axes.len();
        if self.shortcut && self.axes.iter().all(Axis::plain) && plan.stream_begin(n) {
            for (d, axis) in self.axes.iter_mut().enumerate() {
                // (Not plain after all, `Axis::plain` being wrong, the tick
                // fails as a batch that does not fit, and every axis sets
                // its chip up again.)
                axis.plan_plain(plan, d)?;
            }
            plan.stream_end();
            self.plained = self.plained.wrapping_add(1);
            set(&mut self.plain, plain_slot, true);
            self.coord.settle(&self.axes);
            return Ok(plan);
        }
        set(&mut self.plain, plain_slot, false);
        let batch = &mut self.batch;
        batch.reset(n);
        for (d, axis) in self.axes.iter_mut().enumerate() {
            axis.plan(|cmd| batch.push(d, cmd).is_ok());
        }
        // (A landing confirmed in this plan ends a coordinated move now.)
        self.coord.settle(&self.axes);
        plan.schedule(batch)?;
        Ok(plan)
    }

    /// The overlapped tick: the plan of the last [`AxisGroup::prepare`]
    /// goes on the bus (its replies are [`AxisGroup::end_previous`]'s), and
    /// the next prepare makes the other one.
    pub fn launch(&mut self) -> &Plan {
        self.second = !self.second;
        self.slot(false)
    }

    /// The overlapped tick: decode what came back for the batch launched
    /// before the last [`AxisGroup::launch`] if that one was `just_launched`
    /// (else for the last launched), or the bus error that cut it short;
    /// [`AxisGroup::absorb_decoded`] gives it to the axes.
    pub fn end_previous<B: ChainBus>(
        &mut self,
        chain: &mut Chain<B>,
        rx: Result<&Frames, B::Error>,
        just_launched: bool,
    ) -> Result<(), ChainError<B::Error>> {
        // The plan being made is the one before the launch until the next
        // prepare.
        self.decode(chain, rx, self.second == just_launched)
    }

    /// What came back for plan `second` (`plans.1` if true), decoded: a
    /// plain plan's replies into `raw`, any other's into `replies`.
    fn decode<B: ChainBus>(
        &mut self,
        chain: &mut Chain<B>,
        rx: Result<&Frames, B::Error>,
        second: bool,
    ) -> Result<(), ChainError<B::Error>> {
        let rx = chain.ended(rx)?;
        let plan = pick(&self.plans, second);
        self.raw_decoded = self.plain.get(usize::from(second)) == Some(&true);
        if !self.raw_decoded {
            plan.decode_into(rx, &mut self.replies);
            return Ok(());
        }
        // Device d is column n − 1 − d; its read's reply is in windows 1
        // to 3 (a 2-byte STATUS in 1 and 2).
        let [_, w1, w2, w3, ..] = rx;
        let n = plan.devices();
        let (Some(a), Some(b), Some(c)) = (w1.get(..n), w2.get(..n), w3.get(..n)) else {
            return Ok(());
        };
        let columns = a.iter().rev().zip(b.iter().rev()).zip(c.iter().rev());
        for (raw, ((x, y), z)) in self.raw.iter_mut().zip(columns) {
            *raw = (u32::from(*x) << 16) | (u32::from(*y) << 8) | u32::from(*z);
        }
        Ok(())
    }

    /// One control tick on `chain` (whose length must equal the number of axes).
    ///
    /// [`AxisGroup::tick_begin`], every window through the blocking bus,
    /// [`AxisGroup::tick_end`]: a driver that clocks the windows itself (by
    /// DMA) calls those two around its transfer.
    pub fn tick<B: ChainBus>(
        &mut self,
        chain: &mut Chain<B>,
    ) -> Result<TickReport, ChainError<B::Error>> {
        let report = self.tick_begin(chain)?;
        let mut rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];
        let result = chain.clock(self.slot(true), &mut rx);
        self.tick_end(chain, result.map(|()| &rx)).map(|()| report)
    }

    /// First half of an asynchronous tick: every axis plans, the plan is
    /// checked against the chain (resynced if out of step). The windows to
    /// clock are [`AxisGroup::plan`]'s; then call [`AxisGroup::tick_end`].
    /// On an error nothing goes out and every axis sets its chip up again.
    pub fn tick_begin<B: ChainBus>(
        &mut self,
        chain: &mut Chain<B>,
    ) -> Result<TickReport, ChainError<B::Error>> {
        if let Err(e) = self.prepare() {
            self.absorb_decoded(false);
            return Err(ChainError::Schedule(e));
        }
        let plan = self.slot(true);
        if let Err(e) = chain.begin(plan) {
            self.absorb_decoded(false);
            return Err(e);
        }
        Ok(TickReport {
            windows: plan.windows(),
            bytes: plan.bytes(),
            sync_window: plan.sync_window(),
        })
    }

    /// The plan of the last [`AxisGroup::tick_begin`].
    pub fn plan(&self) -> &Plan {
        self.slot(true)
    }

    /// Second half of an asynchronous tick: what came back for the plan of
    /// the last [`AxisGroup::tick_begin`] (or the bus error that cut it
    /// short), decoded and absorbed.
    pub fn tick_end<B: ChainBus>(
        &mut self,
        chain: &mut Chain<B>,
        rx: Result<&Frames, B::Error>,
    ) -> Result<(), ChainError<B::Error>> {
        let result = self.decode(chain, rx, self.second);
        self.absorb_decoded(result.is_ok());
        result
    }

    /// Every axis takes the replies decoded last ([`AxisGroup::tick_end`],
    /// [`AxisGroup::end_previous`]) if `ok`, or sets its chip up again (the
    /// batch failed).
    pub fn absorb_decoded(&mut self, ok: bool) {
        if ok && self.raw_decoded {
            for (axis, raw) in self.axes.iter_mut().zip(self.raw) {
                axis.absorb_plain(raw);
            }
            return;
        }
        for (d, axis) in self.axes.iter_mut().enumerate() {
            if ok {
                axis.absorb(&self.replies, d);
            } else {
                // Some chips may have missed commands: set every chip up again.
                axis.on_chain_error();
            }
        }
    }
}

/// `plans.1` if `second`, else `plans.0`.
fn pick(plans: &(Plan, Plan), second: bool) -> &Plan {
    if second {
        &plans.1
    } else {
        &plans.0
    }
}

/// `flags[k] = on` (k is 0 or 1).
fn set(flags: &mut [bool; 2], k: usize, on: bool) {
    if let Some(f) = flags.get_mut(k) {
        *f = on;
    }
}
