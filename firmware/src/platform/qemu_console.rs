//! The QEMU image's test console on USART1 (see the parent module's docs):
//! lines of `stepbridge_sim::ConsoleLine` that press and release the I/O
//! extension's buttons and inject faults into the simulated hardware, and
//! the statics that hand them to the stand-ins that apply them.

// Steals USART1, which nothing else in the firmware uses (see `Console::start`).
#![allow(unsafe_code)]

use core::sync::atomic::{AtomicBool, AtomicU16, AtomicU32, Ordering};
use stepbridge_sim::{ConsoleLine, Fault, SimChain};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::{Enable, Rcc};

use super::{AXES, IOEXT_165};

/// `SUPPLY_MV` when no `supply MV` line is in force.
pub(super) const SUPPLY_OWN: u32 = u32::MAX;
/// The supply the console set, mV (read by `housekeeping`'s [`Analog`]).
pub(super) static SUPPLY_MV: AtomicU32 = AtomicU32::new(SUPPLY_OWN);
/// The I/O extension's MOSI is jumpered to MISO (read by `ioext_run`).
pub(super) static JUMPER: AtomicBool = AtomicBool::new(false);
/// Inputs the console closed, bit i = receive bit i (read by `ioext_run`).
pub(super) static INPUTS_CLOSED: AtomicU32 = AtomicU32::new(0);
/// A fault for chip k that [`ChainDriver`] has not yet applied: 0 none, else
/// [`fault_code`]. Written by the console (control tick), taken before
/// every chain window (also the control tick, and `init`).
static CHIP_FAULTS: [AtomicU16; AXES] = [const { AtomicU16::new(0) }; AXES];

fn fault_code(f: Fault) -> u16 {
    match f {
        Fault::Dead(stuck) => 1 | u16::from(stuck) << 8,
        Fault::Revive => 2,
        Fault::PowerCycle => 3,
        Fault::Uvlo => 4,
        Fault::Overcurrent => 5,
        _ => 0,
    }
}

fn fault_of(code: u16) -> Option<Fault> {
    Some(match code & 0xFF {
        1 => Fault::Dead((code >> 8) as u8),
        2 => Fault::Revive,
        3 => Fault::PowerCycle,
        4 => Fault::Uvlo,
        5 => Fault::Overcurrent,
        _ => return None,
    })
}

/// Apply the faults the console handed over.
pub(super) fn take_chip_faults(chain: &mut SimChain) {
    for (k, slot) in CHIP_FAULTS.iter().enumerate() {
        if slot.load(Ordering::Relaxed) == 0 {
            continue;
        }
        if let (Some(f), Some(chip)) = (
            fault_of(slot.swap(0, Ordering::Relaxed)),
            chain.device_mut(k),
        ) {
            chip.inject(f);
        }
    }
}

/// Longest console line (`chip 7 dead FF`, `supply 200000` and some slack).
const CONSOLE_LINE: usize = 24;

/// The test console on USART1 (module docs).
pub(super) struct Console {
    usart: pac::USART1,
    line: [u8; CONSOLE_LINE],
    len: usize,
}

impl Console {
    pub(super) fn start(rcc: &mut Rcc) -> Console {
        // SAFETY: nothing else in the firmware uses USART1 (the app never
        // takes it out of `pac::Peripherals`); from here on this console
        // owns it.
        let usart = unsafe { pac::USART1::steal() };
        pac::USART1::enable(rcc);
        // Receive only; QEMU ignores the baud rate.
        usart.cr1().write(|w| w.ue().set_bit().re().set_bit());
        Console {
            usart,
            line: [0; CONSOLE_LINE],
            len: 0,
        }
    }

    /// Take every byte USART1 has (QEMU holds the rest back until DR is
    /// read, so none is lost between polls) and act on complete lines.
    pub(super) fn poll(&mut self) {
        while self.usart.sr().read().rxne().bit_is_set() {
            let byte = self.usart.dr().read().dr().bits() as u8;
            match byte {
                b'\n' | b'\r' => {
                    let len = core::mem::take(&mut self.len);
                    let line = self.line.get(..len).unwrap_or(&[]);
                    let parsed = ConsoleLine::parse(line, IOEXT_165 * 8, AXES);
                    apply(parsed, len);
                }
                _ => {
                    if let Some(slot) = self.line.get_mut(self.len) {
                        *slot = byte;
                        self.len = self.len.saturating_add(1);
                    }
                }
            }
        }
    }
}

// A contact's bit is `1 << bit` with `bit < IOEXT_165 * 8` (ConsoleLine::parse
// bounds it): the inputs must fit the u32 word.
const _: () = assert!(IOEXT_165 * 8 <= 32);

/// Act on one console line.
pub(super) fn apply(line: Option<ConsoleLine>, len: usize) {
    match line {
        Some(ConsoleLine::Input(c)) => {
            let bit = 1u32 << c.bit;
            if c.closed {
                INPUTS_CLOSED.fetch_or(bit, Ordering::Relaxed);
            } else {
                INPUTS_CLOSED.fetch_and(!bit, Ordering::Relaxed);
            }
            defmt::info!(
                "ioext console: input {=usize} {=str}",
                c.bit,
                if c.closed { "closed" } else { "open" }
            );
        }
        Some(ConsoleLine::Supply(mv)) => {
            let mv = mv.unwrap_or(SUPPLY_OWN);
            SUPPLY_MV.store(mv, Ordering::Relaxed);
            if mv == SUPPLY_OWN {
                defmt::info!("sim console: supply back to the fixed 24 V reading");
            } else {
                defmt::info!("sim console: supply reads {=u32} mV", mv);
            }
        }
        Some(ConsoleLine::Jumper(on)) => {
            JUMPER.store(on, Ordering::Relaxed);
            defmt::info!(
                "sim console: I/O extension MOSI -> MISO jumper {=str}",
                if on { "on" } else { "off" }
            );
        }
        Some(l) => {
            let Some((k, f)) = l.chip_fault() else {
                return;
            };
            if let Some(slot) = CHIP_FAULTS.get(k) {
                slot.store(fault_code(f), Ordering::Relaxed);
            }
            let what = match l {
                ConsoleLine::ChipDead { .. } => "dead",
                ConsoleLine::ChipRevive(_) => "revived",
                ConsoleLine::ChipReset(_) => "reset",
                ConsoleLine::ChipUvlo(_) => "undervoltage",
                _ => "overcurrent",
            };
            defmt::info!("sim console: chip {=usize}: {=str}", k, what);
        }
        None if len == 0 => {}
        None => defmt::warn!(
            "sim console: unknown line (press N, release N, chip K dead|revive|reset|uvlo|ocd, supply MV|off, jumper on|off)"
        ),
    }
}
