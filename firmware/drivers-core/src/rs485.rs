//! USART2 and the DE line of a half-duplex RS-485 transceiver: the byte
//! mover under the Modbus RTU server, register by register (RM0090 §30)
//! through an [`Rs485Port`] — on the chip the firmware's PAC glue for
//! `pac::USART2` and PA1 (`firmware::drivers::rs485`), on the host the
//! RM0090 model `host_tests::rm0090::usart`. Framing, timing decisions and every
//! byte's meaning belong to `bridge_logic::transport::modbus::RtuServer`;
//! this module only receives, transmits and switches the driver.
//!
//! # What it guarantees
//!
//! * **Character format** from the settings' [`Serial`]: 9600 or 19200 baud;
//!   even or odd parity with 1 stop bit, or no parity with 2 stop bits — 11
//!   bits either way, as Modbus RTU requires. With parity the USART works
//!   with 9-bit words (M = 1): the STM32 counts the parity bit as a data bit,
//!   so 8 data bits + parity need M = 1. The baud divider comes from the
//!   real APB1 clock (BRR = PCLK1 / baud rounded, oversampling by 16,
//!   §30.3.4). The configuration follows §30.3.2/§30.3.3: UE with the
//!   word length and parity first, then the stop bits, CR3, BRR, and only
//!   then TE, RE and the RXNE interrupt — M, PCE, STOP and BRR are never
//!   changed while TE or RE is set.
//! * **Receiving**: every byte is handed over from the interrupt
//!   ([`Rs485::on_interrupt`]) as [`Rx::Byte`] the moment RXNE is seen; the
//!   caller stamps it. A byte with a parity, framing or noise error, and an
//!   overrun (characters lost), is handed over as [`Rx::Bad`] instead, for
//!   the server's `on_bad_byte`, which discards the frame it belongs to
//!   (Modbus serial line spec §2.5.1.2) even if the rest passes the CRC. The
//!   data register is read either way (which clears the flags), and the
//!   error is counted in [`RxErrors`] as well.
//! * **Transmitting** ([`Rs485::send`]) is interrupt-driven: DE goes high
//!   before the first byte is written; `send` itself loads the data register
//!   while TXE is set (on the chip: the first byte, which moves on to the
//!   shift register at once, and the second), then each TXE interrupt loads
//!   the next byte. After the last one TXE is switched off and TC on, and DE
//!   goes low in the TC interrupt — after the last stop bit has left the
//!   shift register, not when the last byte merely moved out of the data
//!   register (TXE), which would cut off the last character. The transceiver
//!   then listens again within the TC interrupt's latency (~1 µs). TC is
//!   checked right after enabling its interrupt as well, so a TC that is
//!   already set is never missed.
//! * While DE is high nothing is handed over: a byte received then is our own
//!   echo or a collision, read and counted in [`RxErrors::while_sending`]
//!   (or, with a character error, in that error's counter).
//! * Never blocks, never waits on a flag, never panics. Every call does a
//!   bounded amount of work; a flag it does not serve stays pending and is
//!   served by the next interrupt.
//!
//! # Assumptions
//!
//! * `on_interrupt` runs from the USART2 interrupt; `send` is called with that
//!   interrupt masked (an RTIC lock of this resource).
//! * RE̅ of the transceiver is tied to DE (so we do not hear ourselves), and
//!   the RX pin has a pull-up (pins.rs) for while RO is high-Z.
//! * QEMU 7.2's USART model sends each written byte at once, shows TXE and
//!   TC always set and raises its interrupt for RXNE only (TXE/TC interrupts
//!   are not modelled). The "load while TXE is set, then check TC" steps
//!   above make that work without a QEMU branch: there `send` writes the
//!   whole response and releases DE (an unconnected GPIO) before returning.

use bridge_logic::postep60::settings::{Parity, Serial};
use bridge_logic::transport::modbus::ADU_MAX;

use crate::Regs;

/// The USART's registers (RM0090 §30.6; offsets in [`UsartReg::offset`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum UsartReg {
    Sr,
    Dr,
    Brr,
    Cr1,
    Cr2,
    Cr3,
    Gtpr,
}

impl UsartReg {
    pub const fn offset(self) -> usize {
        match self {
            UsartReg::Sr => 0x00,
            UsartReg::Dr => 0x04,
            UsartReg::Brr => 0x08,
            UsartReg::Cr1 => 0x0C,
            UsartReg::Cr2 => 0x10,
            UsartReg::Cr3 => 0x14,
            UsartReg::Gtpr => 0x18,
        }
    }
}

