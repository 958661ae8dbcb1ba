//! The Copley-style SPI I/O extension (issue 11): Copley's I/O extension
//! registers, offered to every bus, on a second SPI port (SPI2, its own CS,
//! separate from the powerSTEP01 chain on SPI1), and the box's own use of
//! it: a chain of 74HC165 (buttons, switches) and 74HC595 (lamps) mapped to
//! axis inputs and outputs. Knows nothing of which bus configured it; the
//! firmware driver only executes [`TransferPlan`]s.
//!
//! # What it guarantees (this layer so far)
//!
//! * **Copley's configuration register** ([`config`]): exactly the note's
//!   bits — n − 1 in bits 0–7 (so 1..=256 bits), auto-restart (9), CS hold
//!   (10), status (11), CPOL (12), CPHA (13), clock period N (16–23), SPI
//!   mode (28). Undocumented bits are dropped and reported, never an error.
//!   SLI mode (bit 28 clear) is [`IoError::Unsupported`].
//! * **Wire order**: MSB first, word 0 first; wire bit i is bit 15 − i % 16
//!   of word i / 16, a transfer of n bits sends the first n bits
//!   ([`WireBits`]). Example: 8 bits 0xA5 are word 0 = 0xA500.
//! * **Never faster than asked** ([`clock`]): the real period is never
//!   shorter than (N·100 + 20) ns — SPI2 with a power-of-two prescaler where
//!   the bit count is a multiple of 8 and the prescaler reaches the period,
//!   else a TIM1-paced engine (exact n periods via the repetition counter).
//! * **A plan leaves the driver no decision** ([`plan`]), and [`wire()`]
//!   gives its edges half-period by half-period: exactly n clock periods,
//!   the configured CPOL/CPHA, CS low from half a period before the first
//!   edge to half a period after the last.
//! * **The box's inputs and lamps** ([`mapping`]): a persisted mapping from
//!   receive bits to BIN1, BIN2, end switch and run/stop per axis (NO/NC,
//!   debounced over K transfers) and from moving/fault/idle to transmit bits.
//! * **Persistence** ([`image`]): enable, configuration, transmit data and
//!   mapping in a fixed, validated, little-endian image.

#![deny(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::unreachable,
    clippy::todo,
    clippy::unimplemented
)]

pub mod clock;
pub mod config;
pub mod image;
pub mod mapping;
pub mod plan;
pub mod wire;

pub use clock::{clock_plan, requested_period_ns, ClockPlan, Clocks, Engine, Period};
pub use config::{Config, SpiMode, WireBits, MAX_BITS, WORDS};
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
