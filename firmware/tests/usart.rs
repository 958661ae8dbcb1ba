//! The Modbus line's USART2 (`drivers::rs485`) on the target: the character
//! format of every serial setting in the registers (baud rate from the real
//! APB1 clock), a frame goes out and DE is low again afterwards, and frames
//! the driver cannot send are refused without touching the line. Board and
//! QEMU (`cargo qemu-test`). The timing (DE until the last stop bit) is the
//! board-only `rs485_timing`.
#![cfg_attr(target_os = "none", no_std, no_main)]
// An on-target test, not bus input: it may index, unwrap, panic and (like
// the drivers) touch registers in `unsafe` blocks.
#![allow(unsafe_code, clippy::indexing_slicing, clippy::arithmetic_side_effects)]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#[cfg(not(target_os = "none"))]
fn main() {}

#[cfg(target_os = "none")]
mod common;

#[cfg(target_os = "none")]
mod support {
    use bridge_logic::postep60::settings::{Parity, Serial};
    use firmware::drivers::clock;
    use firmware::drivers::rs485::Rs485;
    use firmware::pins;
    use stm32f4xx_hal::gpio::GpioExt;
    use stm32f4xx_hal::pac;

    use crate::common::Target;

    #[rustfmt::skip]
    pub const SETTINGS: [Serial; 6] = [
        Serial { baud: 9600, parity: Parity::Even },
        Serial { baud: 9600, parity: Parity::Odd },
        Serial { baud: 9600, parity: Parity::None },
        Serial { baud: 19200, parity: Parity::Even },
        Serial { baud: 19200, parity: Parity::Odd },
        Serial { baud: 19200, parity: Parity::None },
    ];

    // USART_CR1 / CR2 bits (RM0090).
    pub const CR1_OVER8: u32 = 1 << 15;
    pub const CR1_UE: u32 = 1 << 13;
    pub const CR1_M: u32 = 1 << 12;
    pub const CR1_PCE: u32 = 1 << 10;
    pub const CR1_PS: u32 = 1 << 9;
    pub const CR1_RXNEIE: u32 = 1 << 5;
    pub const CR1_TE: u32 = 1 << 3;
    pub const CR1_RE: u32 = 1 << 2;
    pub const CR2_STOP: u32 = 0b11 << 12;
    pub const CR2_STOP_2: u32 = 0b10 << 12;

    /// A fresh driver for `serial` on USART2 and the Modbus pins taken anew
    /// (the previous one has gone out of scope).
    #[allow(unsafe_code)]
    pub fn line(t: &mut Target, serial: Serial) -> Rs485 {
        // SAFETY: this test is the only user of USART2 and GPIOA: the
        // Target's own Modbus pins and USART2 are never used, and every
        // earlier driver built here has been dropped. `split` resets GPIOA,
        // which only this test's pins depend on.
        let (usart, gpioa) = unsafe { (pac::USART2::steal(), pac::GPIOA::steal()) };
        let gpioa = gpioa.split(&mut t.rcc);
        let (tx, rx, de) = pins::modbus_pins(gpioa.pa2, gpioa.pa3, gpioa.pa1);
        Rs485::new(usart, (tx, rx), de, serial, &mut t.rcc)
    }

    /// (CR1, CR2, BRR) of USART2.
    #[allow(unsafe_code)]
    pub fn usart2() -> (u32, u32, u32) {
        // SAFETY: read-only register access.
        let regs = unsafe { &*pac::USART2::ptr() };
        (
            u32::from(regs.cr1().read().bits()),
            u32::from(regs.cr2().read().bits()),
            u32::from(regs.brr().read().bits()),
        )
    }

    /// Serve the driver by polling until DE is low; false after `timeout_us`.
    pub fn finish(rs485: &mut Rs485, timeout_us: u64) -> bool {
        let start = clock::now_us();
        while rs485.is_sending() {
            rs485.on_interrupt(|_| {});
            if clock::now_us().saturating_sub(start) > timeout_us {
                return false;
            }
        }
        true
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::postep60::settings::{Parity, Serial};
    use bridge_logic::transport::modbus::ADU_MAX;

    use super::common::{self, Target};
    use super::support::*;

    #[init]
    fn init() -> Target {
        common::setup()
    }

    #[test]
    fn every_serial_setting_is_an_11_bit_character_at_its_baud_rate(t: &mut Target) {
        let pclk1 = t.rcc.clocks.pclk1().raw();
        for serial in SETTINGS {
            let rs485 = line(t, serial);
            defmt::assert!(rs485.is_configured());
            let (cr1, cr2, brr) = usart2();
            let on = CR1_UE | CR1_TE | CR1_RE | CR1_RXNEIE;
            defmt::assert_eq!(cr1 & on, on);
            defmt::assert_eq!(cr1 & CR1_OVER8, 0);
            let format = cr1 & (CR1_M | CR1_PCE | CR1_PS);
            // With parity the USART counts it as a ninth data bit.
            match serial.parity {
                Parity::Even => defmt::assert_eq!(format, CR1_M | CR1_PCE),
                Parity::Odd => defmt::assert_eq!(format, CR1_M | CR1_PCE | CR1_PS),
                Parity::None => defmt::assert_eq!(format, 0),
            }
            let stop = if serial.parity == Parity::None {
                CR2_STOP_2
            } else {
                0
            };
            defmt::assert_eq!(cr2 & CR2_STOP, stop);
            // Oversampling by 16: baud = PCLK1 / BRR, within 0.5 %.
            defmt::assert!(brr > 0);
            let actual = pclk1 / brr;
            defmt::assert!(
                actual.abs_diff(serial.baud) * 200 <= serial.baud,
                "{=u32} baud set as {=u32} (BRR {=u32}, PCLK1 {=u32})",
                serial.baud,
                actual,
                brr,
                pclk1
            );
        }
    }

    #[test]
    fn a_frame_goes_out_and_de_is_low_afterwards(t: &mut Target) {
        for serial in SETTINGS {
            let mut rs485 = line(t, serial);
            defmt::assert!(rs485.send(&[0x01, 0x03, 0x00, 0x0A, 0x00, 0x03, 0x25, 0xC9]));
            // 8 characters of 11 bits: 9.2 ms at 9600 baud.
            defmt::assert!(finish(&mut rs485, 50_000), "still sending after 50 ms");
            defmt::assert!(!rs485.driver_enabled());
            defmt::assert_eq!(rs485.errors().total(), 0);
        }
    }

    #[test]
    fn frames_it_cannot_send_are_refused(t: &mut Target) {
        let mut rs485 = line(t, Serial::DEFAULT);
        defmt::assert!(!rs485.send(&[]));
        defmt::assert!(!rs485.send(&[0u8; ADU_MAX + 1]));
        defmt::assert!(!rs485.is_sending());
        defmt::assert!(!rs485.driver_enabled());
        // The largest frame goes (293 ms at 9600 baud).
        defmt::assert!(rs485.send(&[0u8; ADU_MAX]));
        defmt::assert!(finish(&mut rs485, 500_000), "still sending after 500 ms");
    }
}
