//! The reset handoff word (`drivers::mcu`, a `.uninit` RAM word): what a run
//! stores right before `SCB::sys_reset()` is what the next run takes, once.
//! Board and QEMU (`cargo qemu-test`).
//!
//! The binary resets the MCU once on purpose, in `init` before any test
//! runs: the first run finds no handoff, stores "boot mode" and resets; the
//! run after the reset takes it and runs the tests. A word that did not
//! survive the reset would make the second run reset again, so the first
//! run also sets a second word (`ARMED`, same section): finding it without
//! a handoff fails the test instead of looping.
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
    use core::mem::MaybeUninit;
    use core::ptr::{addr_of, addr_of_mut};

    use bridge_logic::bridge::ResetTarget;

    /// `MARKER` value: this run follows the test's own reset.
    pub const ARMED: u32 = 0x4841_4E44;

    #[link_section = ".uninit.STEPBRIDGE_HANDOFF_TEST"]
    static mut MARKER: MaybeUninit<u32> = MaybeUninit::uninit();

    #[allow(unsafe_code)]
    pub fn marker() -> u32 {
        // SAFETY: a volatile word read of a static only this thread
        // touches; any bit pattern is a valid u32 (noise after power-up,
        // hence the magic value).
        unsafe { core::ptr::read_volatile(addr_of!(MARKER).cast::<u32>()) }
    }

    #[allow(unsafe_code)]
    pub fn set_marker(value: u32) {
        // SAFETY: as in `marker`.
        unsafe { core::ptr::write_volatile(addr_of_mut!(MARKER).cast::<u32>(), value) }
    }

    pub struct State {
        /// What `init` took from the handoff word after the reset.
        pub taken: Option<ResetTarget>,
        /// The reset was the test's own.
        pub armed: bool,
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::bridge::ResetTarget;
    use firmware::drivers::mcu;

    use super::common;
    use super::support::{marker, set_marker, State, ARMED};

    #[init]
    fn init() -> State {
        // First thing, as the app's `init` does.
        let taken = mcu::take_handoff();
        let armed = marker() == ARMED;
        set_marker(0);
        if taken.is_none() && !armed {
            set_marker(ARMED);
            mcu::store_handoff(ResetTarget::BootMode);
            cortex_m::peripheral::SCB::sys_reset();
        }
        common::setup();
        State { taken, armed }
    }

    #[test]
    fn the_stored_target_survives_a_system_reset(s: &mut State) {
        defmt::assert!(s.armed, "no reset by this test before");
        defmt::assert_eq!(s.taken, Some(ResetTarget::BootMode));
    }

    #[test]
    fn the_word_is_taken_once() {
        defmt::assert_eq!(mcu::take_handoff(), None);
        for target in [
            ResetTarget::Application,
            ResetTarget::BootMode,
            ResetTarget::RomDfu,
        ] {
            mcu::store_handoff(target);
            defmt::assert_eq!(mcu::take_handoff(), Some(target));
            defmt::assert_eq!(mcu::take_handoff(), None);
        }
    }
}
