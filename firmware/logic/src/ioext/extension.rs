//! The extension itself ([`IoExtension`]): its state and its transfer
//! scheduler. (`ext_space` is the bridge's register space on the buses;
//! this is the I/O extension, the '165/'595 shift-register port.)

use super::clock::{clock_plan, ClockPlan, Clocks};
use super::config::{Config, WireBits};
use super::image::IoSettings;
use super::mapping::{apply_outputs, AxisInputs, AxisOutputs, InputFilter, Mapping};
use super::plan::{Action, TransferPlan};

/// Counters for diagnostics (all wrap or saturate, never panic).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Diagnostics {
    /// Transfers completed (wrapping).
    pub transfers: u32,
    /// Control ticks at which auto-restart could not start a transfer
    /// because the previous one was still running (saturating).
    pub skipped_restarts: u32,
    /// Register writes that had undocumented bits set, which were dropped
    /// (saturating).
    pub reserved_ignored: u32,
    /// Transfers the driver reported failed (saturating).
    pub failures: u32,
    /// `complete`/`fail` calls with no transfer running (saturating).
    pub stray_completions: u32,
}

/// `complete` or `fail` without a transfer running.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NotRunning;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct InFlight {
    pub bits: u16,
    pub cs_hold: bool,
}

/// The Copley-style SPI I/O extension (see the module doc of
/// [`ioext`](super)).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IoExtension {
    pub(super) clocks: Clocks,
    pub(super) enabled: bool,
    pub(super) config: Config,
    pub(super) tx: WireBits,
    pub(super) rx: WireBits,
    pub(super) status: bool,
    /// Transmit data written and not started yet.
    pub(super) pending: bool,
    pub(super) in_flight: Option<InFlight>,
    /// CS was left low by the last transfer.
    pub(super) cs_low: bool,
    /// The port has been driven since the last [`Action::Disable`].
    pub(super) port_active: bool,
    pub(super) mapping: Mapping,
    pub(super) filter: InputFilter,
    pub(super) diag: Diagnostics,
}

impl IoExtension {
    /// The extension at power-up with persisted `settings`. If it is
    /// enabled, the stored transmit data goes out at the first tick (the
    /// outputs come up in their stored state), and every tick after that
    /// with auto-restart.
    pub fn new(settings: IoSettings, clocks: Clocks) -> IoExtension {
        IoExtension {
            clocks,
            enabled: settings.enabled,
            config: settings.config,
            tx: settings.tx,
            rx: WireBits::ZERO,
            status: false,
            pending: settings.enabled,
            in_flight: None,
            cs_low: false,
            port_active: false,
            mapping: settings.mapping,
            filter: InputFilter::NEW,
            diag: Diagnostics::default(),
        }
    }

    /// What "write settings" stores.
    pub fn settings(&self) -> IoSettings {
        IoSettings {
            enabled: self.enabled,
            config: self.config,
            tx: self.tx,
            mapping: self.mapping,
        }
    }

    pub fn enabled(&self) -> bool {
        self.enabled
    }

    pub fn config(&self) -> Config {
        self.config
    }

    /// Configuration bit 11.
    pub fn status(&self) -> bool {
        self.status
    }

    /// The transmit data register (what the master wrote, without lamps).
    pub fn tx(&self) -> WireBits {
        self.tx
    }

    /// The receive data of the last completed transfer (bits past its bit
    /// count are 0). Reading it here does not clear the status bit.
    pub fn rx(&self) -> WireBits {
        self.rx
    }

    pub fn mapping(&self) -> &Mapping {
        &self.mapping
    }

    /// A transfer is running (planned, not completed or failed yet).
    pub fn is_running(&self) -> bool {
        self.in_flight.is_some()
    }

    /// CS is held low after the last transfer.
    pub fn cs_low(&self) -> bool {
        self.cs_low
    }

    pub fn diagnostics(&self) -> Diagnostics {
        self.diag
    }

    /// The engine and real period of the current configuration.
    pub fn clock_plan(&self) -> ClockPlan {
        clock_plan(self.config.period_n(), self.config.bits(), self.clocks)
    }

    /// The debounced inputs of `axis` (all `None` while the extension is off).
    pub fn inputs(&self, axis: usize) -> AxisInputs {
        if !self.enabled {
            return AxisInputs::default();
        }
        self.filter.inputs(&self.mapping, axis)
    }

    /// Once per control tick, with the lamp state of each axis (axis 0
    /// first; fewer than the mapped axes leave the rest of the bits as
    /// written). Returns what the driver must do:
    ///
    /// * nothing while a transfer runs (an auto-restart that cannot happen
    ///   is counted in [`Diagnostics::skipped_restarts`]; written data waits
    ///   for the first tick after the running transfer ends);
    /// * [`Action::Disable`] once after the extension was switched off;
    /// * a transfer when the extension is on and transmit data was written
    ///   since the last start, or auto-restart is on.
    pub fn tick(&mut self, outputs: &[AxisOutputs]) -> Option<Action> {
        if self.in_flight.is_some() {
            if self.enabled && self.config.auto_restart() {
                self.diag.skipped_restarts = self.diag.skipped_restarts.saturating_add(1);
            }
            return None;
        }
        if !self.enabled {
            self.pending = false;
            if self.port_active {
                self.port_active = false;
                self.cs_low = false;
                self.filter.reset();
                return Some(Action::Disable);
            }
            return None;
        }
        if !self.pending && !self.config.auto_restart() {
            return None;
        }
        self.pending = false;
        let c = self.config;
        let bits = c.bits();
        let mut tx = self.tx;
        apply_outputs(&self.mapping, outputs, &mut tx);
        let plan = TransferPlan {
            bits,
            mode: c.mode(),
            clock: clock_plan(c.period_n(), bits, self.clocks),
            cs_low_before: self.cs_low,
            cs_hold: c.cs_hold(),
            tx: tx.truncated(bits),
        };
        self.in_flight = Some(InFlight {
            bits,
            cs_hold: plan.cs_hold,
        });
        self.port_active = true;
        Some(Action::Transfer(plan))
    }

    /// The running transfer ended with these received bits (wire order):
    /// the receive data is replaced (bits past the transfer's count read 0),
    /// the status bit is set, the inputs are sampled.
    pub fn complete(&mut self, rx: &WireBits) -> Result<(), NotRunning> {
        let Some(f) = self.in_flight.take() else {
            self.diag.stray_completions = self.diag.stray_completions.saturating_add(1);
            return Err(NotRunning);
        };
        self.rx = rx.truncated(f.bits);
        self.status = true;
        self.cs_low = f.cs_hold;
        self.diag.transfers = self.diag.transfers.wrapping_add(1);
        self.filter.feed(&self.mapping, &self.rx, f.bits);
        Ok(())
    }

    /// The running transfer failed (the driver stopped it and raised CS):
    /// receive data and status are unchanged, the failure is counted, and
    /// the next tick may start a new transfer.
    pub fn fail(&mut self) -> Result<(), NotRunning> {
        if self.in_flight.take().is_none() {
            self.diag.stray_completions = self.diag.stray_completions.saturating_add(1);
            return Err(NotRunning);
        }
        self.cs_low = false;
        self.diag.failures = self.diag.failures.saturating_add(1);
        Ok(())
    }
}
