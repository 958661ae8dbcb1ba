//! The I/O extension model's GPIOB: the port's pins, BSRR and IDR, the levels on the wire (RM0090 §8).

use super::*;

impl IoModel {
    pub(super) fn gpio_write(&mut self, reg: GpioReg, value: u32) {
        let (old, width) = match reg {
            GpioReg::Moder => (self.moder, 2),
            GpioReg::Pupdr => (self.pupdr, 2),
            GpioReg::Afrh => (self.afrh, 4),
            GpioReg::Bsrr => {
                self.bsrr_write(value);
                return;
            }
            GpioReg::Idr => {
                self.violate("X12: GPIOB_IDR is read-only");
                return;
            }
        };
        if self.masked == 0 {
            self.violate(format!(
                "X12: GPIOB {reg:?} written outside the critical section"
            ));
        }
        let mut ours = 0u32;
        for p in OUR_PINS {
            let f = if width == 4 { p - 8 } else { p };
            ours |= ((1 << width) - 1) << (u32::from(f) * width);
        }
        if (old ^ value) & !ours != 0 {
            self.violate(format!(
                "X12: GPIOB {reg:?} {old:#010x} -> {value:#010x} changes another pin"
            ));
        }
        match reg {
            GpioReg::Moder => self.moder = value,
            GpioReg::Pupdr => self.pupdr = value,
            _ => self.afrh = value,
        }
        self.update_pins();
    }

    pub(super) fn bsrr_write(&mut self, value: u32) {
        let allowed = (1 << 11) | (1 << 15);
        if value & !(allowed | allowed << 16) != 0 {
            self.violate(format!("X12: GPIOB_BSRR {value:#010x} drives another pin"));
        }
        self.odr &= !(value >> 16);
        self.odr |= value & 0xFFFF;
        self.update_pins();
    }

    pub(super) fn idr(&self) -> u32 {
        (u32::from(self.cs) << 11)
            | (u32::from(self.sck) << 13)
            | (u32::from(self.chips.miso()) << 14)
            | (u32::from(self.mosi) << 15)
    }

    /// A pin nothing drives: its pull, else its last level.
    pub(super) fn undriven(&self, pin: u8, last: bool) -> bool {
        match field(self.pupdr, pin, 2) {
            0b01 => true,
            0b10 => false,
            _ => last,
        }
    }

    /// The pins' levels now; X13 on the edges, the chips on the wire.
    pub(super) fn update_pins(&mut self) {
        let spi_on = self.spi_enabled();
        let cs = match field(self.moder, 11, 2) {
            0b01 => self.odr & (1 << 11) != 0,
            // An external pull-up.
            _ => true,
        };
        let sck = match (field(self.moder, 13, 2), field(self.afrh, 5, 4)) {
            (0b01, _) => self.odr & (1 << 13) != 0,
            (0b10, 5) if spi_on => self.spi_sck,
            (0b10, 1) => match self.oc1n() {
                Some(level) => level,
                None => self.undriven(13, self.sck),
            },
            _ => self.undriven(13, self.sck),
        };
        let mosi = match (field(self.moder, 15, 2), field(self.afrh, 7, 4)) {
            (0b01, _) => self.odr & (1 << 15) != 0,
            (0b10, 5) if spi_on => self.spi_mosi,
            _ => self.undriven(15, self.mosi),
        };
        let (cs_edge, sck_edge) = (cs != self.cs, sck != self.sck);
        if cs_edge && sck_edge {
            self.violate("X13: CS and SCK change at the same instant");
        }
        if cs_edge {
            if cs {
                if self.busy() {
                    self.violate("X5: CS raised while SPI2 is busy: the last frame is cut");
                }
                let idle = self.windows.last().map(|w| w.idle);
                if idle.is_some_and(|i| i != sck) {
                    self.violate("X13: CS rose with SCK away from the level it had when CS fell");
                }
                if let Some(w) = self.windows.last_mut() {
                    w.rose = Some(self.now);
                }
            } else {
                self.windows.push(CsWindow {
                    fell: self.now,
                    rose: None,
                    idle: sck,
                    engine_start: None,
                    edges: Vec::new(),
                });
            }
            self.chips.cs_edge(cs);
            self.cs = cs;
        }
        if sck_edge {
            if self.cs && (self.frame.is_some() || self.tim_running()) {
                self.violate("X13: SCK clocked by SPI2 or TIM1 while CS is high");
            }
            if self.cs {
                self.stray_edges += 1;
            } else if let Some(w) = self.windows.last_mut() {
                w.edges.push(self.now);
            }
            if sck {
                // The chips see MOSI as it was before this instant.
                self.chips.sck_rise(self.mosi);
            }
            self.sck = sck;
        }
        self.mosi = mosi;
    }
}
