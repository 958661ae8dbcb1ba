//! The bridge side of the Copley-style SPI I/O extension: the box's
//! buttons, switches and lamps over 74HC165/74HC595 shift registers.
//!
//! Each control tick the debounced inputs of every axis are handed to its
//! device (where the mapping wires them; unmapped inputs keep what
//! [`Bridge::on_inputs`] last reported), and the lamps of every axis go
//! into the extension's next transfer. The firmware takes the transfer
//! with [`Bridge::take_io_action`] and reports its end with
//! [`Bridge::on_io_done`] or [`Bridge::on_io_failed`].
//!
//! Decisions (docs/DECISIONS.md):
//! * A mapped input that has no debounced level yet (power-up, mapping just
//!   written) reads released/open/off: BINx not pressed, end switch open,
//!   run/stop switch off — an auto-run axis with a mapped run/stop switch
//!   does not start before the switch is read on.
//! * BINx and run/stop use the extension's contact polarity (the mapping's
//!   NC bit). The end switch is handed over as the contact level and the
//!   PoStep60 end-switch settings apply to it as to the chip's SW input.
//! * Homing (extension 0x04) uses the chip's SW input only: GoUntil and
//!   ReleaseSW are executed by the chip, which cannot see the shift
//!   registers.

use super::Bridge;
use crate::ioext::{Action, AxisOutputs, Input, IoExtension, NotRunning, WireBits};
use crate::postep60::device::{DriverStatus, Inputs};
use crate::powerstep::chain::ChainBus;

impl<B: ChainBus> Bridge<B> {
    /// Axis `k`'s inputs: what [`Bridge::on_inputs`] last reported, with
    /// every input the extension's mapping wires taken from the extension.
    pub(super) fn merged_inputs(&self, k: usize) -> Inputs {
        let mut inputs = self.board_inputs.get(k).copied().unwrap_or_default();
        if !self.io.enabled() {
            return inputs;
        }
        let Some(map) = self.io.mapping().axes.get(k) else {
            return inputs;
        };
        let got = self.io.inputs(k);
        if map.input(Input::Bin1).is_some() {
            inputs.bin1 = got.bin1.is_some_and(|c| c.active);
        }
        if map.input(Input::Bin2).is_some() {
            inputs.bin2 = got.bin2.is_some_and(|c| c.active);
        }
        if map.input(Input::EndSwitch).is_some() {
            inputs.end_switch = Some(got.end_switch.is_some_and(|c| c.closed));
        }
        if map.input(Input::Run).is_some() {
            inputs.run = Some(got.run.is_some_and(|c| c.active));
        }
        inputs
    }

    /// Hand every axis its inputs where they changed (ignored while
    /// settings are saved: they are applied at the first tick after).
    pub(super) fn apply_inputs(&mut self) {
        if self.saving {
            return;
        }
        for k in 0..self.devices.len() {
            let inputs = self.merged_inputs(k);
            if let (Some(d), Some(a)) = (self.devices.get_mut(k), self.group.axis_mut(k)) {
                if d.inputs() != inputs {
                    d.set_inputs(inputs, a);
                }
            }
        }
    }

    /// Lamps for the next transfer and the driver's next action (once per
    /// tick, after the chain batch).
    pub(super) fn io_outputs(&mut self) {
        if self.io_action.is_some() {
            return;
        }
        let mut lamps = [AxisOutputs::default(); crate::ioext::mapping::MAX_AXES];
        for ((l, d), a) in lamps
            .iter_mut()
            .zip(self.devices.iter())
            .zip(self.group.iter())
        {
            *l = AxisOutputs {
                moving: !a.is_at_rest(),
                fault: d.faults() != 0,
                idle: d.status() == DriverStatus::Idle,
            };
        }
        let n = self.devices.len().min(lamps.len());
        self.io_action = self.io.tick(lamps.get(..n).unwrap_or(&[]));
    }

    /// What the extension's driver must do next: a transfer to run, or
    /// release the port. Taken once; the next one comes at a later tick.
    pub fn take_io_action(&mut self) -> Option<Action> {
        self.io_action.take()
    }

    /// The transfer the driver took has ended with these received bits.
    pub fn on_io_done(&mut self, rx: &WireBits) -> Result<(), NotRunning> {
        self.io.complete(rx)
    }

    /// The transfer the driver took has failed (the driver raised CS).
    pub fn on_io_failed(&mut self) -> Result<(), NotRunning> {
        self.io.fail()
    }

    /// The extension (registers, inputs, diagnostics).
    pub fn io(&self) -> &IoExtension {
        &self.io
    }
}
