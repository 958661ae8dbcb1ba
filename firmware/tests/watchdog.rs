//! The independent watchdog as the board runs it (`platform::Watchdog`):
//! started in the long window (6.5 s nominal, 4.4-12.2 s over the LSI's
//! spread) it never resets the MCU fed every 100 ms, even for longer than
//! its longest timeout, and outlasts a save's longest stall unfed; in the
//! short window (25 ms nominal, 16.9-47.1 ms) it never resets the MCU fed
//! at the slowest tick's period, nor with feeds seven periods late; back in
//! the long window it outlasts the stall again; left unfed in the short
//! window it resets the MCU within the short window's bounds, and the next
//! boot reports the watchdog as the reset cause. Board only: QEMU does not
//! model the IWDG.
//!
//! The last test resets the MCU on purpose: two words in `.uninit` RAM
//! (kept through a reset) tell the run after the reset that the reset was
//! expected and how long after the last feed it came at the latest; that
//! run passes the other tests again and checks the reset cause and the
//! time. It takes about 50 s.
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

    use bridge_logic::bridge::ResetCause;
    use firmware::platform::Watchdog;
    use stm32f4xx_hal::pac;

    /// Longer than the long window's longest timeout (12.2 s at the
    /// slowest LSI).
    pub const BEYOND_LONG_US: u64 = 13_000_000;
    /// `MARKER` value: a watchdog reset is expected.
    pub const ARMED: u32 = 0x5744_4F47;

    #[link_section = ".uninit.STEPBRIDGE_WATCHDOG_TEST"]
    static mut MARKER: MaybeUninit<u32> = MaybeUninit::uninit();
    /// µs since the last feed, written while the stall test waits for the
    /// reset: the reset came at most one step after the last value.
    #[link_section = ".uninit.STEPBRIDGE_WATCHDOG_TEST_US"]
    static mut UNFED_US: MaybeUninit<u32> = MaybeUninit::uninit();

    #[allow(unsafe_code)]
    fn read(word: *const MaybeUninit<u32>) -> u32 {
        // SAFETY: a volatile word read of a static only this thread
        // touches; any bit pattern is a valid u32 (after power-up it is
        // noise, which is why the marker is a magic word).
        unsafe { core::ptr::read_volatile(word.cast::<u32>()) }
    }

    #[allow(unsafe_code)]
    fn write(word: *mut MaybeUninit<u32>, value: u32) {
        // SAFETY: as in `read`.
        unsafe { core::ptr::write_volatile(word.cast::<u32>(), value) }
    }

    pub fn marker() -> u32 {
        read(addr_of!(MARKER))
    }

    pub fn set_marker(value: u32) {
        write(addr_of_mut!(MARKER), value);
    }

    pub fn unfed_us() -> u32 {
        read(addr_of!(UNFED_US))
    }

    pub fn set_unfed_us(value: u32) {
        write(addr_of_mut!(UNFED_US), value);
    }

    /// The started watchdog (the first test starts it).
    pub fn watchdog(s: &mut State) -> &mut Watchdog {
        match s.watchdog.as_mut() {
            Some(w) => w,
            None => defmt::panic!("watchdog not started (run the tests in order)"),
        }
    }

    /// Feed every `period_us` for `total_us`.
    pub fn fed(w: &mut Watchdog, period_us: u64, total_us: u64) {
        let mut waited = 0;
        while waited < total_us {
            super::common::spin_us(period_us);
            w.feed();
            waited += period_us;
        }
    }

    pub struct State {
        pub iwdg: Option<pac::IWDG>,
        pub dbgmcu: pac::DBGMCU,
        pub watchdog: Option<Watchdog>,
        pub reset_cause: ResetCause,
        /// This run follows the reset the stall test provoked, which came
        /// at most this many µs (plus one step) after the last feed.
        pub after_stall: Option<u32>,
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::bridge::ResetCause;
    use bridge_logic::bridge::WatchdogWindow;
    use bridge_logic::rate::PERIOD_MAX_US;
    use drivers_core::iwdg::{SAVE_STALL_MAX_US, SHORT_MAX_US, SHORT_MIN_US};
    use firmware::drivers::clock;
    use firmware::platform::Watchdog;

    use super::common;
    use super::support::{
        fed, marker, set_marker, set_unfed_us, unfed_us, watchdog, State, ARMED, BEYOND_LONG_US,
    };

    /// The stall test's step between two writes of `UNFED_US`.
    const STEP_US: u64 = 100;

    #[init]
    fn init() -> State {
        let t = common::setup();
        let after_stall = (marker() == ARMED).then(unfed_us);
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
    fn long_window_fed_every_100_ms_never_resets_the_mcu(s: &mut State) {
        let Some(iwdg) = s.iwdg.take() else {
            defmt::panic!("IWDG taken");
        };
        let mut watchdog = Watchdog::start(iwdg, &s.dbgmcu);
        fed(&mut watchdog, 100_000, BEYOND_LONG_US);
        s.watchdog = Some(watchdog);
    }

    #[test]
    fn long_window_outlasts_a_saves_longest_stall_unfed(s: &mut State) {
        let w = watchdog(s);
        w.feed();
        common::spin_us(SAVE_STALL_MAX_US + 50_000);
        w.feed();
    }

    #[test]
    fn short_window_fed_at_the_slowest_tick_never_resets_the_mcu(s: &mut State) {
        let w = watchdog(s);
        defmt::assert!(w.feed_in(WatchdogWindow::Short).is_ok());
        fed(w, u64::from(PERIOD_MAX_US), 2_000_000);
        // Every feed seven periods late.
        fed(w, 7 * u64::from(PERIOD_MAX_US), 1_000_000);
    }

    #[test]
    fn back_in_the_long_window_it_outlasts_a_saves_longest_stall_again(s: &mut State) {
        let w = watchdog(s);
        defmt::assert!(w.feed_in(WatchdogWindow::Long).is_ok());
        common::spin_us(SAVE_STALL_MAX_US + 50_000);
        w.feed();
    }

    #[test]
    fn unfed_in_the_short_window_it_resets_the_mcu_within_its_bounds(s: &mut State) {
        if let Some(us) = s.after_stall {
            defmt::assert_eq!(s.reset_cause, ResetCause::Watchdog);
            defmt::info!(
                "the watchdog reset the MCU {=u32} us after the last feed",
                us
            );
            defmt::assert!(u64::from(us) + STEP_US >= SHORT_MIN_US, "reset too early");
            defmt::assert!(u64::from(us) <= SHORT_MAX_US, "reset too late");
            return;
        }
        defmt::info!("stalling: the watchdog should reset the MCU within 47.1 ms");
        let w = watchdog(s);
        defmt::assert!(w.feed_in(WatchdogWindow::Short).is_ok());
        let start = clock::now_us();
        set_unfed_us(0);
        set_marker(ARMED);
        let mut unfed = 0;
        while unfed < 1_000_000 {
            common::spin_us(STEP_US);
            unfed = clock::now_us().saturating_sub(start);
            set_unfed_us(unfed as u32);
        }
        set_marker(0);
        defmt::panic!("no watchdog reset after 1 s without feeding");
    }
}
