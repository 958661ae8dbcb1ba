//! What reaches the chip from outside SPI: the SW input, STCK pulses and
//! injected faults (test backdoor).

use super::*;
use crate::datasheet::status::th;

impl Powerstep01 {
    // ---------------------------------------------------- environment ----

    /// Drive the SW input. Closing is the falling edge ("turn-on").
    /// A cam on the motor shaft drives the SW input: pressed while the
    /// shaft is at or below `edge` microsteps (contact closed, or open for
    /// `nc`), evaluated after every [`Powerstep01::advance`] (so the edge is
    /// seen within one advance, not on the microstep). `None` removes it.
    pub fn set_home_cam(&mut self, cam: Option<HomeCam>) {
        self.cam = cam;
        self.apply_cam();
    }

    pub(super) fn apply_cam(&mut self) {
        if let Some(c) = self.cam {
            let pressed = self.shaft <= c.edge;
            self.set_switch(pressed != c.nc);
        }
    }

    pub fn set_switch(&mut self, closed: bool) {
        let was = self.sw_closed;
        self.sw_closed = closed;
        if self.dead.is_some() || was == closed {
            return;
        }
        // SW_MODE = 0: every turn-on edge is a HardStop interrupt.
        let hard = !self.sw_user();
        if closed {
            self.sw_evn = true;
            if let Motion::Speed {
                kind: SpeedKind::GoUntil(act),
                ..
            } = self.motion
            {
                self.apply_act(act);
                if hard {
                    self.stop_now();
                } else {
                    self.motion = Motion::Stopping { hiz: false };
                    self.run_engine(0);
                }
            } else if hard && self.motion != Motion::Idle {
                self.stop_now();
            }
        } else if let Motion::Speed {
            kind: SpeedKind::ReleaseSw(act),
            ..
        } = self.motion
        {
            self.apply_act(act);
            self.stop_now();
        }
    }

    /// One STCK pulse: in step-clock mode, one microstep in DIR.
    pub fn step_clock_pulse(&mut self) {
        if self.dead.is_some() || !self.stck_mod || self.hiz {
            return;
        }
        self.frac = 0;
        self.apply_steps(self.dir, 1);
    }

    /// Inject a fault or event.
    pub fn inject(&mut self, fault: Fault) {
        match fault {
            Fault::Revive => {
                if self.dead.take().is_some() {
                    self.need = 0;
                    self.got = 0;
                    self.resp_len = 0;
                    self.resp_next = 0;
                    self.out = 0;
                }
                return;
            }
            Fault::Dead(b) => {
                self.stop_now();
                self.hiz = true;
                self.stck_mod = false;
                self.dead = Some(b);
                return;
            }
            _ => {}
        }
        if self.dead.is_some() {
            // A dead device reacts to nothing but the thermal condition.
            match fault {
                Fault::ThermalWarning => self.th_cond = th::WARNING,
                Fault::ThermalShutdown => self.th_cond = th::BRIDGE_SHUTDOWN,
                Fault::ThermalNormal => self.th_cond = th::NORMAL,
                _ => {}
            }
            return;
        }
        match fault {
            Fault::Uvlo => {
                self.uvlo = true;
                self.hiz_now();
            }
            Fault::PowerCycle => self.power_up(),
            Fault::Overcurrent => {
                self.ocd = true;
                if self.oc_shutdown() {
                    self.ocd_lock = true;
                    self.hiz_now();
                }
            }
            Fault::ThermalWarning => {
                self.th_cond = th::WARNING;
                self.th_latched = self.th_latched.max(th::WARNING);
            }
            Fault::ThermalShutdown => {
                self.th_cond = th::BRIDGE_SHUTDOWN;
                self.th_latched = self.th_latched.max(th::BRIDGE_SHUTDOWN);
                self.hiz_now();
            }
            Fault::ThermalNormal => self.th_cond = th::NORMAL,
            Fault::Stall => self.stall = true,
            Fault::AdcinLow => self.adcin_low = true,
            Fault::AdcinNormal => self.adcin_low = false,
            Fault::Dead(_) | Fault::Revive => {}
        }
    }

    pub(super) fn hiz_now(&mut self) {
        self.stop_now();
        self.stck_mod = false;
        self.hiz = true;
    }
}
