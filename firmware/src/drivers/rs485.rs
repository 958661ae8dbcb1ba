//! USART2 and the DE line of a half-duplex RS-485 transceiver: the byte
//! mover under the Modbus RTU server. Framing, timing decisions and every
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
//!   real APB1 clock.
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
//!   the RX pin has a pull-up (board.rs) for while RO is high-Z.
//! * QEMU 7.2's USART model sends each written byte at once, shows TXE and
//!   TC always set and raises its interrupt for RXNE only (TXE/TC interrupts
//!   are not modelled). The "load while TXE is set, then check TC" steps
//!   above make that work without a QEMU branch: there `send` writes the
//!   whole response and releases DE (an unconnected GPIO) before returning.

use bridge_logic::postep60::settings::{Parity, Serial};
use bridge_logic::transport::modbus::ADU_MAX;
use stm32f4xx_hal::nb;
use stm32f4xx_hal::prelude::_embedded_hal_serial_nb_Read as _;
use stm32f4xx_hal::prelude::_embedded_hal_serial_nb_Write as _;
use stm32f4xx_hal::rcc::Rcc;
use stm32f4xx_hal::serial::config::{Config, StopBits};
use stm32f4xx_hal::serial::{self, Event, Flag, Serial as HalSerial};
use stm32f4xx_hal::time::Bps;
use stm32f4xx_hal::{Listen, ReadFlags};

use crate::board::{ModbusDe, ModbusRx, ModbusTx, ModbusUsart};

/// What [`Rs485::on_interrupt`] hands over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rx {
    /// A byte received without error.
    Byte(u8),
    /// A character with a parity, framing or noise error, or an overrun.
    Bad,
}

/// Receive errors and dropped bytes (all saturate).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
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

/// USART2 with the transceiver's DE line.
pub struct Rs485 {
    /// `None` only if the HAL refused the configuration (cannot happen at
    /// ≤ 19200 baud on any APB1 clock this firmware runs with): then the
    /// driver stays silent.
    serial: Option<HalSerial<ModbusUsart, u8>>,
    de: ModbusDe,
    state: State,
    tx: [u8; ADU_MAX],
    len: usize,
    pos: usize,
    errors: RxErrors,
}

/// The HAL configuration for `s` (see the module docs).
fn config(s: Serial) -> Config {
    let base = Config::default().baudrate(Bps(s.baud));
    match s.parity {
        Parity::Even => base.parity_even().wordlength_9().stopbits(StopBits::STOP1),
        Parity::Odd => base.parity_odd().wordlength_9().stopbits(StopBits::STOP1),
        Parity::None => base.parity_none().wordlength_8().stopbits(StopBits::STOP2),
    }
}

impl Rs485 {
    /// Enable and configure USART2 for `settings` and start receiving (RXNE
    /// interrupt on). `de` must be low.
    pub fn new(
        usart: ModbusUsart,
        pins: (ModbusTx, ModbusRx),
        de: ModbusDe,
        settings: Serial,
        rcc: &mut Rcc,
    ) -> Rs485 {
        let serial = HalSerial::new(usart, pins, config(settings), rcc)
            .ok()
            .map(|mut s| {
                s.listen(Event::RxNotEmpty);
                s
            });
        Rs485 {
            serial,
            de,
            state: State::Receiving,
            tx: [0; ADU_MAX],
            len: 0,
            pos: 0,
            errors: RxErrors::default(),
        }
    }

    /// Whether DE (the transceiver's driver enable) is driven high now.
    pub fn driver_enabled(&self) -> bool {
        self.de.is_set_high()
    }

    /// False if the HAL refused the configuration (nothing is ever received).
    pub fn is_configured(&self) -> bool {
        self.serial.is_some()
    }

    /// True from [`Rs485::send`] until DE is released after the last stop bit.
    pub fn is_sending(&self) -> bool {
        self.state != State::Receiving
    }

    pub fn errors(&self) -> RxErrors {
        self.errors
    }

    /// The USART2 interrupt: hands a received byte or character error to
    /// `on_rx`, moves the transmission on (TXE, TC). See the module docs.
    pub fn on_interrupt(&mut self, mut on_rx: impl FnMut(Rx)) {
        let Some(serial) = self.serial.as_mut() else {
            return;
        };
        let flags = serial.flags();
        // RXNE, or an overrun (which also raises the RX interrupt). `read`
        // checks PE/FE/NE/ORE first and reads DR in every case but "nothing
        // there", which clears RXNE and the error flags.
        if flags.intersects(Flag::RxNotEmpty | Flag::Overrun) {
            let receiving = self.state == State::Receiving;
            match serial.read() {
                Ok(byte) if receiving => on_rx(Rx::Byte(byte)),
                Ok(_) => bump(&mut self.errors.while_sending),
                Err(nb::Error::Other(e)) => {
                    bump(match e {
                        serial::Error::Parity => &mut self.errors.parity,
                        serial::Error::FrameFormat => &mut self.errors.framing,
                        serial::Error::Noise => &mut self.errors.noise,
                        _ => &mut self.errors.overrun,
                    });
                    if receiving {
                        on_rx(Rx::Bad);
                    }
                }
                Err(nb::Error::WouldBlock) => {}
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
        let Some(serial) = self.serial.as_mut() else {
            return;
        };
        loop {
            let flags = serial.flags();
            match self.state {
                State::Receiving => return,
                State::Sending => {
                    if !flags.contains(Flag::TxEmpty) {
                        // The data register is full: the TXE interrupt goes on.
                        serial.listen(Event::TxEmpty);
                        return;
                    }
                    match self.tx.get(self.pos).filter(|_| self.pos < self.len) {
                        // SR was just read, so this DR write also clears TC.
                        Some(&byte) => {
                            if serial.write(byte).is_err() {
                                serial.listen(Event::TxEmpty);
                                return;
                            }
                            self.pos += 1;
                        }
                        None => {
                            serial.unlisten(Event::TxEmpty);
                            self.state = State::Draining;
                        }
                    }
                }
                State::Draining => {
                    if flags.contains(Flag::TransmissionComplete) {
                        self.de.set_low();
                        serial.unlisten(Event::TransmissionComplete);
                        self.state = State::Receiving;
                    } else {
                        // Level-triggered: a TC set since the read above
                        // interrupts at once.
                        serial.listen(Event::TransmissionComplete);
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
        if self.serial.is_none() {
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
        self.de.set_high();
        self.pump();
        true
    }
}
