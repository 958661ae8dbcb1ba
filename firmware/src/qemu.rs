//! Stand-ins for what QEMU 7.2's `netduinoplus2` (STM32F405) does not model
//! (feature `qemu`). Everything else — the RTIC app, the bridge, the Modbus
//! server and its USART2/RS-485 driver, timing — is the board's code.
//!
//! | board | under QEMU | why |
//! |---|---|---|
//! | HSE + PLL to 168 MHz | HSI 16 MHz, no PLL (`main.rs`) | RCC ready bits read 0: HSE/PLL start-up hangs |
//! | SysTick input = SYSCLK | [`SYSTICK_HZ`] = 168 MHz | QEMU's SysTick counts at 168 MHz whatever the clocks say |
//! | TIM2 control tick | monotonic task every 1 ms (`main.rs`) | TIM2 counts far too fast |
//! | powerSTEP01 chain on SPI1 | [`SimChain`] of [`AXES`] simulated chips, advanced one tick period per control tick | no chips attached |
//! | ADC1 samples | [`FixedAnalog`]: 24 V supply, 25 °C | ADC init reads calibration next to the unique ID, which HardFaults |
//! | settings store in flash sectors 10/11 | [`RamFlash`] (erased at every boot) | the flash controller is not modelled |
//! | I2C1 slave | not started, its tasks not built; [`NoI2c`] takes the address changes | I2C transfers hang |
//! | defmt over RTT | defmt over semihosting (stdout; `defmt-print -e ELF`) | no probe |
//! | a fault halts the core | [`HardFault`] exits QEMU with status 1 | so a crashed image ends the run |
//!
//! A panic (the handler in `failsafe.rs`, the board's) drives STBY low,
//! prints its message through defmt, then `udf` raises a HardFault, which
//! ends QEMU with status 1.

// The HardFault handler is an `unsafe fn` by cortex-m-rt's contract.
#![allow(unsafe_code)]

use bridge_logic::persist::Store;
use bridge_logic::postep::analog::AnalogSample;
use bridge_logic::sim::SimFlash;
use stm32f4xx_hal::rcc::Rcc;

use crate::board::{SenseAdc, SupplySense};

pub use bridge_logic::sim::SimChain;

/// Simulated powerSTEP01s on the chain.
pub const AXES: usize = 4;
/// The rate QEMU's SysTick counts at.
pub const SYSTICK_HZ: u32 = 168_000_000;

/// Sector size of the RAM flash: the smallest power of two that holds the
/// store's largest record (the store needs one record per erase unit).
const RAM_SECTOR: usize = bridge_logic::persist::MAX_RECORD.next_power_of_two();
/// The settings store's flash under QEMU: two RAM sectors (erased at boot,
/// so every boot starts from factory settings; saves work until QEMU exits).
pub type RamFlash = SimFlash<RAM_SECTOR, 2>;
/// The settings store as the QEMU image uses it.
pub type SettingsStore = Store<RamFlash>;

/// The chain under QEMU.
pub fn chain() -> SimChain {
    SimChain::new(AXES)
}

/// ADC1 stand-in: the same interface as `crate::analog::Analog`, constant
/// samples of a 24 V supply and a 25 °C die (at VDDA = 3.3 V, with the
/// reference board's ÷20 divider). The ADC and its pin stay untouched.
pub struct FixedAnalog;

impl FixedAnalog {
    /// 24 V / 20 = 1.2 V at the pin = 1490 counts at VDDA 3.2988 V.
    const SAMPLE: AnalogSample = AnalogSample {
        supply: 1490,
        temperature: 943,
        vrefint: 1502,
    };

    pub fn new(_adc: SenseAdc, _pin: SupplySense, _rcc: &mut Rcc) -> FixedAnalog {
        FixedAnalog
    }

    pub fn sample(&mut self) -> AnalogSample {
        Self::SAMPLE
    }
}

/// I2C1 slave stand-in: the shared resource the Modbus server hands
/// address changes to (`crate::i2c_slave::I2cSlaveDriver` on the board).
pub struct NoI2c;

impl NoI2c {
    /// Nothing to reprogram under QEMU.
    pub fn set_addresses(&mut self, _primary: u8, _secondary: Option<u8>) {}
}

/// Any HardFault (including the panic handler's `udf` after its message)
/// ends QEMU with exit status 1, so a crash fails a test run instead of
/// hanging.
#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    // Through semihosting's stderr, not defmt: the fault may have hit inside
    // a defmt frame on stdout.
    semihosting::eprintln!("stepbridge: HardFault, exiting QEMU");
    semihosting::process::exit(1)
}
