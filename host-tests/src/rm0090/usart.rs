//! RM0090 §30: USART2 as `drivers_core::rs485` sees it, with the RS-485
//! transceiver's DE line and the wire, in steps of one bit time
//! ([`UsartModel::tick`]).
//!
//! # Rules (RM0090 rev 19 section numbers)
//!
//! | # | rule | section |
//! |---|---|---|
//! | U1 | Configure UE and the word length (M, PCE, PS), the stop bits (CR2.STOP), CR3 and BRR before TE/RE; M, PCE, PS, STOP and BRR must not change while TE or RE is set | §30.3.2 "Character transmission" procedure, §30.3.3, §30.6.4 (M), §30.3.4 ("the baud rate register value should not be changed during communication") |
//! | U2 | Frame = start bit + 8 or 9 data bits (M; with PCE the last is the parity bit) + 1 or 2 stop bits; baud = f_PCLK / BRR with OVER8 = 0 | §30.3.1, §30.3.4 |
//! | U3 | Setting TE sends an idle frame first | §30.3.2 |
//! | U4 | TXE: set when DR's byte moved to the shift register; cleared by a DR write. A DR write while TXE = 0 overwrites the waiting byte | §30.3.2, §30.6.1 (TXE) |
//! | U5 | TC: set when a frame is complete and TXE = 1 (nothing left to send); cleared by a read of SR followed by a write of DR (or by writing 0) | §30.3.2 "Single byte communication", §30.6.1 (TC) |
//! | U6 | RXNE: set when a received character is in DR; cleared by a read of DR (or writing 0) | §30.3.3, §30.6.1 (RXNE) |
//! | U7 | ORE: a character received while RXNE = 1 is lost, DR keeps the old one; PE/FE/NF are set with RXNE for a bad character; all four are cleared by a read of SR followed by a read of DR | §30.3.3 "Overrun error", "Noise error", "Framing error", §30.6.1 |
//! | U8 | Interrupt: TXEIE·TXE, TCIE·TC, RXNEIE·(RXNE or ORE), PEIE·PE, IDLEIE·IDLE | §30.4, Table 146 "USART interrupt requests" (table number UNCONFIRMED) |
//! | U9 | The transceiver drives the bus only while DE is high: every bit of every character must go out with DE high (a DE released at TXE instead of TC cuts the last character) | RS-485 transceiver, our board (not RM0090) |
//!
//! # Modelling choices (UNCONFIRMED)
//!
//! * "Read SR, followed by …" (TC, and the receive errors): armed by an SR
//!   read that shows the flag, cleared by the following DR write (TC) or
//!   DR read (errors); any other write in between disarms, reads of other
//!   registers do not (as for the I2C model).
//! * The RS-485 receiver is not modelled: [`UsartModel::receive`] puts a
//!   character on RX whatever DE is (the board ties RE̅ to DE; the tests
//!   decide when a master talks).
//! * [`UsartModel::qemu_7_2`]: QEMU 7.2's USART instead — every DR write
//!   goes out at once, TXE and TC always read 1 — to check the driver's
//!   claim that it runs there unchanged (the QEMU image and its e2e test).

use std::collections::VecDeque;

use drivers_core::rs485::bits::*;
use drivers_core::rs485::{Rs485Port, UsartReg};
use drivers_core::Regs;

/// The APB1 clock of USART2 on the board.
pub const PCLK1_HZ: u32 = 42_000_000;

/// A receive error to put on a character.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RxFault {
    Parity,
    Framing,
    Noise,
}

/// USART2, DE and the wire (see the module docs).
#[derive(Clone, Debug)]
pub struct UsartModel {
    cr1: u32,
    cr2: u32,
    cr3: u32,
    brr: u32,
    gtpr: u32,
    sr: u32,
    /// A byte written and not yet in the shift register.
    dr_tx: Option<u8>,
    /// The received byte DR shows.
    dr_rx: u8,
    /// The character being sent and its bits left (None: the idle frame).
    shift: Option<(Option<u8>, u32)>,
    /// A character arriving on RX and its bits left.
    incoming: Option<(u8, Option<RxFault>, u32)>,
    rx_queue: VecDeque<(u8, Option<RxFault>)>,
    de: bool,
    armed_tc: bool,
    armed_rx: bool,
    /// Bit times so far.
    now: u64,
    /// Characters sent: byte, bit time its stop bit ended.
    wire: Vec<(u8, u64)>,
    /// When DE last went low.
    de_low_at: Option<u64>,
    qemu: bool,
    violations: Vec<String>,
}

impl Default for UsartModel {
    fn default() -> Self {
        UsartModel::new()
    }
}

