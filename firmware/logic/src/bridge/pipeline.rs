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

use super::Bridge;
use crate::powerstep::chain::{BatchState, ChainBus, Plan};

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
        match previous {
            BatchState::Running => {
                self.timing.overruns = self.timing.overruns.saturating_add(1);
                return PipelinedTick::Overrun;
            }
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

    /// Control ticks that overran: their own computation took longer than
    /// the period ([`Bridge::tick_timing`]), or the previous batch was still
    /// on the bus ([`Bridge::tick_pipelined`]). Diagnostics 0x032E–2F.
    pub fn tick_overruns(&self) -> u32 {
        self.timing.overruns
    }
}
