//! [`ChainBus`] on the board's chain SPI and CS pin: one CS-low window per
//! call, nothing else. Which bytes go into a window is the logic crate's job.
//!
//! # Timing
//!
//! * SCK is the fastest APB2 division that does not exceed [`SCK_MAX_HZ`]:
//!   with APB2 = 84 MHz that is /32 = **2.625 MHz** (/16 would be 5.25 MHz,
//!   above the chip's 5 MHz limit). A window of 8 bytes takes ~25 µs.
//! * Mode 3 (CPOL = 1, CPHA = 1), MSB first, 8-bit frames (powerSTEP01).
//! * CS falls [`CS_SETUP_NS`] before the first clock edge and, after the last
//!   byte, stays high for [`CS_DESELECT_NS`] (t_disCS) before `window`
//!   returns, so back-to-back windows always respect t_disCS.
//!
//! Delays are busy-waits of CPU cycles computed from the real SYSCLK
//! (`cortex_m::asm::delay` waits *at least* the given cycles).

use bridge_logic::powerstep::ChainBus;
use cortex_m::asm;
use stm32f4xx_hal::rcc::Rcc;
use stm32f4xx_hal::spi::{self, Mode, Phase, Polarity, Spi};
use stm32f4xx_hal::time::Hertz;

use crate::board::{ChainCs, ChainMiso, ChainMosi, ChainSck, ChainSpi};

/// The powerSTEP01 SPI limit is 5 MHz; stay at or below 4 MHz, the rate the
/// reference libraries use on long daisy chains.
pub const SCK_MAX_HZ: u32 = 4_000_000;
/// CS low to first SCK edge (t_setCS of the family datasheets).
pub const CS_SETUP_NS: u32 = 350;
/// CS high between windows (t_disCS).
pub const CS_DESELECT_NS: u32 = 800;

/// powerSTEP01 SPI mode 3: clock idles high, data captured on the rising edge.
const MODE: Mode = Mode {
    polarity: Polarity::IdleHigh,
    phase: Phase::CaptureOnSecondTransition,
};

/// Smallest SPI baud-rate divider (2, 4, …, 256) giving at most `max_hz`.
fn sck_divider(pclk_hz: u32, max_hz: u32) -> u32 {
    let mut div = 2;
    while div < 256 && pclk_hz / div > max_hz {
        div *= 2;
    }
    div
}

/// CPU cycles for `ns` nanoseconds at `sysclk_hz`, rounded up.
fn cycles(ns: u32, sysclk_hz: u32) -> u32 {
    let c = (u64::from(ns) * u64::from(sysclk_hz)).div_ceil(1_000_000_000);
    u32::try_from(c).unwrap_or(u32::MAX)
}

/// The chain's SPI bus: SPI master plus the common CS line.
pub struct ChainSpiBus {
    spi: Spi<ChainSpi>,
    cs: ChainCs,
    setup_cycles: u32,
    deselect_cycles: u32,
    sck_hz: u32,
}

impl ChainSpiBus {
    /// Enable and configure the SPI (mode 3, 8-bit, MSB first, see module
    /// docs for the rate). `cs` must already be high.
    pub fn new(
        spi: ChainSpi,
        pins: (ChainSck, ChainMiso, ChainMosi),
        cs: ChainCs,
        rcc: &mut Rcc,
    ) -> ChainSpiBus {
        let pclk = rcc.clocks.pclk2().raw();
        let sysclk = rcc.clocks.sysclk().raw();
        let sck_hz = pclk / sck_divider(pclk, SCK_MAX_HZ);
        // The HAL picks the divider from pclk / requested rate (rounding the
        // divider down); asking for exactly pclk / div lands on div.
        let spi = Spi::new(
            spi,
            (Some(pins.0), Some(pins.1), Some(pins.2)),
            MODE,
            Hertz::from_raw(sck_hz),
            rcc,
        );
        ChainSpiBus {
            spi,
            cs,
            setup_cycles: cycles(CS_SETUP_NS, sysclk),
            deselect_cycles: cycles(CS_DESELECT_NS, sysclk),
            sck_hz,
        }
    }

    /// The SCK rate actually configured.
    pub fn sck_hz(&self) -> u32 {
        self.sck_hz
    }
}

impl ChainBus for ChainSpiBus {
    type Error = spi::Error;

    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), spi::Error> {
        self.cs.set_low();
        asm::delay(self.setup_cycles);
        // Blocking full duplex; the HAL pads with 0x00 / drops extra bytes
        // if the lengths ever differ (the chain always passes equal lengths).
        let result = self.spi.transfer(rx, tx);
        self.cs.set_high();
        asm::delay(self.deselect_cycles);
        result
    }
}
