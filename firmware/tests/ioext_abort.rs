//! The I/O extension driver (`drivers::ioext_spi`, the board's code) under
//! QEMU, which models SPI2's registers but has no DMA controller and no
//! TIM1: every transfer starts and never ends, which is exactly the case
//! the app's timeout handles. Checked here: the SPI engine programs SPI2 as
//! the plan says (CR1 master, software NSS, BR, CPOL/CPHA, enabled; CR2 DMA
//! requests on while running, off after); `abort` stops a transfer that did
//! not end and reports `Timeout`; a second start while one runs is refused
//! (`Busy`); Disable releases the port and the next transfer starts again.
//! QEMU only (feature `qemu`): on a board the DMA ends every transfer
//! (`tests/ioext_spi.rs`). QEMU does not model GPIO levels, so CS is checked
//! there, not here.
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
    use bridge_logic::ioext::{Action, Clocks, SpiMode, TransferPlan, WireBits};
    use stm32f4xx_hal::pac;

    pub fn plan(bits: u16, mode: SpiMode, n: u8) -> Action {
        let tx = WireBits::from_fn(bits, |i| i % 3 == 0);
        Action::Transfer(TransferPlan::single(bits, mode, n, Clocks::BOARD, tx))
    }

    pub fn spi2() -> &'static pac::spi1::RegisterBlock {
        #[allow(unsafe_code)]
        // SAFETY: reads of SPI2 registers only.
        unsafe {
            &*pac::SPI2::ptr()
        }
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::ioext::{Action, SpiMode};
    use firmware::drivers::ioext_spi::{IoExtError, IoExtPort, Started};

    use super::common;
    use super::support::{plan, spi2};

    #[init]
    fn init() -> IoExtPort {
        common::ioext_port(common::setup())
    }

    #[test]
    fn the_spi_engine_programs_spi2_as_the_plan_says(port: &mut IoExtPort) {
        // (mode, N, CR1.BR): N = 0 → /2, N = 5 → /32, N = 50 → /256.
        for (mode, n, br) in [
            (SpiMode::MODE0, 0u8, 0u16),
            (SpiMode::MODE3, 5, 4),
            (SpiMode::MODE1, 50, 7),
        ] {
            defmt::assert_eq!(port.run(&plan(256, mode, n)), Started::Running);
            let cr1 = spi2().cr1().read().bits();
            defmt::assert_eq!(cr1 & 1, u16::from(mode.cpha), "CPHA");
            defmt::assert_eq!((cr1 >> 1) & 1, u16::from(mode.cpol), "CPOL");
            defmt::assert!(cr1 & (1 << 2) != 0, "master");
            defmt::assert_eq!((cr1 >> 3) & 0b111, br, "BR");
            defmt::assert!(cr1 & (1 << 6) != 0, "enabled");
            defmt::assert_eq!(cr1 & (1 << 7), 0, "MSB first");
            defmt::assert_eq!(cr1 & (0b11 << 8), 0b11 << 8, "software NSS, high");
            defmt::assert_eq!(cr1 & (1 << 11), 0, "8-bit frames");
            defmt::assert_eq!(spi2().cr2().read().bits() & 0b11, 0b11, "RX and TX DMA on");
            defmt::assert_eq!(port.abort(), Some(Err(IoExtError::Timeout)));
            defmt::assert_eq!(spi2().cr2().read().bits() & 0b11, 0, "DMA requests off");
            defmt::assert!(!port.is_running());
        }
    }

    #[test]
    fn a_transfer_that_never_ends_is_aborted_as_a_timeout(port: &mut IoExtPort) {
        // SPI engine (256 bits) and bit engine (37 bits, 9 bits at N = 255).
        for action in [
            plan(256, SpiMode::MODE0, 1),
            plan(37, SpiMode::MODE0, 5),
            plan(9, SpiMode::MODE2, 255),
        ] {
            defmt::assert_eq!(port.run(&action), Started::Running);
            defmt::assert!(port.is_running());
            defmt::assert_eq!(port.on_interrupt(), None, "no DMA end under QEMU");
            defmt::assert_eq!(port.abort(), Some(Err(IoExtError::Timeout)));
            defmt::assert!(!port.is_running());
            defmt::assert_eq!(port.abort(), None, "nothing left to abort");
        }
    }

    #[test]
    fn a_second_start_while_one_runs_is_refused(port: &mut IoExtPort) {
        defmt::assert_eq!(port.run(&plan(16, SpiMode::MODE0, 5)), Started::Running);
        defmt::assert_eq!(
            port.run(&plan(16, SpiMode::MODE0, 5)),
            Started::Ended(Err(IoExtError::Busy))
        );
        defmt::assert_eq!(port.abort(), Some(Err(IoExtError::Timeout)));
    }

    #[test]
    fn disable_releases_the_port_and_the_next_transfer_starts(port: &mut IoExtPort) {
        defmt::assert_eq!(port.run(&Action::Disable), Started::Released);
        defmt::assert_eq!(spi2().cr1().read().bits() & (1 << 6), 0, "SPI2 off");
        defmt::assert_eq!(port.run(&plan(8, SpiMode::MODE3, 5)), Started::Running);
        defmt::assert!(spi2().cr1().read().bits() & (1 << 6) != 0, "SPI2 on again");
        defmt::assert_eq!(port.abort(), Some(Err(IoExtError::Timeout)));
    }
}
