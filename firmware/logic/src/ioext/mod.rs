//! The Copley-style SPI I/O extension (issue 11): Copley's I/O extension
//! registers, offered to every bus, on a second SPI port (SPI2, its own CS,
//! separate from the powerSTEP01 chain on SPI1), and the box's own use of
//! it: a chain of 74HC165 (buttons, switches) and 74HC595 (lamps) mapped to
//! axis inputs and outputs. Knows nothing of which bus configured it; the
//! firmware driver only executes [`TransferPlan`]s.
//!
//! # What it guarantees
//!
//! * **Copley's registers** ([`config`], [`registers`]): I/O options bit 0
//!   enables the extension; the configuration register has exactly the
//!   note's bits — n − 1 in bits 0–7 (so 1..=256 bits), auto-restart (9), CS
//!   hold (10), status (11), CPOL (12), CPHA (13), clock period N (16–23),
//!   SPI mode (28). Undocumented bits are dropped on write, read 0, and are
//!   counted, never an error. Transmit data is 16 words; receive data is as
//!   many words as the bit count needs.
//! * **Wire order**: MSB first, word 0 first; wire bit i is bit 15 − i % 16
//!   of word i / 16, a transfer of n bits sends the first n bits
//!   ([`WireBits`]). Example: 8 bits 0xA5 are word 0 = 0xA500.
//! * **Transfers** ([`IoExtension::tick`]): writing transmit data starts a
//!   transfer at the next control tick; with auto-restart every tick starts
//!   one with the latest data. Exactly n clock periods, the configured
//!   CPOL/CPHA, CS low from half a period before the first edge to half a
//!   period after the last ([`wire()`]). A transfer never starts while the
//!   previous one runs: a written transfer waits for the first tick after it
//!   ends; an auto-restart tick that finds one running is skipped and
//!   counted. So with auto-restart, transfers longer than a tick happen
//!   every ⌈duration / tick⌉ ticks.
//! * **Status** (bit 11): set when a transfer ends and updates the receive
//!   data ([`IoExtension::complete`]); cleared by any register read that
//!   includes a receive word; a failed transfer leaves it and the receive
//!   data unchanged.
//! * **CS hold** (bit 10): CS stays low after the transfer; the next one
//!   starts without a CS edge, so two transfers of a and b bits with hold on
//!   the first are, for the slaves, one transfer of a + b bits. CS rises at
//!   the end of a transfer without hold, or when the extension is disabled.
//!   Changing CPOL while CS is held would clock the slaves: refused (Busy).
//! * **Never faster than asked** ([`clock`]): the real period is never
//!   shorter than (N·100 + 20) ns — SPI2 with a power-of-two prescaler where
//!   the bit count is a multiple of 8 and the prescaler reaches the period,
//!   else a TIM1-paced engine (exact n periods via the repetition counter).
//!   The period produced is readable (register 0x0208).
//! * **Never delays the chain or a bus reply**: the transfer runs on DMA and
//!   timer hardware; the driver's CPU work runs at the lowest priority and
//!   never locks this state; the control tick calls [`IoExtension::complete`]
//!   and [`IoExtension::tick`] after its chain batch ([`plan`] says exactly
//!   what the driver does).
//! * **SLI mode is refused**: a configuration with bit 28 clear is
//!   [`IoError::Unsupported`] and changes nothing; I/O options bit 1 (SLI
//!   LED style) reads 0. SLI drives Copley's CAN/EtherCAT status LEDs and
//!   address switches through shift registers whose layout the note does
//!   not give; the bridge has neither. Its own shift registers are served in
//!   SPI mode by the [`mapping`].
//! * **Bad input never panics** and gets a documented outcome: the register
//!   rules are in [`registers`], bit counts 0 and above 256 cannot be
//!   written (the field holds n − 1; [`Config::new`] refuses them), transmit
//!   data longer than configured is stored and not sent, reserved bits of
//!   the mapping registers are [`IoError::IllegalValue`].
//! * **The box's inputs and lamps** ([`mapping`]): a persisted mapping from
//!   receive bits to BIN1, BIN2, end switch and run/stop per axis (NO/NC,
//!   debounced over K transfers) and from moving/fault/idle to transmit bits.
//! * **Persistence** ([`image`]): enable, configuration, transmit data and
//!   mapping in a fixed, validated, little-endian image.
//!
//! Modbus maps the errors to exceptions: [`IoError::IllegalAddress`] → 02,
//! [`IoError::IllegalValue`] → 03, the others → 04.
//!
//! Its strict lints (no indexing, no unchecked arithmetic, no unwrap or
//! panic) are the workspace's, on every bus-facing crate.

pub mod clock;
pub mod config;
mod extension;
pub mod image;
pub mod mapping;
pub mod plan;
pub mod registers;
pub mod wire;

#[cfg(test)]
mod tests;

pub use clock::{clock_plan, requested_period_ns, ClockPlan, Clocks, Engine, Period};
pub use config::{Config, SpiMode, WireBits, MAX_BITS, WORDS};
pub use extension::{Diagnostics, IoExtension, NotRunning};
pub use image::{ImageError, IoSettings, IMAGE_LEN};
pub use mapping::{
    AxisInputs, AxisMap, AxisOutputs, Contact, Input, InputBit, Mapping, Output, OutputBit,
    MAX_AXES,
};
pub use plan::{Action, SpiSetup, TimerSetup, TransferPlan};
pub use wire::{wire, HalfPeriod};

/// Why a register access or a configuration was refused. Nothing changes
/// when one is returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum IoError {
    /// No such register: outside the page or the table, a write to a
    /// read-only register, a range splitting a 32-bit register, a receive
    /// word past the configured bit count. (Modbus 02)
    IllegalAddress,
    /// A value the register cannot take: an empty range, a mapping entry
    /// with reserved bits, debounce 0 or above 255, a bit count of 0 or
    /// above 256 through the typed API. (Modbus 03)
    IllegalValue,
    /// SLI mode (configuration bit 28 clear). (Modbus 04)
    Unsupported,
    /// Transmit data whose earlier write has not gone out yet (auto-restart
    /// off: it starts at the next tick; write again after it), or a CPOL
    /// change while CS is held low. (Modbus 04)
    Busy,
    /// Transmit data written while the extension is disabled. (Modbus 04)
    Disabled,
}
