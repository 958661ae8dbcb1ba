//! The I/O extension's port (`drivers::ioext_spi`) on the board, with a
//! loopback jumper **PB15 (MOSI) → PB14 (MISO)** and nothing else on the
//! port (CS on PB11 may stay open): what goes out comes back, on the SPI
//! engine (SPI2 + DMA1) and on the bit engine (TIM1 + DMA2), in all four
//! SPI modes; the DMA transfer-complete interrupt is raised (checked as the
//! NVIC pending bit of `DMA1_STREAM3` / `DMA2_STREAM2`, left masked so the
//! test itself finishes the transfer as the app's task would); CS ends high
//! (or held low when the plan says so); a transfer takes at least its
//! nominal time; Disable releases SCK and MOSI. Board only: QEMU 7.2 has no
//! DMA controller and no TIM1, and does not model GPIO levels.
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
    use cortex_m::peripheral::NVIC;
    use firmware::drivers::clock;
    use firmware::drivers::ioext_spi::{IoExtError, IoExtPort, Started};
    use stm32f4xx_hal::pac::{self, Interrupt};

    pub struct State {
        pub port: IoExtPort,
        pub sysclk_hz: u32,
    }

    /// CS is PB11 (`pins::IoExtCs`).
    const CS: u32 = 1 << 11;

    fn gpiob() -> &'static pac::gpiob::RegisterBlock {
        #[allow(unsafe_code)]
        // SAFETY: reads of GPIOB registers only.
        unsafe {
            &*pac::GPIOB::ptr()
        }
    }

    pub fn cs_is_high() -> bool {
        gpiob().idr().read().bits() & CS != 0
    }

    /// MODER field of GPIOB pin `n`.
    pub fn mode_of(n: u32) -> u32 {
        (gpiob().moder().read().bits() >> (2 * n)) & 0b11
    }

    /// A plan of `bits` bits with a pattern that is neither all 0 nor all 1
    /// in any byte.
    pub fn plan(
        bits: u16,
        mode: SpiMode,
        n: u8,
        cs_low_before: bool,
        cs_hold: bool,
    ) -> TransferPlan {
        let tx = WireBits::from_fn(bits, |i| (i * 7 + 3) % 5 < 2);
        TransferPlan {
            cs_low_before,
            cs_hold,
            ..TransferPlan::single(bits, mode, n, Clocks::BOARD, tx)
        }
    }

    /// The interrupt that ends `plan`.
    pub fn end_irq(plan: &TransferPlan) -> Interrupt {
        if plan.spi().is_some() {
            Interrupt::DMA1_STREAM3
        } else {
            Interrupt::DMA2_STREAM2
        }
    }

    /// Run `plan` to its end as the app does, but with the interrupt
    /// masked: wait for it to be pending, then finish the transfer.
    pub fn transfer(port: &mut IoExtPort, plan: TransferPlan) -> Result<WireBits, IoExtError> {
        let irq = end_irq(&plan);
        NVIC::unpend(irq);
        match port.run(&Action::Transfer(plan)) {
            Started::Running => {}
            Started::Ended(r) => return r,
            Started::Released => defmt::panic!("a transfer released the port"),
        }
        let start = clock::now_us();
        while !NVIC::is_pending(irq) {
            if clock::now_us().saturating_sub(start) > plan.timeout_us() {
                defmt::error!("no {} within {=u64} us", irq, plan.timeout_us());
                return port.abort().unwrap_or(Err(IoExtError::Timeout));
            }
        }
        let r = port.on_interrupt();
        NVIC::unpend(irq);
        r.unwrap_or(Err(IoExtError::Timeout))
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::ioext::{Action, SpiMode};
    use firmware::drivers::ioext_spi::Started;

    use super::common;
    use super::support::{cs_is_high, mode_of, plan, transfer, State};

    #[init]
    fn init() -> State {
        let t = common::setup();
        let sysclk_hz = t.sysclk_hz;
        State {
            port: common::ioext_port(t),
            sysclk_hz,
        }
    }

    #[test]
    fn spi_engine_loops_back_in_every_mode_and_cs_ends_high(s: &mut State) {
        for mode in SpiMode::ALL {
            // N = 5: SPI2 /32 (1.3125 MHz); 256 bits = 32 DMA frames.
            let p = plan(256, mode, 5, false, false);
            defmt::assert!(p.spi().is_some());
            let rx = defmt::unwrap!(transfer(&mut s.port, p));
            defmt::assert_eq!(rx, p.tx, "mode {}", mode);
            defmt::assert!(cs_is_high());
        }
    }

    #[test]
    fn bit_engine_loops_back_in_every_mode_and_cs_ends_high(s: &mut State) {
        for mode in SpiMode::ALL {
            // 37 bits: not a multiple of 8, so TIM1 (1 µs floor at N = 5).
            for (bits, n) in [(37u16, 5u8), (9, 61)] {
                let p = plan(bits, mode, n, false, false);
                defmt::assert!(p.timer().is_some());
                let rx = defmt::unwrap!(transfer(&mut s.port, p));
                defmt::assert_eq!(rx, p.tx, "{=u16} bits, mode {}", bits, mode);
                defmt::assert!(cs_is_high());
            }
        }
    }

    #[test]
    fn a_transfer_takes_at_least_its_nominal_time(s: &mut State) {
        // SPI /256 and the bit engine at N = 20 (2.02 µs).
        for p in [
            plan(64, SpiMode::MODE0, 50, false, false),
            plan(15, SpiMode::MODE3, 20, false, false),
        ] {
            let start = common::cycles_now();
            let rx = defmt::unwrap!(transfer(&mut s.port, p));
            let cycles = u64::from(common::cycles_since(start));
            let nominal = p.nominal_ns() * u64::from(s.sysclk_hz) / 1_000_000_000;
            defmt::info!(
                "{=u16} bits: {=u64} cycles, nominal {=u64}",
                p.bits,
                cycles,
                nominal
            );
            defmt::assert_eq!(rx, p.tx);
            defmt::assert!(cycles >= nominal);
        }
    }

    #[test]
    fn cs_stays_low_while_held_and_rises_after_the_last_transfer(s: &mut State) {
        for n in [5u8, 61] {
            let first = plan(16, SpiMode::MODE0, n, false, true);
            defmt::assert_eq!(defmt::unwrap!(transfer(&mut s.port, first)), first.tx);
            defmt::assert!(!cs_is_high(), "held low");
            let second = plan(16, SpiMode::MODE0, n, true, false);
            defmt::assert_eq!(defmt::unwrap!(transfer(&mut s.port, second)), second.tx);
            defmt::assert!(cs_is_high());
        }
    }

    #[test]
    fn disable_raises_cs_and_releases_sck_and_mosi(s: &mut State) {
        let p = plan(8, SpiMode::MODE3, 5, false, true);
        defmt::assert_eq!(defmt::unwrap!(transfer(&mut s.port, p)), p.tx);
        defmt::assert!(!cs_is_high());
        defmt::assert_eq!(s.port.run(&Action::Disable), Started::Released);
        defmt::assert!(cs_is_high());
        defmt::assert_eq!(mode_of(13), 0b00, "SCK an input");
        defmt::assert_eq!(mode_of(15), 0b00, "MOSI an input");
        // And the port comes back for the next transfer.
        let p = plan(8, SpiMode::MODE0, 5, false, false);
        defmt::assert_eq!(defmt::unwrap!(transfer(&mut s.port, p)), p.tx);
    }
}
