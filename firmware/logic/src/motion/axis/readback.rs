//! The chip's replies: positions unwrapped, STATUS decoded (resets, faults,
//! stalls, refusals), extension-space register reads.

use super::*;
use crate::powerstep::chain::Reply;

impl Axis {
    /// Take the replies of the oldest batch in flight for the axis's device.
    pub fn absorb(&mut self, replies: &Replies, device: usize) {
        let Some(sent) = self.rb.in_flight.pop() else {
            return;
        };
        if let Some(r) = self.ext_read.as_mut() {
            match r.index {
                Some((at, i)) if at == sent.tick => {
                    r.index = None;
                    if let Some(Reply::Param(reg, v)) = replies.get(device, i) {
                        if reg == r.reg {
                            r.value = Some((v, sent.tick));
                        }
                    }
                }
                // Its batch's replies were lost: ask again.
                Some((at, _)) if at < sent.tick => r.index = None,
                _ => {}
            }
        }
        // The read is the plan's first command ([`Axis::plan_read`]).
        match (sent.read, replies.get(device, 0)) {
            (Some(Read::Position), Some(Reply::Param(Register::AbsPos, raw))) => {
                self.take_position(raw, &sent);
            }
            (Some(Read::Status), Some(Reply::Status(s))) => self.take_status(s, sent.tick),
            _ => {}
        }
    }

    /// [`Axis::absorb`] for a batch planned plain ([`Axis::plan_plain`]):
    /// its only reply is the read's, `raw` the 3 bytes from window 1 (a
    /// position read's 22 bits, or a STATUS in the first two).
    pub fn absorb_plain(&mut self, raw: u32) {
        let Some(sent) = self.rb.in_flight.pop() else {
            return;
        };
        match sent.read {
            Some(Read::Position) => self.take_position(raw & Register::AbsPos.mask(), &sent),
            Some(Read::Status) => self.take_status(Status((raw >> 8) as u16), sent.tick),
            None => {}
        }
    }

    /// A position read of the batch `sent` describes.
    fn take_position(&mut self, raw: u32, sent: &Sent) {
        if matches!(self.state, AxisState::Setup(_)) {
            return; // the chip's frame is being re-based
        }
        let rb = &mut self.rb;
        if core::mem::take(&mut self.absolute_read) {
            // The chip re-based its frame (homing): its value is the position.
            rb.chip_pos = i64::from(sign_extend_22(raw));
            self.rate.disarm();
        } else {
            let base = rb.raw.unwrap_or(wrap_22(rb.chip_pos as i32));
            let delta = sign_extend_22(raw.wrapping_sub(base) & 0x3F_FFFF);
            rb.chip_pos += i64::from(delta);
            // Only while the chip follows: a chip still stopping or landing
            // when streaming began runs its own ramps.
            let follows =
                sent.expected_valid && (sent.expected - rb.chip_pos).abs() <= RATE_MAX_ERROR;
            if matches!(self.state, AxisState::Streaming) && rb.raw.is_some() && follows {
                self.rate.take(
                    i64::from(delta),
                    (sent.commanded, sent.epoch),
                    self.cfg.tick_us,
                    self.cfg.step.shift(),
                );
            } else {
                self.rate.disarm();
            }
        }
        let rb = &mut self.rb;
        rb.raw = Some(raw);
        rb.pos_at = sent.tick;
        // Measured in every state: when a move starts while the chip is
        // still stopping or landing, the correction starts at once.
        rb.error = if self.stop.zero {
            0
        } else if sent.expected_valid {
            sent.expected - rb.chip_pos
        } else {
            rb.error
        };
    }

    /// A STATUS read of the batch planned at tick `at`.
    fn take_status(&mut self, s: Status, at: u64) {
        self.rb.status = s;
        self.rb.status_at = at;
        self.image.status_seen(s.command_error());
        if s.uvlo() {
            // Reset or undervoltage. In a setup, only a read issued after
            // the setup began reports a new one (the power-up flag, or the
            // one that started this setup, was cleared by the first read).
            let new = match self.state {
                AxisState::Setup(_) => at > self.rb.setup_at,
                _ => true,
            };
            if new {
                self.fault = Some(AxisFault::ChipReset);
                self.resets = self.resets.wrapping_add(1);
                if !matches!(self.state, AxisState::Setup(_)) {
                    // Positions read since the last clean STATUS are not
                    // trustworthy; stop where the chip was then.
                    self.rb.chip_pos = self.rb.pos_at_status;
                }
                self.restart_setup();
                return;
            }
        }
        if s.stalled() {
            // A stall may have lost steps: the home is no longer known.
            self.homed = false;
        }
        if s.overcurrent()
            || matches!(
                s.thermal(),
                ThermalStatus::BridgeShutdown | ThermalStatus::DeviceShutdown
            )
        {
            if matches!(self.state, AxisState::Homing) {
                self.end_homing(HomingError::Fault);
            }
            self.fault = Some(if s.overcurrent() {
                AxisFault::Overcurrent
            } else {
                AxisFault::Thermal
            });
            // The power stage is in trouble: bridges off (they may already be,
            // with OC_SD), hold where the chip is, no landing move.
            if self.is_configured() && !self.chip_off_for_fault {
                self.profile.stop_now();
                self.chip_off_for_fault = true;
                self.stop_then(AfterStop::Hold, Command::HardHiZ);
            }
        } else {
            self.chip_off_for_fault = false;
        }
        self.rb.pos_at_status = self.rb.chip_pos;
    }
}
