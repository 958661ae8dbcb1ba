//! The switch-off path (`failsafe::chips_off`, the first thing the panic
//! handler and the HardFault handler do): it drives the chain's STBY/RESET
//! pin low — the pad itself, read back through GPIOC_IDR — from any state,
//! and changes no other pin. Board only: QEMU models no GPIO levels (its
//! panic path is `panic_path`).
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
    use stm32f4xx_hal::pac;

    /// STBY is PC4 (`pins::ChainStby`).
    pub const STBY: u32 = 1 << 4;

    /// (ODR, MODER, IDR) of GPIOA, GPIOB, GPIOC.
    #[allow(unsafe_code)]
    pub fn ports() -> [(u32, u32, u32); 3] {
        // SAFETY: read-only register access; the three ports share one
        // register layout.
        let regs = unsafe {
            [
                &*pac::GPIOA::ptr(),
                &*pac::GPIOB::ptr().cast::<pac::gpioa::RegisterBlock>(),
                &*pac::GPIOC::ptr().cast::<pac::gpioa::RegisterBlock>(),
            ]
        };
        regs.map(|r| {
            (
                r.odr().read().bits(),
                r.moder().read().bits(),
                r.idr().read().bits(),
            )
        })
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use firmware::failsafe;

    use super::common::{self, Target};
    use super::support::{ports, STBY};

    #[init]
    fn init() -> Target {
        common::setup()
    }

    #[test]
    fn chips_off_drives_stby_low_at_the_pad(t: &mut Target) {
        t.pins.chain_stby.set_high();
        cortex_m::asm::delay(100);
        defmt::assert!(
            ports()[2].2 & STBY != 0,
            "STBY does not rise: short to ground?"
        );
        failsafe::chips_off();
        cortex_m::asm::delay(100);
        let (odr, _, idr) = ports()[2];
        defmt::assert_eq!(odr & STBY, 0);
        defmt::assert_eq!(idr & STBY, 0);
    }

    #[test]
    fn chips_off_changes_no_other_pin(t: &mut Target) {
        t.pins.chain_stby.set_high();
        t.pins.led.set_high();
        let before = ports();
        failsafe::chips_off();
        let after = ports();
        for (port, (b, a)) in before.iter().zip(after.iter()).enumerate() {
            let stby = if port == 2 { STBY } else { 0 };
            defmt::assert_eq!(a.0 | stby, b.0 | stby, "ODR of port {=usize}", port);
            defmt::assert_eq!(a.1, b.1, "MODER of port {=usize}", port);
        }
        t.pins.led.set_low();
    }

    #[test]
    fn chips_off_keeps_a_low_stby_low(t: &mut Target) {
        t.pins.chain_stby.set_low();
        failsafe::chips_off();
        defmt::assert_eq!(ports()[2].0 & STBY, 0);
    }
}