impl UsartModel {
    /// After an RCC reset: every register 0 but SR (TXE and TC set).
    pub fn new() -> UsartModel {
        UsartModel {
            cr1: 0,
            cr2: 0,
            cr3: 0,
            brr: 0,
            gtpr: 0,
            sr: SR_TXE | SR_TC,
            dr_tx: None,
            dr_rx: 0,
            shift: None,
            incoming: None,
            rx_queue: VecDeque::new(),
            de: false,
            armed_tc: false,
            armed_rx: false,
            now: 0,
            wire: Vec::new(),
            de_low_at: None,
            qemu: false,
            violations: Vec::new(),
        }
    }

    /// QEMU 7.2's USART model instead (module docs).
    pub fn qemu_7_2() -> UsartModel {
        UsartModel {
            qemu: true,
            ..UsartModel::new()
        }
    }

    pub fn cr1(&self) -> u32 {
        self.cr1
    }

    pub fn cr2(&self) -> u32 {
        self.cr2
    }

    pub fn brr(&self) -> u32 {
        self.brr
    }

    pub fn sr(&self) -> u32 {
        self.sr
    }

    pub fn de(&self) -> bool {
        self.de
    }

    pub fn now(&self) -> u64 {
        self.now
    }

    /// The bytes sent so far.
    pub fn sent(&self) -> Vec<u8> {
        self.wire.iter().map(|&(b, _)| b).collect()
    }

    /// When the last character's stop bit ended.
    pub fn last_stop_end(&self) -> Option<u64> {
        self.wire.last().map(|&(_, t)| t)
    }

    /// When DE last went low.
    pub fn de_low_at(&self) -> Option<u64> {
        self.de_low_at
    }

    pub fn violations(&self) -> &[String] {
        &self.violations
    }

    /// Whether a character (or the idle frame) is being sent.
    pub fn transmitting(&self) -> bool {
        self.shift.is_some() || self.dr_tx.is_some()
    }

    /// Whether characters are still arriving on RX.
    pub fn receiving(&self) -> bool {
        self.incoming.is_some() || !self.rx_queue.is_empty()
    }

    /// U2: bits per character as configured.
    pub fn frame_bits(&self) -> u32 {
        let data = if self.cr1 & CR1_M != 0 { 9 } else { 8 };
        let stop = match (self.cr2 & CR2_STOP_MASK) >> CR2_STOP_SHIFT {
            0b10 | 0b11 => 2,
            _ => 1,
        };
        1 + data + stop
    }

    /// U2: the baud rate as configured (OVER8 = 0).
    pub fn baud(&self) -> u32 {
        PCLK1_HZ.checked_div(self.brr).unwrap_or(0)
    }

    /// U8: the interrupt line.
    pub fn irq(&self) -> bool {
        let (c, s) = (self.cr1, self.sr);
        (c & CR1_TXEIE != 0 && s & SR_TXE != 0)
            || (c & CR1_TCIE != 0 && s & SR_TC != 0)
            || (c & CR1_RXNEIE != 0 && s & (SR_RXNE | SR_ORE) != 0)
            || (c & CR1_PEIE != 0 && s & SR_PE != 0)
            || (c & CR1_IDLEIE != 0 && s & SR_IDLE != 0)
    }

    /// A character arrives on RX (after the one arriving now, if any).
    pub fn receive(&mut self, byte: u8, fault: Option<RxFault>) {
        self.rx_queue.push_back((byte, fault));
    }

    fn violate(&mut self, what: impl Into<String>) {
        self.violations.push(what.into());
    }

    fn on(&self) -> bool {
        self.cr1 & CR1_UE != 0
    }

    /// One bit time.
    pub fn tick(&mut self) {
        self.now += 1;
        if self.qemu {
            return;
        }
        // Transmitter.
        if let Some((byte, left)) = self.shift {
            if byte.is_some() && !self.de {
                self.violate(format!(
                    "U9: DE low while {byte:02X?} was on the wire (bit time {})",
                    self.now
                ));
            }
            if left <= 1 {
                self.shift = None;
                if let Some(b) = byte {
                    self.wire.push((b, self.now));
                }
                self.load_shift();
            } else {
                self.shift = Some((byte, left - 1));
            }
        }
        // Receiver.
        if self.incoming.is_none() && self.cr1 & CR1_RE != 0 && self.on() {
            if let Some((b, f)) = self.rx_queue.pop_front() {
                self.incoming = Some((b, f, self.frame_bits()));
            }
        }
        if let Some((b, f, left)) = self.incoming {
            if left <= 1 {
                self.incoming = None;
                self.received(b, f);
            } else {
                self.incoming = Some((b, f, left - 1));
            }
        }
    }