/// Register bits (RM0090 §30.6.1–§30.6.5).
pub mod bits {
    pub const SR_PE: u32 = 1 << 0;
    pub const SR_FE: u32 = 1 << 1;
    pub const SR_NF: u32 = 1 << 2;
    pub const SR_ORE: u32 = 1 << 3;
    pub const SR_IDLE: u32 = 1 << 4;
    pub const SR_RXNE: u32 = 1 << 5;
    pub const SR_TC: u32 = 1 << 6;
    pub const SR_TXE: u32 = 1 << 7;
    /// The receive errors, cleared by a read of SR followed by a read of DR.
    pub const SR_RX_ERRORS: u32 = SR_PE | SR_FE | SR_NF | SR_ORE;
    pub const CR1_RE: u32 = 1 << 2;
    pub const CR1_TE: u32 = 1 << 3;
    pub const CR1_IDLEIE: u32 = 1 << 4;
    pub const CR1_RXNEIE: u32 = 1 << 5;
    pub const CR1_TCIE: u32 = 1 << 6;
    pub const CR1_TXEIE: u32 = 1 << 7;
    pub const CR1_PEIE: u32 = 1 << 8;
    pub const CR1_PS: u32 = 1 << 9;
    pub const CR1_PCE: u32 = 1 << 10;
    pub const CR1_M: u32 = 1 << 12;
    pub const CR1_UE: u32 = 1 << 13;
    pub const CR1_OVER8: u32 = 1 << 15;
    pub const CR2_STOP_SHIFT: u32 = 12;
    pub const CR2_STOP_MASK: u32 = 0b11 << CR2_STOP_SHIFT;
    pub const CR2_STOP_1: u32 = 0b00 << CR2_STOP_SHIFT;
    pub const CR2_STOP_2: u32 = 0b10 << CR2_STOP_SHIFT;
}

use bits::*;

/// What the driver needs besides the USART's registers: the transceiver's
/// DE line (a GPIO output).
pub trait Rs485Port: Regs<UsartReg> {
    /// Drive DE high (the transceiver drives the bus) or low (it listens).
    fn set_de(&mut self, high: bool);
    /// Whether DE is driven high now.
    fn de_is_high(&self) -> bool;
}

/// What [`Rs485::on_interrupt`] hands over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rx {
    /// A byte received without error.
    Byte(u8),
    /// A character with a parity, framing or noise error, or an overrun.
    Bad,
}

/// Receive errors and dropped bytes (all saturate).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RxErrors {
    pub parity: u32,
    pub framing: u32,
    pub noise: u32,
    pub overrun: u32,
    /// Bytes received while our driver was enabled.
    pub while_sending: u32,
    /// Responses refused because the previous one was still going out.
    pub busy: u32,
}

impl RxErrors {
    /// Sum of all counters (to notice a change).
    pub fn total(&self) -> u32 {
        self.parity
            .saturating_add(self.framing)
            .saturating_add(self.noise)
            .saturating_add(self.overrun)
            .saturating_add(self.while_sending)
            .saturating_add(self.busy)
    }
}

fn bump(counter: &mut u32) {
    *counter = counter.saturating_add(1);
}

/// Where the line stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// DE low: bytes are received and handed over.
    Receiving,
    /// DE high: TXE interrupts load `tx[pos..len]`.
    Sending,
    /// DE high, every byte written: waiting for TC (last stop bit out).
    Draining,
}

/// CR1 (without TE, RE and the interrupt enables), CR2 and BRR for `s` at
/// `pclk_hz`; None if the baud rate cannot be reached with oversampling by
/// 16 (PCLK1 < 16 × baud) or is 0.
pub fn config(s: Serial, pclk_hz: u32) -> Option<(u32, u32, u32)> {
    if s.baud == 0 || pclk_hz / 16 < s.baud {
        return None;
    }
    // baud ≥ 1 and ≤ pclk / 16 (above): no overflow, no division by 0.
    let brr = pclk_hz
        .saturating_add(s.baud / 2)
        .checked_div(s.baud)
        .unwrap_or(u32::MAX);
    if brr > 0xFFFF {
        return None;
    }
    let (format, stop) = match s.parity {
        Parity::Even => (CR1_M | CR1_PCE, CR2_STOP_1),
        Parity::Odd => (CR1_M | CR1_PCE | CR1_PS, CR2_STOP_1),
        Parity::None => (0, CR2_STOP_2),
    };
    Some((CR1_UE | format, stop, brr))
}

/// The USART with the transceiver's DE line (see the module docs).
#[derive(Debug)]
pub struct Rs485<P> {
    port: P,
    /// False if the configuration was refused: then the driver stays silent.
    configured: bool,
    state: State,
    tx: [u8; ADU_MAX],
    len: usize,
    pos: usize,
    errors: RxErrors,
}

impl<P: Rs485Port> Rs485<P> {
    /// Configure the USART (enabled and reset through the RCC by the
    /// caller) for `settings` at an APB clock of `pclk_hz` and start
    /// receiving (RXNE interrupt on). DE goes low.
    pub fn new(port: P, pclk_hz: u32, settings: Serial) -> Rs485<P> {
        let mut rs485 = Rs485 {
            port,
            configured: false,
            state: State::Receiving,
            tx: [0; ADU_MAX],
            len: 0,
            pos: 0,
            errors: RxErrors::default(),
        };
        rs485.port.set_de(false);
        if let Some((cr1, cr2, brr)) = config(settings, pclk_hz) {
            // §30.3.2 / §30.3.3: UE and the word length, stop bits, CR3,
            // baud rate, then TE and RE (and the RXNE interrupt).
            rs485.port.write(UsartReg::Cr1, cr1);
            rs485.port.write(UsartReg::Cr2, cr2);
            rs485.port.write(UsartReg::Cr3, 0);
            rs485.port.write(UsartReg::Brr, brr);
            rs485
                .port
                .write(UsartReg::Cr1, cr1 | CR1_TE | CR1_RE | CR1_RXNEIE);
            rs485.configured = true;
        }
        rs485
    }

