//! The register sequences of stepbridge's peripheral drivers, written once
//! against a small register-access interface ([`Regs`]), so the same code
//! runs on the STM32F405 (the firmware implements [`Regs`] on the PAC) and
//! on the host against the RM0090 peripheral models in `host-tests`
//! (`host_tests::rm0090`).
//!
//! * [`chain_spi`] — the powerSTEP01 chain: one driver owns SPI1, DMA2
//!   streams 0/3, TIM7 and CS, and clocks both the blocking windows and the
//!   batches of windows by DMA (CS gaps timed by TIM7).
//! * [`ioext_spi`] — the I/O extension's port: SPI2 + DMA1 (the SPI
//!   engine) and TIM1 + DMA2 writing GPIOB (the bit engine), CS on GPIOB.
//! * [`dma`] — DMA1/DMA2 streams for both DMA drivers: the stream flags
//!   wherever they sit in LISR/HISR/LIFCR/HIFCR, the one rule for which
//!   flags are errors (FIFO errors included), the stream set-up.
//! * [`spi`] — SPI1/SPI2 registers, bits and status sequences for both SPI
//!   drivers.
//! * [`i2c_slave`] — I2C1 as the PoStep60 I2C slave (interrupt-driven).
//! * [`flash`] — the settings store's flash sectors through FLASH_KEYR /
//!   FLASH_SR / FLASH_CR (blocking, as flash programming is on this chip).
//! * [`rs485`] — USART2 and the RS-485 transceiver's DE line
//!   (interrupt-driven).
//! * [`iwdg`] — the independent watchdog: key sequence, prescaler, reload,
//!   the two windows and the change between them while it runs.
//!
//! What a driver decides — which register is read or written, in which
//! order, with which value — lives here; the firmware's part is the PAC
//! glue (a `match` from register id to PAC register, RCC enable/reset, GPIO)
//! and nothing else. Every access is one volatile 16- or 32-bit access on
//! the chip, so the order the models see is the order the bus sees.
//!
//! No `unsafe`, no allocation, no panics on any register value.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_debug_implementations)]

pub mod chain_spi;
pub mod dma;
pub mod flash;
pub mod i2c_slave;
pub mod ioext_spi;
pub mod iwdg;
pub mod rs485;
pub mod spi;

/// One peripheral's registers, named by `R` (an enum of that peripheral's
/// registers). Each call is exactly one bus access, in program order: a read
/// may have side effects (clearing a flag), so it takes `&mut self`.
///
/// Registers narrower than 32 bits are zero-extended on read and truncated
/// on write.
pub trait Regs<R: Copy> {
    /// One read of `reg`.
    fn read(&mut self, reg: R) -> u32;
    /// One write of `value` to `reg`.
    fn write(&mut self, reg: R, value: u32);
    /// Read `reg`, then write `f(value)` back: two accesses, as on the chip.
    #[inline]
    fn modify(&mut self, reg: R, f: impl FnOnce(u32) -> u32) {
        let value = self.read(reg);
        self.write(reg, f(value));
    }
}
