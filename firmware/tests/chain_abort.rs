//! The chain's one driver (`drivers::chain_spi`, the board's code: blocking
//! windows and DMA batches) under QEMU, which models SPI1's registers but
//! has no DMA controller and no TIM7: a batch starts and, left alone, never
//! ends — the case its deadline handles. Checked here: SPI1 set up in mode
//! 3, MSB first, 8-bit master; blocking windows; a batch past its deadline
//! is stopped and reported as a timeout, with the DMA requests closed and
//! blocking windows free again;
//! while a batch runs a second start and a blocking window are refused;
//! the per-window phases (gap, set-up, shift) walked through by handing the
//! driver the events the board's TIM7 and DMA2 would raise: TXDMAEN opens
//! only after the set-up time and closes at each window's end, RXDMAEN
//! spans the batch, stray or half-transfer flags change nothing, the batch
//! is handed over once after its last window; a DMA error ends the batch as
//! a bus error. QEMU only (feature `qemu`): on a board the events come by
//! themselves (`tests/chain_spi.rs`). QEMU does not model GPIO levels, so CS
//! is checked there, not here.
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
    use firmware::drivers::chain_spi::ChainSpi;
    use stm32f4xx_hal::pac;

    pub struct State {
        /// The one driver: `window` for the blocking windows, `start` /
        /// `poll` and the events for the batches.
        pub dma: ChainSpi,
        pub pclk2_hz: u32,
    }

    pub fn spi1() -> &'static pac::spi1::RegisterBlock {
        #[allow(unsafe_code)]
        // SAFETY: reads of SPI1 registers only.
        unsafe {
            &*pac::SPI1::ptr()
        }
    }

    /// SPI1_CR2's (TXDMAEN, RXDMAEN).
    pub fn dma_requests() -> (bool, bool) {
        let cr2 = spi1().cr2().read();
        (cr2.txdmaen().bit_is_set(), cr2.rxdmaen().bit_is_set())
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::bridge::BatchState;
    use bridge_logic::powerstep::chain::{Frames, Plan, MAX_DEVICES, MAX_WINDOWS};
    use firmware::drivers::chain_spi::{ChainSpiError, FEIF0, SCK_MAX_HZ, TCIF0, TEIF0};
    use firmware::drivers::clock;

    use super::common;
    use super::support::{dma_requests, spi1, State};

    const EMPTY: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS];

    #[init]
    fn init() -> State {
        let t = common::setup();
        let pclk2_hz = t.rcc.clocks.pclk2().raw();
        let dma = common::chain(t);
        State { dma, pclk2_hz }
    }

    #[test]
    fn spi1_is_an_8_bit_msb_first_mode_3_master_at_most_4_mhz(s: &mut State) {
        let cr1 = spi1().cr1().read();
        defmt::assert!(cr1.cpol().bit_is_set() && cr1.cpha().bit_is_set(), "mode 3");
        defmt::assert!(cr1.mstr().bit_is_set(), "master");
        defmt::assert!(cr1.spe().bit_is_set(), "enabled");
        defmt::assert!(cr1.lsbfirst().bit_is_clear(), "MSB first");
        defmt::assert!(cr1.dff().bit_is_clear(), "8-bit frames");
        defmt::assert!(
            cr1.ssm().bit_is_set() && cr1.ssi().bit_is_set(),
            "software NSS"
        );
        let div = 2u32 << cr1.br().bits();
        defmt::assert_eq!(s.pclk2_hz / div, s.dma.sck_hz());
        defmt::assert!(s.dma.sck_hz() <= SCK_MAX_HZ);
        defmt::assert!(s.dma.sck_hz() * 2 > SCK_MAX_HZ, "the fastest rate allowed");
        defmt::assert_eq!(dma_requests(), (false, false));
    }

    #[test]
    fn blocking_windows_go_through(s: &mut State) {
        for n in [1usize, 4, 8, 16] {
            let (tx, mut rx) = ([0xA5u8; 16], [0x5Au8; 16]);
            defmt::assert!(s.dma.window(&tx[..n], &mut rx[..n]).is_ok());
            // QEMU's SPI1 has no slave: every byte reads 0.
            defmt::assert!(rx[..n].iter().all(|&b| b == 0));
        }
    }

    #[test]
    fn a_batch_past_its_deadline_is_stopped_as_a_timeout(s: &mut State) {
        let plan = common::streaming_plan(8);
        defmt::assert_eq!(plan.windows(), 5);
        let now = clock::now_us();
        defmt::assert!(s.dma.start(&plan, now).is_ok());
        defmt::assert!(s.dma.is_running());
        defmt::assert_eq!(dma_requests(), (false, true), "RX requests for the batch");
        let mut rx = EMPTY;
        defmt::assert!(matches!(s.dma.poll(now, &mut rx), BatchState::Running));
        // Refused while it runs: a second batch, a blocking window.
        defmt::assert_eq!(s.dma.start(&plan, now), Err(ChainSpiError::Busy));
        let (tx, mut one) = ([0u8; 8], [0u8; 8]);
        defmt::assert_eq!(s.dma.window(&tx, &mut one), Err(ChainSpiError::Busy));
        // 5 windows of 8 bytes: nominal ~150 µs at 4 MHz; the deadline is
        // twice that + 100 µs.
        let nominal = s.dma.nominal_us();
        defmt::info!("nominal batch time {=u64} us", nominal);
        defmt::assert!(nominal > 5 * 16 && nominal < 1_000);
        defmt::assert!(matches!(
            s.dma.poll(now + 2 * nominal, &mut rx),
            BatchState::Running
        ));
        let stopped = s.dma.poll(now + 2 * nominal + 100, &mut rx);
        defmt::assert!(matches!(
            stopped,
            BatchState::Done(Err(ChainSpiError::Timeout))
        ));
        defmt::assert!(!s.dma.is_running());
        defmt::assert_eq!(dma_requests(), (false, false));
        defmt::assert_eq!(s.dma.stats().timeouts, 1);
        defmt::assert!(matches!(s.dma.poll(now, &mut rx), BatchState::Idle));
        // The blocking path is free again, and so is the next batch.
        defmt::assert!(s.dma.window(&tx, &mut one).is_ok());
        defmt::assert!(s.dma.start(&plan, now).is_ok());
        let _ = s.dma.poll(u64::MAX, &mut rx);
        defmt::assert!(!s.dma.is_running());
    }

    #[test]
    fn each_window_goes_gap_setup_shift_and_the_batch_is_handed_over_once(s: &mut State) {
        let plan = common::long_plan(8);
        let windows = plan.windows();
        defmt::assert_eq!(windows, 12);
        let before = s.dma.stats();
        let now = clock::now_us();
        defmt::assert!(s.dma.start(&plan, now).is_ok());
        let mut rx = [[0xEE; MAX_DEVICES]; MAX_WINDOWS];
        for w in 0..windows {
            // Gap: CS high, nothing may move.
            defmt::assert_eq!(dma_requests(), (false, true), "window {=usize}: gap", w);
            // A stray transfer-complete flag outside the shift is ignored.
            s.dma.dma_event(TCIF0);
            defmt::assert_eq!(s.dma.stats().windows, before.windows + w as u32);
            s.dma.on_timer();
            // Set-up: CS low, still nothing moves.
            defmt::assert_eq!(dma_requests(), (false, true), "window {=usize}: set-up", w);
            s.dma.on_timer();
            // Shift: the TX requests open.
            defmt::assert_eq!(dma_requests(), (true, true), "window {=usize}: shift", w);
            // Half the bytes in: nothing happens yet.
            s.dma.dma_event(1 << 4);
            defmt::assert_eq!(dma_requests(), (true, true));
            defmt::assert!(matches!(s.dma.poll(now, &mut rx), BatchState::Running));
            s.dma.dma_event(TCIF0);
        }
        defmt::assert!(!s.dma.is_running());
        defmt::assert_eq!(dma_requests(), (false, false));
        defmt::assert_eq!(s.dma.stats().windows, before.windows + windows as u32);
        // Handed over once: the windows' rows (QEMU's DMA wrote nothing, so
        // the buffer's zeros), the rows beyond untouched.
        match s.dma.poll(now, &mut rx) {
            BatchState::Done(Ok(frames)) => {
                defmt::assert!(frames[..windows].iter().all(|r| r == &[0; MAX_DEVICES]));
                defmt::assert!(frames[windows..].iter().all(|r| r == &[0xEE; MAX_DEVICES]));
            }
            _ => defmt::panic!("batch not handed over"),
        }
        defmt::assert!(matches!(s.dma.poll(now, &mut rx), BatchState::Idle));
        // Late timer or DMA events change nothing.
        s.dma.on_timer();
        s.dma.dma_event(TCIF0);
        defmt::assert!(matches!(s.dma.poll(now, &mut rx), BatchState::Idle));
        defmt::assert_eq!(dma_requests(), (false, false));
    }

    #[test]
    fn a_dma_error_ends_the_batch_as_a_bus_error(s: &mut State) {
        let plan = common::streaming_plan(4);
        let mut rx = EMPTY;
        for flag in [TEIF0, FEIF0] {
            let before = s.dma.stats().dma_errors;
            let now = clock::now_us();
            defmt::assert!(s.dma.start(&plan, now).is_ok());
            s.dma.on_timer();
            s.dma.on_timer();
            s.dma.dma_event(TCIF0);
            s.dma.on_timer();
            s.dma.on_timer();
            s.dma.dma_event(flag | TCIF0);
            defmt::assert!(!s.dma.is_running());
            defmt::assert_eq!(dma_requests(), (false, false));
            defmt::assert!(matches!(
                s.dma.poll(now, &mut rx),
                BatchState::Done(Err(ChainSpiError::Dma))
            ));
            defmt::assert_eq!(s.dma.stats().dma_errors, before + 1);
        }
        let (tx, mut one) = ([0u8; 4], [0u8; 4]);
        defmt::assert!(s.dma.window(&tx, &mut one).is_ok());
    }

    #[test]
    fn a_plan_without_windows_is_refused(s: &mut State) {
        defmt::assert_eq!(
            s.dma.start(&Plan::default(), 0),
            Err(ChainSpiError::BadPlan)
        );
        defmt::assert!(!s.dma.is_running());
    }
}