    /// The port (on the host: the USART model).
    pub fn port(&self) -> &P {
        &self.port
    }

    pub fn port_mut(&mut self) -> &mut P {
        &mut self.port
    }

    /// Whether DE (the transceiver's driver enable) is driven high now.
    pub fn driver_enabled(&self) -> bool {
        self.port.de_is_high()
    }

    /// False if the configuration was refused (nothing is ever received).
    pub fn is_configured(&self) -> bool {
        self.configured
    }

    /// True from [`Rs485::send`] until DE is released after the last stop bit.
    pub fn is_sending(&self) -> bool {
        self.state != State::Receiving
    }

    pub fn errors(&self) -> RxErrors {
        self.errors
    }

    /// The USART interrupt: hands a received byte or character error to
    /// `on_rx`, moves the transmission on (TXE, TC). See the module docs.
    pub fn on_interrupt(&mut self, mut on_rx: impl FnMut(Rx)) {
        if !self.configured {
            return;
        }
        let sr = self.port.read(UsartReg::Sr);
        // RXNE, or an overrun (which also raises the RX interrupt). The DR
        // read right after the SR read clears RXNE and the error flags
        // (§30.6.1), whatever the character was.
        if sr & (SR_RXNE | SR_ORE) != 0 {
            // DR holds 8 data bits (the ninth is the parity bit).
            let byte = self.port.read(UsartReg::Dr) as u8;
            let receiving = self.state == State::Receiving;
            let error = sr & SR_RX_ERRORS;
            if error != 0 {
                bump(if error & SR_PE != 0 {
                    &mut self.errors.parity
                } else if error & SR_FE != 0 {
                    &mut self.errors.framing
                } else if error & SR_NF != 0 {
                    &mut self.errors.noise
                } else {
                    &mut self.errors.overrun
                });
                if receiving {
                    on_rx(Rx::Bad);
                }
            } else if receiving {
                on_rx(Rx::Byte(byte));
            } else {
                bump(&mut self.errors.while_sending);
            }
        }
        if self.state != State::Receiving {
            self.pump();
        }
    }

    /// Moves the transmission on as far as the flags allow: loads the data
    /// register while TXE is set and bytes are left, then waits for TC with
    /// its interrupt on, and releases DE once TC is set. At most `len + 2`
    /// steps.
    fn pump(&mut self) {
        loop {
            let sr = self.port.read(UsartReg::Sr);
            match self.state {
                State::Receiving => return,
                State::Sending => {
                    if sr & SR_TXE == 0 {
                        // The data register is full: the TXE interrupt goes on.
                        self.port.modify(UsartReg::Cr1, |cr1| cr1 | CR1_TXEIE);
                        return;
                    }
                    match self.tx.get(self.pos).filter(|_| self.pos < self.len) {
                        // SR was just read, so this DR write also clears TC.
                        Some(&byte) => {
                            self.port.write(UsartReg::Dr, u32::from(byte));
                            self.pos = self.pos.saturating_add(1);
                        }
                        None => {
                            self.port.modify(UsartReg::Cr1, |cr1| cr1 & !CR1_TXEIE);
                            self.state = State::Draining;
                        }
                    }
                }
                State::Draining => {
                    if sr & SR_TC != 0 {
                        self.port.set_de(false);
                        self.port.modify(UsartReg::Cr1, |cr1| cr1 & !CR1_TCIE);
                        self.state = State::Receiving;
                    } else {
                        // Level-triggered: a TC set since the read above
                        // interrupts at once.
                        self.port.modify(UsartReg::Cr1, |cr1| cr1 | CR1_TCIE);
                    }
                    return;
                }
            }
        }
    }

    /// Start sending `adu` (DE high now, bytes from the TXE interrupt).
    /// Returns false, sending nothing, while the previous one is still going
    /// out or if `adu` is empty or longer than [`ADU_MAX`].
    pub fn send(&mut self, adu: &[u8]) -> bool {
        if !self.configured {
            return false;
        }
        if self.state != State::Receiving {
            bump(&mut self.errors.busy);
            return false;
        }
        let Some(slot) = self.tx.get_mut(..adu.len()).filter(|_| !adu.is_empty()) else {
            return false;
        };
        slot.copy_from_slice(adu);
        self.len = adu.len();
        self.pos = 0;
        self.state = State::Sending;
        self.port.set_de(true);
        self.pump();
        true
    }
}
