//! The control tick for a chain driver that clocks the windows on its own
//! (DMA): [`Bridge::tick_pipelined`].
//!
//! # Order of events
//!
//! Tick k ends batch k − 1 (its replies are decoded and absorbed), then
//! begins tick k (device models, every axis plans) and hands the plan to the
//! driver, which clocks its windows while the CPU does other work. Batch k's
//! replies are absorbed at the start of tick k + 1, before batch k + 1 is
//! planned: the same order as the blocking [`Bridge::tick`] (plan k,
//! windows k, absorb k, plan k + 1). What changes is *when* the absorb runs
//! (at the next tick instead of right after the windows) and that the bus
//! tasks' requests between two ticks now reach the axes between the plan
//! and the absorb of the same batch.
//!
//! # A batch still on the bus
//!
//! If the driver says the previous batch is still running when the next
//! tick comes, nothing else happens in that tick: no models, no plan, no
//! batch. It is counted as an overrun (the diagnostics' tick overruns, with
//! the ticks whose own computation took longer than the period) and the
//! batch is ended by the first tick that finds it over. A driver must end a
//! batch that never completes on its own (a timeout), or every tick after
//! it is skipped.

//! # The overlapped tick
//!
//! [`Bridge::tick_overlapped`] puts batch k on the bus first, planned by
//! tick k − 1, and then absorbs batch k − 1 and plans batch k + 1 while
//! batch k is on the bus: a period needs the longer of the computation and
//! the batch, not their sum. The price is one tick: each plan works from
//! the read-back of the batch before the one on the bus, and a command
//! reaches the chip one tick later (each axis keeps its batches' reads
//! apart, `motion::axis`). A tick without a planned batch (the first one,
//! or after a failed batch, whose follower is dropped unsent) plans one and
//! starts nothing.

use super::Bridge;
use crate::powerstep::chain::{BatchState, ChainBus, Frames, Plan, MAX_DEVICES, MAX_WINDOWS};

/// The overlapped tick's state.
#[derive(Clone, Debug)]
pub(super) struct Overlap {
    /// The ticks run overlapped: [`Bridge::tick_pipelined`] is
    /// [`Bridge::tick_overlapped`], and [`Bridge::tick`] clocks on its
    /// blocking bus the batch the previous tick planned and keeps its
    /// replies for the next (the simulators).
    pub(super) on: bool,
    /// A planned batch waits for the next tick.
    ready: bool,
    /// The blocking variant's batch clocked at the last tick (a failed one
    /// was ended in it), and its replies.
    done: bool,
    rx: Frames,
}

impl Overlap {
    pub(super) const fn new() -> Overlap {
        Overlap {
            on: false,
            ready: false,
            rx: [[0; MAX_DEVICES]; MAX_WINDOWS],
            done: false,
        }
    }
}

/// What [`Bridge::tick_pipelined`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PipelinedTick {
    /// The previous batch was still running: this tick was skipped and
    /// counted as an overrun.
    Overrun,
    /// The tick is complete without a batch (no axes, or the plan could not
    /// be made / the chain could not be brought back in step: counted as a
    /// chain error).
    NoBatch,
    /// A batch started: hand the driver's answer to the next tick.
    Started,
    /// The driver refused the batch: ended at once as a chain error.
    StartFailed,
}

impl<B: ChainBus> Bridge<B> {
    /// One control tick at `now_ms` for a chain driver that clocks the
    /// windows itself (module docs): end the previous batch as `previous`
    /// says, begin this tick, and give its plan and the chain's bus to
    /// `start` (which starts the windows; the bus is there for drivers that
    /// clock them at once, e.g. through a simulator). The blocking
    /// [`ChainBus::window`] is still used for the chain's own recovery
    /// windows inside the tick.
    pub fn tick_pipelined(
        &mut self,
        now_ms: u64,
        previous: BatchState<'_, B::Error>,
        start: impl FnOnce(&Plan, &mut B) -> Result<(), B::Error>,
    ) -> PipelinedTick {
        if self.overlap.on {
            return self.tick_overlapped(now_ms, previous, start);
        }
        match previous {
            BatchState::Running => return self.overrun(),
            BatchState::Done(rx) => self.tick_end(rx),
            BatchState::Idle => {}
        }
        if !self.tick_begin(now_ms) {
            return PipelinedTick::NoBatch;
        }
        match start(self.group.plan(), self.chain.bus_mut()) {
            Ok(()) => PipelinedTick::Started,
            Err(e) => {
                self.tick_end(Err(e));
                PipelinedTick::StartFailed
            }
        }
    }

