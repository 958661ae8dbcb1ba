//! The one seam between the board and QEMU 7.2's `netduinoplus2` (an
//! STM32F405 without most of its peripherals).
//!
//! `stm32f405.rs` (the default) and `qemu.rs` (feature `qemu`) offer the same
//! names; this module picks one, and nothing outside `platform/` asks which.
//! The RTIC app, the Modbus line (`drivers::rs485`), the SysTick monotonic
//! (`drivers::clock`), the pins (`crate::pins`) and the panic handler are
//! the same code on both.
//!
//! | name | board | QEMU | why QEMU differs |
//! |---|---|---|---|
//! | `freeze_clocks` | 8 MHz HSE, PLL to 168 MHz and 48 MHz PLL48CLK | 16 MHz HSI, no PLL | RCC ready bits read 0: HSE/PLL start-up hangs |
//! | `systick_hz` | SYSCLK | 168 MHz | QEMU's SysTick counts at 168 MHz whatever the clocks say |
//! | `take_reset_flags` | RCC_CSR's reset flags, then cleared (decoded by `bridge_logic::bridge::ResetCause`) | 0 (unknown) | RCC not modelled |
//! | `Watchdog` | IWDG (`drivers_core::iwdg`): started in the long window (6.5 s nominal), then fed in the bridge's (`feed_in`: short, 25 ms, whenever an axis may move; long only around a save's erase) | does nothing; every window "in effect" | IWDG not modelled |
//! | `TickTimer` | TIM2 update at the control rate (HAL) | TIM2 programmed for QEMU's timer model, each deadline armed on the period's phase; reads the test console (USART1: `sim::ConsoleLine`) every tick | QEMU's TIM2 ignores the prescaler and re-arms from the moment it is served |
//! | `tick_need` (the tick's cost the rate is fitted to, in a row and overlapped) | `rate::need_on`: SPI bytes and computation | measured per simulated chip, the same overlapped | the simulated chips cost more than SPI bytes and are clocked on the CPU |
//! | `idle_wait` | `nop` (spin) | `wfi` | a spinning QEMU takes a host core from its own timers |
//! | `ChainDriver` (the chain's one driver: blocking windows and the control tick's batches), `ChainLink` (the bridge's bus: a handle on it), `chain_driver`, `with_chain` | SPI1 + CS, blocking windows polled, batches by DMA2 streams 0/3 with CS gaps by TIM7 (`drivers::chain_spi`), in a critical-section cell | 4 simulated powerSTEP01s that live on QEMU's virtual clock (the host's time, TIM5's counter), the same API in the same kind of cell; a batch is clocked through them at start and reported over at the next poll | no chips attached, no DMA, no TIM7 |
//! | `Analog` | ADC1 (`drivers::analog`) | constant 24 V / 25 °C, or the console's `supply MV` | ADC init reads calibration next to the unique ID, which HardFaults |
//! | `SettingsFlash` | sectors 10 and 11 (`drivers::flash`) | RAM copy of a host file, written through by semihosting | flash controller not modelled |
//! | `I2cSlaveDriver` | I2C1 slave (`drivers::i2c_slave`) | takes address changes; I2C1 stays off | I2C transfers hang |
//! | `IoExtDriver`, `ioext_driver` | SPI2 + DMA1, TIM1 + DMA2, CS PB11 (`drivers::ioext_spi`) | `stepbridge_sim::ShiftChain` (two '165, one '595), ends at once; the console's `press N` / `release N`, `jumper on` (MISO reads MOSI) | no DMA, no TIM1 |
//! | `HardFault` handler | STBY low, wait for the watchdog | exit QEMU with status 1 | a crash must end a run |
//! | `Usb`, `start_usb` | OTG FS, PoStep60 HID (`drivers::usb`) | never started (`Usb` has no value); logs "USB: not modelled by QEMU, not started" | OTG FS unimplemented: its core reset waits for ever |
//! | `unique_id` | the 96 bits at 0x1FFF_7A10 | a fixed id (logged) | reading 0x1FFF_7A10 HardFaults |
//! | `rom_bootloader` | jump to ST's ROM DFU bootloader (`drivers::mcu`) | logs, returns: normal start | no system memory |
//! | `Stopwatch`, `enable_stopwatch` (control-tick timing) | DWT cycle counter | QEMU's virtual clock (TIM5's counter) | QEMU's cycle counter reads 0 |
//! | `measure_us`, `SYSTICK_LAG_MAX_PERCENT` (on-target tests) | DWT cycle counter; SysTick exact | host clock (semihosting); SysTick up to 200 % slow (a loaded host) | QEMU's cycle counter reads 0; its SysTick re-arms late |
//! | defmt transport | RTT (probe) | semihosting stdout | no probe |
//!
//! The reset handoff word (`drivers::mcu`, `.uninit` RAM) is the same on
//! both.

#[cfg_attr(feature = "qemu", path = "qemu.rs")]
#[cfg_attr(not(feature = "qemu"), path = "stm32f405.rs")]
mod selected;

pub use selected::*;
