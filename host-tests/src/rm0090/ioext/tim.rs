//! The I/O extension model's TIM1: the bit engine's counter, OC1REF on CH1N, its DMA requests (RM0090 §17).

use super::*;

impl IoModel {
    pub(super) fn tim_sync(&mut self) {
        if self.tim_running() {
            let ticks = (self.now - self.tim_at) / self.tim_tick();
            let period = u64::from(self.tim_arr) + 1;
            let cnt = (u64::from(self.tim_cnt) + ticks) % period;
            self.tim_at += ticks * self.tim_tick();
            self.tim_cnt = cnt as u32;
        }
    }

    pub(super) fn oc1m(&self) -> u32 {
        (self.tim_ccmr1 & TIM_CCMR1_OC1M_MASK) >> TIM_CCMR1_OC1M_SHIFT
    }

    /// X11: OC1REF from the mode and the counter.
    pub(super) fn eval_oc1ref(&mut self) {
        self.oc1ref = match self.oc1m() {
            0b100 => false,
            0b101 => true,
            0b110 => self.tim_cnt < self.tim_ccr[0],
            0b111 => self.tim_cnt >= self.tim_ccr[0],
            _ => self.oc1ref,
        };
    }

    /// X10, X11: CNT reached `v` (ARR + 1: the overflow).
    pub(super) fn tim_event(&mut self, v: u32) {
        if let Some((_, at)) = self.tim_next() {
            self.tim_at = at;
        }
        if v > self.tim_arr {
            self.tim_cnt = 0;
            if self.tim_rep == 0 {
                // The update event.
                self.tim_sr |= 1;
                self.tim_rep = self.tim_rcr;
                self.tim_psc_live = self.tim_psc;
                if self.tim_cr1 & TIM_CR1_OPM != 0 {
                    self.tim_cr1 &= !TIM_CR1_CEN;
                }
            } else {
                self.tim_rep -= 1;
            }
        } else {
            self.tim_cnt = v;
        }
        self.eval_oc1ref();
        let cnt = self.tim_cnt;
        for (ch, (de, req)) in [
            (TIM_DIER_CC2DE, Request::TimCh2),
            (TIM_DIER_CC3DE, Request::TimCh3),
        ]
        .into_iter()
        .enumerate()
        {
            if self.tim_ccr[ch + 1] == cnt && (v <= self.tim_arr || cnt == 0) {
                self.tim_sr |= 1 << (ch + 2);
                if self.tim_dier & de != 0 {
                    self.timer_request(req);
                }
            }
        }
        self.update_pins();
    }

    pub(super) fn timer_request(&mut self, req: Request) {
        let (ctl, s) = match req {
            Request::TimCh2 => (1, 2),
            _ => (1, 6),
        };
        let st = self.dma[ctl].streams[s];
        let ok = st.cr & DMA_CR_EN != 0
            && (st.cr & DMA_CR_CHSEL_MASK) >> DMA_CR_CHSEL_SHIFT == req.channel();
        // A stream that stopped itself on a bus error loses the rest: that
        // is the error's effect, which the driver reports, not a new one.
        let faulted = self.dma[ctl].flags(s as u8).intersects(Flags::TEIF);
        if !ok && faulted {
            return;
        }
        if !ok {
            self.violate(format!(
                "X11: {} request with DMA2 stream {s} not ready for it: lost",
                req.name()
            ));
            return;
        }
        if st.pending.is_some() {
            self.violate(format!(
                "X11: {} request while the last one is still pending: lost",
                req.name()
            ));
            return;
        }
        if !st.stalled {
            self.dma[ctl].streams[s].pending = Some(self.now + DMA_LATENCY);
        }
    }

    pub(super) fn tim_write(&mut self, reg: TimReg, value: u32) {
        self.tim_sync();
        let period_reg = matches!(
            reg,
            TimReg::Psc
                | TimReg::Arr
                | TimReg::Rcr
                | TimReg::Ccr1
                | TimReg::Ccr2
                | TimReg::Ccr3
                | TimReg::Ccmr1
                | TimReg::Ccmr2
                | TimReg::Ccer
        );
        // The mode change that starts or ends a transfer is allowed: OC1M
        // to PWM 2 before CEN, to forced inactive in a stop.
        if period_reg && self.tim_running() && reg != TimReg::Ccmr1 {
            self.violate(format!("X11: TIM1 {reg:?} written while CEN = 1"));
        }
        match reg {
            TimReg::Cr1 => {
                let was = self.tim_running();
                self.tim_cr1 = value & 0x3FF;
                if !was && self.tim_running() {
                    self.tim_at = self.now;
                    self.engine_started();
                }
            }
            TimReg::Dier => self.tim_dier = value & 0x7FFF,
            TimReg::Sr => self.tim_sr &= value,
            TimReg::Egr => {
                if value & TIM_EGR_UG != 0 {
                    self.tim_cnt = 0;
                    self.tim_at = self.now;
                    self.tim_psc_live = self.tim_psc;
                    self.tim_rep = self.tim_rcr;
                    self.tim_sr |= 1;
                }
            }
            TimReg::Ccmr1 => self.tim_ccmr1 = value,
            TimReg::Ccmr2 => self.tim_ccmr2 = value,
            TimReg::Ccer => self.tim_ccer = value,
            TimReg::Cnt => self.tim_cnt = value & 0xFFFF,
            TimReg::Psc => self.tim_psc = value & 0xFFFF,
            TimReg::Arr => self.tim_arr = value & 0xFFFF,
            TimReg::Rcr => self.tim_rcr = value & 0xFF,
            TimReg::Ccr1 => self.tim_ccr[0] = value & 0xFFFF,
            TimReg::Ccr2 => self.tim_ccr[1] = value & 0xFFFF,
            TimReg::Ccr3 => self.tim_ccr[2] = value & 0xFFFF,
            TimReg::Bdtr => self.tim_bdtr = value,
        }
        self.eval_oc1ref();
    }

    pub(super) fn tim_read(&mut self, reg: TimReg) -> u32 {
        self.tim_sync();
        match reg {
            TimReg::Cr1 => self.tim_cr1,
            TimReg::Dier => self.tim_dier,
            TimReg::Sr => self.tim_sr,
            TimReg::Egr => 0,
            TimReg::Ccmr1 => self.tim_ccmr1,
            TimReg::Ccmr2 => self.tim_ccmr2,
            TimReg::Ccer => self.tim_ccer,
            TimReg::Cnt => self.tim_cnt,
            TimReg::Psc => self.tim_psc,
            TimReg::Arr => self.tim_arr,
            TimReg::Rcr => self.tim_rcr,
            TimReg::Ccr1 => self.tim_ccr[0],
            TimReg::Ccr2 => self.tim_ccr[1],
            TimReg::Ccr3 => self.tim_ccr[2],
            TimReg::Bdtr => self.tim_bdtr,
        }
    }

    /// X11: CH1N's level, if it drives the pin.
    pub(super) fn oc1n(&self) -> Option<bool> {
        let drives = self.tim_bdtr & TIM_BDTR_MOE != 0
            && self.tim_ccer & TIM_CCER_CC1NE != 0
            && self.tim_ccer & TIM_CCER_CC1E == 0;
        drives.then_some(self.oc1ref ^ (self.tim_ccer & TIM_CCER_CC1NP != 0))
    }
}
