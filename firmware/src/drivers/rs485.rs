//! USART2 and the RS-485 transceiver's DE line (PA1): the PAC glue under
//! [`drivers_core::rs485`], where the configuration, receive and
//! TXE/TC/DE sequences live (and are tested on the host against the RM0090
//! USART model, `host_tests::rm0090::usart`). This module enables and
//! resets USART2 through the RCC, maps the driver's register ids to
//! `pac::USART2`'s registers and drives PA1. The pins come configured from
//! `crate::pins` (TX/RX in AF7, DE low).

// The only unsafe block is the PAC's raw register writer (`W::bits`).
#![allow(unsafe_code)]

use bridge_logic::postep60::settings::Serial;
use drivers_core::rs485::{Rs485Port, UsartReg};
use drivers_core::Regs;
use stm32f4xx_hal::rcc::{Enable, Rcc, Reset};

use crate::pins::{ModbusDe, ModbusRx, ModbusTx, ModbusUsart};

pub use drivers_core::rs485::{Rx, RxErrors};

/// USART2, its pins and DE, as the driver's [`Rs485Port`].
pub struct Usart2Port {
    usart: ModbusUsart,
    _pins: (ModbusTx, ModbusRx),
    de: ModbusDe,
}

impl Regs<UsartReg> for Usart2Port {
    #[inline]
    fn read(&mut self, reg: UsartReg) -> u32 {
        let u = &self.usart;
        u32::from(match reg {
            UsartReg::Sr => u.sr().read().bits(),
            UsartReg::Dr => u.dr().read().bits(),
            UsartReg::Brr => u.brr().read().bits(),
            UsartReg::Cr1 => u.cr1().read().bits(),
            UsartReg::Cr2 => u.cr2().read().bits(),
            UsartReg::Cr3 => u.cr3().read().bits(),
            UsartReg::Gtpr => u.gtpr().read().bits(),
        })
    }

    #[inline]
    fn write(&mut self, reg: UsartReg, value: u32) {
        let u = &self.usart;
        // The USART registers are 16 bits wide (RM0090 §30.6).
        let v = value as u16;
        // SAFETY: one volatile write of the whole register. The values come
        // from `drivers_core::rs485` (the RM0090 configuration order, BRR
        // from the APB1 clock, interrupt enables by read-modify-write, data
        // bytes), checked against the RM0090 model on the host.
        unsafe {
            match reg {
                UsartReg::Sr => u.sr().write(|w| w.bits(v)),
                UsartReg::Dr => u.dr().write(|w| w.bits(v)),
                UsartReg::Brr => u.brr().write(|w| w.bits(v)),
                UsartReg::Cr1 => u.cr1().write(|w| w.bits(v)),
                UsartReg::Cr2 => u.cr2().write(|w| w.bits(v)),
                UsartReg::Cr3 => u.cr3().write(|w| w.bits(v)),
                UsartReg::Gtpr => u.gtpr().write(|w| w.bits(v)),
            };
        }
    }
}

impl Rs485Port for Usart2Port {
    #[inline]
    fn set_de(&mut self, high: bool) {
        if high {
            self.de.set_high();
        } else {
            self.de.set_low();
        }
    }

    #[inline]
    fn de_is_high(&self) -> bool {
        self.de.is_set_high()
    }
}

/// USART2 with the transceiver's DE line (`drivers_core::rs485`).
pub struct Rs485(drivers_core::rs485::Rs485<Usart2Port>);

impl Rs485 {
    /// Enable and reset USART2 through the RCC, configure it for
    /// `settings` on the real APB1 clock and start receiving (RXNE
    /// interrupt on). `de` must be low.
    pub fn new(
        usart: ModbusUsart,
        pins: (ModbusTx, ModbusRx),
        de: ModbusDe,
        settings: Serial,
        rcc: &mut Rcc,
    ) -> Rs485 {
        ModbusUsart::enable(rcc);
        ModbusUsart::reset(rcc);
        let pclk1 = rcc.clocks.pclk1().raw();
        let port = Usart2Port {
            usart,
            _pins: pins,
            de,
        };
        Rs485(drivers_core::rs485::Rs485::new(port, pclk1, settings))
    }

    /// Whether DE (the transceiver's driver enable) is driven high now.
    pub fn driver_enabled(&self) -> bool {
        self.0.driver_enabled()
    }

    /// False if the configuration was refused (nothing is ever received).
    pub fn is_configured(&self) -> bool {
        self.0.is_configured()
    }

    /// True from [`Rs485::send`] until DE is released after the last stop bit.
    pub fn is_sending(&self) -> bool {
        self.0.is_sending()
    }

    pub fn errors(&self) -> RxErrors {
        self.0.errors()
    }

    /// The USART2 interrupt: received bytes to `on_rx`, the transmission on.
    pub fn on_interrupt(&mut self, on_rx: impl FnMut(Rx)) {
        self.0.on_interrupt(on_rx);
    }

    /// Start sending `adu` (see `drivers_core::rs485::Rs485::send`).
    pub fn send(&mut self, adu: &[u8]) -> bool {
        self.0.send(adu)
    }
}