    /// U6, U7: a character's stop bit is in.
    fn received(&mut self, byte: u8, fault: Option<RxFault>) {
        if self.sr & SR_RXNE != 0 {
            self.sr |= SR_ORE;
            return;
        }
        self.dr_rx = byte;
        self.sr |= SR_RXNE;
        self.sr |= match fault {
            Some(RxFault::Parity) => SR_PE,
            Some(RxFault::Framing) => SR_FE,
            Some(RxFault::Noise) => SR_NF,
            None => 0,
        };
    }

    /// U4, U5: DR to the shift register, or TC.
    fn load_shift(&mut self) {
        if self.shift.is_some() {
            return;
        }
        match self.dr_tx.take() {
            Some(b) => {
                self.shift = Some((Some(b), self.frame_bits()));
                self.sr |= SR_TXE;
            }
            None => self.sr |= SR_TC,
        }
    }

    fn cr1_write(&mut self, value: u32) {
        let old = self.cr1;
        let active = old & (CR1_TE | CR1_RE) != 0;
        let format = CR1_M | CR1_PCE | CR1_PS | CR1_OVER8;
        if active && (old ^ value) & format != 0 {
            self.violate(format!(
                "U1: CR1 word format changed with TE/RE on ({old:#06x} -> {value:#06x})"
            ));
        }
        let te_on = old & CR1_TE == 0 && value & CR1_TE != 0;
        let re_on = old & CR1_RE == 0 && value & CR1_RE != 0;
        if (te_on || re_on) && (value & CR1_UE == 0 || self.brr == 0) {
            self.violate("U1: TE/RE set before UE and BRR");
        }
        if (te_on || re_on) && old & CR1_UE == 0 {
            self.violate("U1: TE/RE set in the write that sets UE and the word length");
        }
        self.cr1 = value;
        if te_on && !self.qemu {
            // U3: the idle frame.
            self.sr &= !SR_TC;
            self.shift = Some((None, self.frame_bits()));
        }
    }

    fn dr_write(&mut self, byte: u8) {
        if self.cr1 & CR1_TE == 0 || !self.on() {
            self.violate("DR written with TE or UE off: nothing is sent");
            return;
        }
        if self.armed_tc {
            self.sr &= !SR_TC;
        }
        if self.qemu {
            self.wire.push((byte, self.now));
            return;
        }
        if self.sr & SR_TXE == 0 {
            self.violate(format!(
                "U4: DR written while TXE = 0: {:02X?} lost",
                self.dr_tx
            ));
        }
        self.dr_tx = Some(byte);
        self.sr &= !SR_TXE;
        self.load_shift();
    }
}

impl Regs<UsartReg> for UsartModel {
    fn read(&mut self, reg: UsartReg) -> u32 {
        match reg {
            UsartReg::Sr => {
                let v = if self.qemu {
                    self.sr | SR_TXE | SR_TC
                } else {
                    self.sr
                };
                self.armed_tc = v & SR_TC != 0;
                self.armed_rx = v & (SR_RXNE | SR_RX_ERRORS) != 0;
                v
            }
            UsartReg::Dr => {
                self.sr &= !SR_RXNE;
                if self.armed_rx {
                    self.sr &= !(SR_RX_ERRORS | SR_IDLE);
                }
                self.armed_rx = false;
                u32::from(self.dr_rx)
            }
            UsartReg::Brr => self.brr,
            UsartReg::Cr1 => self.cr1,
            UsartReg::Cr2 => self.cr2,
            UsartReg::Cr3 => self.cr3,
            UsartReg::Gtpr => self.gtpr,
        }
    }

    fn write(&mut self, reg: UsartReg, value: u32) {
        let value = value & 0xFFFF;
        let active = self.cr1 & (CR1_TE | CR1_RE) != 0;
        match reg {
            // rc_w0: RXNE, TC (and LBD, CTS); the rest read-only.
            UsartReg::Sr => self.sr &= value | !(SR_RXNE | SR_TC | (1 << 8) | (1 << 9)),
            UsartReg::Dr => self.dr_write(value as u8),
            UsartReg::Brr => {
                if active && value != self.brr {
                    self.violate("U1: BRR changed during communication");
                }
                self.brr = value;
            }
            UsartReg::Cr1 => self.cr1_write(value),
            UsartReg::Cr2 => {
                if active && (value ^ self.cr2) & CR2_STOP_MASK != 0 {
                    self.violate("U1: STOP changed with TE/RE on");
                }
                self.cr2 = value;
            }
            UsartReg::Cr3 => self.cr3 = value,
            UsartReg::Gtpr => self.gtpr = value,
        }
        // A write ends every "read SR, then …" sequence (a DR write is the
        // second half of TC's).
        self.armed_tc = false;
        self.armed_rx = false;
    }
}

impl Rs485Port for UsartModel {
    fn set_de(&mut self, high: bool) {
        if self.de && !high {
            self.de_low_at = Some(self.now);
        }
        self.de = high;
    }

    fn de_is_high(&self) -> bool {
        self.de
    }
}
