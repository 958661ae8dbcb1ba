//! The chain's SPI driver (`drivers::chain_spi`) on the board: SPI1 in
//! powerSTEP01 mode 3, MSB first, 8-bit frames at ≤ 4 MHz (2.625 MHz from
//! APB2), CS idle high around every window, and each window lasting at least
//! CS setup + the bytes + CS deselect (t_disCS), timed with the CPU cycle
//! counter. Works with or without chips on the chain. Board only: QEMU's
//! SPI has no timing and its cycle counter reads 0.
#![cfg_attr(target_os = "none", no_std, no_main)]
#[cfg(not(target_os = "none"))]
fn main() {}

#[cfg(target_os = "none")]
mod common;

#[cfg(target_os = "none")]
mod support {
    use firmware::drivers::chain_spi::ChainSpiBus;
    use stm32f4xx_hal::pac;

    pub struct State {
        pub bus: ChainSpiBus,
        pub sysclk_hz: u32,
    }

    /// CS is PA4 (`board::ChainCs`).
    const CS: u32 = 1 << 4;

    #[allow(unsafe_code)]
    pub fn cs_is_high() -> bool {
        // SAFETY: one read of GPIOA_IDR.
        unsafe { (*pac::GPIOA::ptr()).idr().read().bits() & CS != 0 }
    }

    #[allow(unsafe_code)]
    pub fn spi1_cr1() -> u16 {
        // SAFETY: one read of SPI1_CR1.
        unsafe { (*pac::SPI1::ptr()).cr1().read().bits() }
    }

    pub fn ns_to_cycles(ns: u64, sysclk_hz: u32) -> u64 {
        (ns * u64::from(sysclk_hz)).div_ceil(1_000_000_000)
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::powerstep::ChainBus;
    use firmware::drivers::chain_spi::{ChainSpiBus, CS_DESELECT_NS, CS_SETUP_NS, SCK_MAX_HZ};

    use super::common;
    use super::support::{cs_is_high, ns_to_cycles, spi1_cr1, State};

    #[init]
    fn init() -> State {
        let mut t = common::setup();
        let p = t.pins;
        let pins = (p.chain_sck, p.chain_miso, p.chain_mosi);
        State {
            bus: ChainSpiBus::new(t.spi1, pins, p.chain_cs, &mut t.rcc),
            sysclk_hz: t.sysclk_hz,
        }
    }

    #[test]
    fn spi1_is_mode_3_msb_first_8_bit_master_at_2_625_mhz(s: &mut State) {
        let cr1 = spi1_cr1();
        defmt::assert_eq!(cr1 & 0b11, 0b11, "CPOL = 1, CPHA = 1");
        defmt::assert!(cr1 & (1 << 2) != 0, "master");
        defmt::assert_eq!((cr1 >> 3) & 0b111, 0b100, "fPCLK / 32");
        defmt::assert!(cr1 & (1 << 6) != 0, "enabled");
        defmt::assert_eq!(cr1 & (1 << 7), 0, "MSB first");
        defmt::assert_eq!(cr1 & (1 << 11), 0, "8-bit frames");
        defmt::assert_eq!(cr1 & (0b11 << 8), 0b11 << 8, "software NSS, held high");
        defmt::assert_eq!(s.bus.sck_hz(), 2_625_000);
        defmt::assert!(s.bus.sck_hz() <= SCK_MAX_HZ);
    }

    #[test]
    fn cs_is_high_before_and_after_every_window(s: &mut State) {
        for n in [0usize, 1, 4, 16] {
            defmt::assert!(cs_is_high());
            let (tx, mut rx) = ([0u8; 16], [0u8; 16]);
            defmt::assert!(s.bus.window(&tx[..n], &mut rx[..n]).is_ok());
            defmt::assert!(cs_is_high());
        }
    }

    #[test]
    fn a_window_lasts_cs_setup_plus_the_bytes_plus_cs_deselect(s: &mut State) {
        let sck = u64::from(s.bus.sck_hz());
        for n in [0usize, 1, 4, 16] {
            let (tx, mut rx) = ([0u8; 16], [0u8; 16]);
            let start = common::cycles_now();
            let result = s.bus.window(&tx[..n], &mut rx[..n]);
            let cycles = u64::from(common::cycles_since(start));
            defmt::assert!(result.is_ok());
            let bytes = (n as u64 * 8 * u64::from(s.sysclk_hz)).div_ceil(sck);
            let min = ns_to_cycles(u64::from(CS_SETUP_NS), s.sysclk_hz)
                + bytes
                + ns_to_cycles(u64::from(CS_DESELECT_NS), s.sysclk_hz);
            // The blocking transfer adds a little per byte, nothing more.
            let max = min + (n as u64 + 5) * ns_to_cycles(2_000, s.sysclk_hz);
            defmt::info!(
                "{=usize} bytes: {=u64} cycles ({=u64}..={=u64})",
                n,
                cycles,
                min,
                max
            );
            defmt::assert!(cycles >= min && cycles <= max);
        }
    }
}
