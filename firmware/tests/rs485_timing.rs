//! The RS-485 driver's timing on the board (`drivers::rs485`): DE goes high
//! with the first byte and low only after the last stop bit (TC), at both
//! baud rates, timed with the CPU cycle counter; a response handed over
//! while the previous one still goes out is refused and counted. Board only:
//! QEMU's USART sends every byte at once. Needs no loopback: the bytes go
//! out on PA2 whatever is attached.
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
    use bridge_logic::postep60::settings::Serial;
    use firmware::drivers::rs485::Rs485;
    use firmware::pins;
    use stm32f4xx_hal::gpio::GpioExt;
    use stm32f4xx_hal::pac;

    use crate::common::{self, Target};

    pub const FRAME: [u8; 8] = [0x01, 0x03, 0x00, 0x0A, 0x00, 0x03, 0x25, 0xC9];

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

    /// Serve the driver by polling until DE is low; CPU cycles since `start`.
    pub fn finish(rs485: &mut Rs485, start: u32, sysclk_hz: u32) -> u32 {
        while rs485.is_sending() {
            rs485.on_interrupt(|_| {});
            if common::cycles_since(start) > sysclk_hz {
                defmt::panic!("still sending after 1 s");
            }
        }
        common::cycles_since(start)
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::postep60::settings::{Parity, Serial};

    use super::common::{self, Target};
    use super::support::{finish, line, FRAME};

    #[init]
    fn init() -> Target {
        common::setup()
    }

    #[test]
    fn de_is_high_from_the_first_byte_until_the_last_stop_bit(t: &mut Target) {
        for baud in [9600u32, 19200] {
            let parity = Parity::Even;
            let mut rs485 = line(t, Serial { baud, parity });
            let start = common::cycles_now();
            defmt::assert!(rs485.send(&FRAME));
            defmt::assert!(rs485.driver_enabled(), "DE high while sending");
            let cycles = u64::from(finish(&mut rs485, start, t.sysclk_hz));
            defmt::assert!(!rs485.driver_enabled());
            // 8 characters of 11 bits must all have left the shift register;
            // DE is released within the polling latency after TC.
            let sysclk = u64::from(t.sysclk_hz);
            let frame = FRAME.len() as u64 * 11 * sysclk / u64::from(baud);
            let late = sysclk / 10_000; // 100 µs
            defmt::info!(
                "{=u32} baud: DE high for {=u64} cycles, frame {=u64}",
                baud,
                cycles,
                frame
            );
            defmt::assert!(
                cycles >= frame - frame / 100,
                "DE low before the last stop bit"
            );
            defmt::assert!(cycles <= frame + late, "DE held after the frame");
        }
    }

    #[test]
    fn a_response_while_sending_is_refused_and_counted(t: &mut Target) {
        let mut rs485 = line(t, Serial::DEFAULT);
        defmt::assert!(rs485.send(&FRAME));
        defmt::assert!(!rs485.send(&FRAME));
        defmt::assert_eq!(rs485.errors().busy, 1);
        finish(&mut rs485, common::cycles_now(), t.sysclk_hz);
        defmt::assert!(rs485.send(&FRAME), "free again after the frame");
        finish(&mut rs485, common::cycles_now(), t.sysclk_hz);
    }
}