    /// One overlapped control tick at `now_ms` (module docs): `previous`
    /// is the batch started by the last tick; the batch planned by it is
    /// handed to `start` at once, then `previous` is absorbed and the next
    /// batch planned. A failed batch drops the one planned behind it (every
    /// axis sets its chip up again; the next tick plans anew).
    pub fn tick_overlapped(
        &mut self,
        now_ms: u64,
        previous: BatchState<'_, B::Error>,
        start: impl FnOnce(&Plan, &mut B) -> Result<(), B::Error>,
    ) -> PipelinedTick {
        let failed = match &previous {
            BatchState::Running => return self.overrun(),
            BatchState::Done(rx) => rx.is_err(),
            BatchState::Idle => false,
        };
        // First the batch the last tick planned (unless the one before it
        // failed: then it goes unsent), then the previous one's replies.
        let planned = core::mem::take(&mut self.overlap.ready);
        let ready = planned && !failed;
        if planned && failed {
            // The tick whose batch goes unsent counts toward the chain's
            // death as a failed one ([`Bridge::chain_dead`] after
            // `CHAIN_DEAD_TICKS` in a row, as in a row).
            self.failed_ticks = self.failed_ticks.saturating_add(1);
        }
        let started = ready.then(|| {
            let plan = self.group.launch();
            match self.chain.begin(plan) {
                Ok(()) => start(plan, self.chain.bus_mut()).map_err(Some),
                Err(_) => Err(None),
            }
        });
        if let BatchState::Done(rx) = previous {
            let ok = self.group.end_previous(&mut self.chain, rx, ready).is_ok();
            self.group.absorb_decoded(ok);
            self.after_batch(ok);
        }
        let started = match started {
            Some(Err(e)) => {
                // Not on the bus: as a batch that failed (a refusal by the
                // driver puts the chain out of step, as a failed transfer).
                if let Some(e) = e {
                    let _ = self.group.end_previous(&mut self.chain, Err(e), false);
                }
                self.group.absorb_decoded(false);
                self.after_batch(false);
                Some(false)
            }
            Some(Ok(())) => Some(true),
            None => None,
        };
        self.overlap.ready = self.tick_begin(now_ms);
        match started {
            Some(true) => PipelinedTick::Started,
            Some(false) => PipelinedTick::StartFailed,
            None => PipelinedTick::NoBatch,
        }
    }

    /// The ticks run overlapped (`on`; module docs): the firmware sets it
    /// as `rate::fit` says ([`Bridge::new_fitted_with`]); on a simulated
    /// chain [`Bridge::tick`] clocks each batch at the tick after its plan,
    /// as the firmware's driver does.
    pub fn set_overlapped(&mut self, on: bool) {
        self.overlap.on = on;
    }

    /// At most `windows` CS windows a batch (what the tick's period holds
    /// on this chain: `rate::Rate::windows`, which
    /// [`Bridge::new_fitted_with`] applies; a command past it waits for a
    /// later tick).
    pub fn set_window_budget(&mut self, windows: usize) {
        self.group.set_window_budget(windows);
    }

    /// Whether a tick in which every axis streams or rests is planned
    /// without the batch (`AxisGroup::set_plain_shortcut`; on by default,
    /// the tests turn it off to compare the two).
    pub fn set_plain_shortcut(&mut self, on: bool) {
        self.group.set_plain_shortcut(on);
    }

    /// Ticks planned without the batch so far (wrapping).
    pub fn plain_ticks(&self) -> u32 {
        self.group.plain_ticks()
    }

    /// The ticks run overlapped ([`Bridge::set_overlapped`]).
    pub fn is_overlapped(&self) -> bool {
        self.overlap.on
    }

    pub(super) fn tick_overlapped_blocking(&mut self, now_ms: u64) {
        let rx = self.overlap.rx;
        let previous = if core::mem::take(&mut self.overlap.done) {
            BatchState::Done(Ok(&rx))
        } else {
            BatchState::Idle
        };
        let mut out = self.overlap.rx;
        let mut clocked = false;
        self.tick_overlapped(now_ms, previous, |plan, bus| {
            let r = crate::powerstep::chain::clock_windows(bus, plan, plan.devices(), &mut out);
            clocked = r.is_ok();
            r
        });
        self.overlap.rx = out;
        // A batch that failed was ended in the tick.
        self.overlap.done = clocked;
    }

    /// A tick that found its batch still on the bus: skipped, counted.
    fn overrun(&mut self) -> PipelinedTick {
        self.timing.overruns = self.timing.overruns.saturating_add(1);
        PipelinedTick::Overrun
    }

    /// Control ticks that overran: their own computation took longer than
    /// the period ([`Bridge::tick_timing`]), or the previous batch was still
    /// on the bus ([`Bridge::tick_pipelined`]). Diagnostics 0x032E–2F.
    pub fn tick_overruns(&self) -> u32 {
        self.timing.overruns
    }
}
