//! The independent watchdog as the board starts it (`platform::Watchdog`,
//! 6.5 s nominal, 4.4-12.2 s over the LSI's spread): fed every 100 ms it
//! never resets the MCU, even for longer than its longest timeout; left
//! unfed it resets the MCU, and the next boot reports the watchdog as the
//! reset cause. Board only: QEMU does not model the IWDG.
//!
//! The second test resets the MCU on purpose: a word in `.uninit` RAM
//! (kept through a reset) tells the run after the reset that the reset was
//! expected; that run passes both tests again and checks the reset cause.
//! It takes about 40 s.
#![cfg_attr(target_os = "none", no_std, no_main)]
#[cfg(not(target_os = "none"))]
fn main() {}

#[cfg(target_os = "none")]
mod common;

#[cfg(target_os = "none")]
mod support {
    use core::mem::MaybeUninit;
    use core::ptr::{addr_of, addr_of_mut};

    use firmware::platform::{ResetCause, Watchdog};
    use stm32f4xx_hal::pac;

    /// Longer than the longest timeout (12.2 s at the slowest LSI).
    pub const BEYOND_TIMEOUT_US: u64 = 13_000_000;
    /// `MARKER` value: a watchdog reset is expected.
    pub const ARMED: u32 = 0x5744_4F47;

    #[link_section = ".uninit.STEPBRIDGE_WATCHDOG_TEST"]
    static mut MARKER: MaybeUninit<u32> = MaybeUninit::uninit();

    #[allow(unsafe_code)]
    pub fn marker() -> u32 {
        // SAFETY: a volatile word read of a static only this thread
        // touches; any bit pattern is a valid u32 (after power-up it is
        // noise, which is why the value is a magic word).
        unsafe { core::ptr::read_volatile(addr_of!(MARKER).cast::<u32>()) }
    }

    #[allow(unsafe_code)]
    pub fn set_marker(value: u32) {
        // SAFETY: as in `marker`.
        unsafe { core::ptr::write_volatile(addr_of_mut!(MARKER).cast::<u32>(), value) }
    }

    pub struct State {
        pub iwdg: Option<pac::IWDG>,
        pub dbgmcu: pac::DBGMCU,
        pub watchdog: Option<Watchdog>,
        pub reset_cause: ResetCause,
        /// This run follows the reset the stall test provoked.
        pub after_stall: bool,
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use firmware::platform::{ResetCause, Watchdog};

    use super::common;
    use super::support::{marker, set_marker, State, ARMED, BEYOND_TIMEOUT_US};

    #[init]
    fn init() -> State {
        let t = common::setup();
        let after_stall = marker() == ARMED;
        set_marker(0);
        State {
            iwdg: Some(t.iwdg),
            dbgmcu: t.dbgmcu,
            watchdog: None,
            reset_cause: t.reset_cause,
            after_stall,
        }
    }

    #[test]
    fn fed_every_100_ms_it_never_resets_the_mcu(s: &mut State) {
        let Some(iwdg) = s.iwdg.take() else {
            defmt::panic!("IWDG taken");
        };
        let mut watchdog = Watchdog::start(iwdg, &s.dbgmcu);
        let mut waited = 0;
        while waited < BEYOND_TIMEOUT_US {
            common::spin_us(100_000);
            watchdog.feed();
            waited += 100_000;
        }
        s.watchdog = Some(watchdog);
    }

    #[test]
    fn unfed_it_resets_the_mcu(s: &mut State) {
        if s.after_stall {
            defmt::assert_eq!(s.reset_cause, ResetCause::IndependentWatchdog);
            return;
        }
        defmt::info!("stalling: the watchdog should reset the MCU within 12.2 s");
        set_marker(ARMED);
        common::spin_us(BEYOND_TIMEOUT_US);
        set_marker(0);
        defmt::panic!("no watchdog reset after 13 s without feeding");
    }
}
