//! The board's clock tree (`platform::freeze_clocks`): SYSCLK 168 MHz from
//! the 8 MHz HSE crystal through the PLL, bus clocks, flash wait states, and
//! the control tick's TIM2 at 1 kHz measured against the CPU cycle counter.
//! Board only: QEMU models no RCC (it runs on the HSI) and its timers
//! ignore the prescaler.
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
    use stm32f4xx_hal::rcc::Rcc;

    pub struct State {
        pub rcc: Rcc,
        pub tim2: Option<pac::TIM2>,
        pub sysclk_hz: u32,
    }

    #[allow(unsafe_code)]
    pub fn rcc_regs() -> &'static pac::rcc::RegisterBlock {
        // SAFETY: read-only register access for the checks.
        unsafe { &*pac::RCC::ptr() }
    }

    #[allow(unsafe_code)]
    pub fn flash_latency() -> u8 {
        // SAFETY: one read of FLASH_ACR.
        unsafe { (*pac::FLASH::ptr()).acr().read().latency().bits() }
    }

    #[allow(unsafe_code)]
    pub fn tim2_update_flag() -> bool {
        // SAFETY: one read of TIM2_SR; the TickTimer under test owns TIM2
        // but only writes SR in `acknowledge`, called from this thread.
        unsafe { (*pac::TIM2::ptr()).sr().read().uif().bit_is_set() }
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use firmware::platform::TickTimer;

    use super::common;
    use super::support::{flash_latency, rcc_regs, tim2_update_flag, State};

    #[init]
    fn init() -> State {
        let t = common::setup();
        State {
            rcc: t.rcc,
            tim2: Some(t.tim2),
            sysclk_hz: t.sysclk_hz,
        }
    }

    #[test]
    fn sysclk_is_168_mhz_from_the_hse_through_the_pll(s: &mut State) {
        let clocks = &s.rcc.clocks;
        defmt::assert_eq!(clocks.sysclk().raw(), 168_000_000);
        defmt::assert_eq!(clocks.hclk().raw(), 168_000_000);
        defmt::assert_eq!(clocks.pclk1().raw(), 42_000_000);
        defmt::assert_eq!(clocks.pclk2().raw(), 84_000_000);
        let rcc = rcc_regs();
        defmt::assert!(rcc.cr().read().hserdy().bit_is_set(), "HSE not ready");
        defmt::assert!(rcc.cr().read().pllrdy().bit_is_set(), "PLL not locked");
        defmt::assert!(
            rcc.pllcfgr().read().pllsrc().bit_is_set(),
            "PLL not fed by the HSE"
        );
        // SWS = 0b10: the PLL drives SYSCLK.
        defmt::assert_eq!(rcc.cfgr().read().sws().bits(), 0b10);
    }

    #[test]
    fn flash_has_5_wait_states_for_168_mhz() {
        // RM0090: 5 WS from 150 to 168 MHz at 2.7-3.6 V.
        defmt::assert_eq!(flash_latency(), 5);
    }

    #[test]
    fn the_control_tick_timer_runs_at_1_khz(s: &mut State) {
        let Some(tim2) = s.tim2.take() else {
            defmt::panic!("TIM2 taken");
        };
        let mut tick = TickTimer::new(tim2, &mut s.rcc);
        defmt::assert!(tick.start(1_000).is_ok());
        let one_second = s.sysclk_hz;
        let wait_update = |tick: &mut TickTimer| {
            let start = common::cycles_now();
            while !tim2_update_flag() {
                if common::cycles_since(start) > one_second {
                    defmt::panic!("no TIM2 update within 1 s");
                }
            }
            tick.acknowledge();
        };
        // Sync to an update, then time 100 of them.
        wait_update(&mut tick);
        let start = common::cycles_now();
        for _ in 0..100 {
            wait_update(&mut tick);
        }
        let cycles = common::cycles_since(start);
        let expected = s.sysclk_hz / 10; // 100 ms
        defmt::info!(
            "100 ticks: {=u32} cycles ({=u32} expected)",
            cycles,
            expected
        );
        // One crystal for both: only the polling latency differs (< 0.1 %).
        defmt::assert!(cycles.abs_diff(expected) < expected / 1_000);
    }
}
