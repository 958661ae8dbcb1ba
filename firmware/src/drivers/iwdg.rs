//! The independent watchdog: the PAC glue under [`drivers_core::iwdg`],
//! where the key/prescaler/reload sequence lives (tested on the host
//! against the RM0090 IWDG model, `host_tests::rm0090::iwdg`). This module
//! maps the driver's register ids to `pac::IWDG`'s registers.

// The only unsafe block is the PAC's raw register writer (`W::bits`).
#![allow(unsafe_code)]

use drivers_core::iwdg::IwdgReg;
use drivers_core::Regs;
use stm32f4xx_hal::pac::IWDG;

/// `pac::IWDG` as the driver's register port.
pub struct IwdgPeripheral(pub IWDG);

impl Regs<IwdgReg> for IwdgPeripheral {
    #[inline]
    fn read(&mut self, reg: IwdgReg) -> u32 {
        let w = &self.0;
        match reg {
            IwdgReg::Kr => 0,
            IwdgReg::Pr => u32::from(w.pr().read().bits()),
            IwdgReg::Rlr => u32::from(w.rlr().read().bits()),
            IwdgReg::Sr => u32::from(w.sr().read().bits()),
        }
    }

    #[inline]
    fn write(&mut self, reg: IwdgReg, value: u32) {
        let w = &self.0;
        // The IWDG registers are 16 bits wide (RM0090 §21.4).
        let v = value as u16;
        // SAFETY: one volatile write of the whole register; the values come
        // from `drivers_core::iwdg` (the RM0090 keys, PR ≤ 6, RLR ≤ 0xFFF),
        // checked against the RM0090 model on the host. SR is read-only.
        unsafe {
            match reg {
                IwdgReg::Kr => w.kr().write(|x| x.bits(v)),
                IwdgReg::Pr => w.pr().write(|x| x.bits(v)),
                IwdgReg::Rlr => w.rlr().write(|x| x.bits(v)),
                IwdgReg::Sr => 0,
            };
        }
    }
}
