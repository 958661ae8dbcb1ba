//! RM0090 §27: the STM32F4 I2C block ("v1") in 7-bit slave mode, as the
//! register interface of `drivers_core::i2c_slave` sees it, with the bus
//! side driven byte by byte by a simulated master ([`I2cModel::start`],
//! [`I2cModel::address`], [`I2cModel::master_write`],
//! [`I2cModel::master_read`], [`I2cModel::stop`]).
//!
//! # Rules (RM0090 rev 19 section numbers)
//!
//! | # | rule | section |
//! |---|---|---|
//! | A1 | ADDR is set when the address byte matches OAR1 (ADDMODE = 0) or, with ENDUAL, OAR2, and ACK = 1 (else the address is NACKed and the slave stays out); SR2.TRA is the R/W bit, SR2.DUALF which own address matched | §27.3.3 "Slave mode", §27.6.4, §27.6.7 |
//! | A2 | ADDR is cleared by a read of SR1 followed by a read of SR2 (the model: any SR1 read, see the modelling choices); until then SCL is stretched | §27.3.3, §27.6.6 (ADDR) |
//! | A3 | In transmitter mode TXE sets once ADDR is clear; with DR empty and the shift register empty SCL is stretched until DR is written (EV3-1) | §27.3.3 "Slave transmitter" |
//! | A4 | After a byte the master ACKs, DR (if written) moves to the shift register and TXE sets; if DR was not written, BTF sets and SCL is stretched until a read of SR1 (showing BTF) followed by a write of DR | §27.3.3 "Slave transmitter", §27.6.6 (BTF) |
//! | A5 | A byte the master NACKs sets AF (an error interrupt); no STOPF follows a NACK; AF is cleared by writing 0 to it | §27.3.3 "Closing slave communication", §27.3.5 "Acknowledge failure", §27.6.6 (AF, STOPF) |
//! | A6 | A received byte goes to DR and sets RXNE (cleared by reading DR); if DR is still full when the next byte has arrived, BTF sets and SCL is stretched until a read of SR1 (showing BTF) followed by a read of DR | §27.3.3 "Slave receiver", §27.6.6 (RXNE, BTF) |
//! | A7 | A STOP after an acknowledged byte sets STOPF; STOPF is cleared by a read of SR1 that shows it, followed by a write of CR1 | §27.3.3 "Closing slave communication", §27.6.6 (STOPF) |
//! | A8 | A repeated START or a STOP clears TRA and DUALF, and in transmission TXE and BTF; a byte left in DR stays there and goes out first in the next read | §27.6.6 (TXE, BTF), §27.6.7 (TRA, DUALF); DR's fate: UNCONFIRMED, see below |
//! | A9 | BERR, ARLO, OVR (and the SMBus flags) are rc_w0: writing 0 clears, writing 1 leaves; each raises the error interrupt | §27.6.6, §27.4 |
//! | A10 | A START or STOP in the middle of a byte is a bus error: BERR, the slave discards the byte and releases the lines | §27.3.5 "Bus error" |
//! | A11 | OVR only with NOSTRETCH = 1: a byte received while DR is full is lost | §27.3.5 "Overrun/underrun error" |
//! | A12 | ACK is cleared by hardware while PE = 0 (so it must be set after PE); PE = 0 clears the status flags | §27.6.1 (ACK, PE) |
//! | A13 | SWRST puts every register in its reset state (BUSY included); it must be used with the lines released | §27.6.1 (SWRST) |
//! | A14 | FREQ (CR2) must be 2..=42 MHz (≥ 4 for fast mode) when the peripheral is enabled; OAR1 bit 14 must be kept at 1 | §27.6.2, §27.6.3 |
//! | A15 | Event interrupt: ITEVTEN and (SB, ADDR, ADD10, STOPF, BTF, or with ITBUFEN: TXE, RXNE); error interrupt: ITERREN and any error flag | §27.4, Table 124 "I2C Interrupt requests" (table number UNCONFIRMED) |
//! | A16 | BUSY: set while a transfer is on the bus, cleared by a STOP | §27.6.7 (BUSY) |
//!
//! # Modelling choices (UNCONFIRMED: RM0090 does not say)
//!
//! * "Read SR1, followed by X": the model arms a clear with the flags an SR1
//!   read showed; X (SR2 read for ADDR, CR1 write for STOPF, DR access for
//!   BTF) clears what is armed. ADDR is the strict exception: every SR1
//!   read arms its clear, so an SR2 read after any SR1 read clears an ADDR
//!   that has set in between (the reading that assumes least of the
//!   silicon; the driver must never pair the two reads casually). Reads of other registers in between keep it
//!   armed (ST's own HAL reads CR1 between the two halves of the STOPF
//!   clear, and it works on silicon); any write, or a DR access, disarms.
//! * A byte written to DR that never went out (the master NACKed earlier)
//!   stays in DR through STOP and START and is the first byte of the next
//!   read (the behaviour ST's forum reports call "the stale byte"); TXE is
//!   cleared by the STOP/START as §27.6.6 says.
//! * A STOP or START while the slave transmitter has the next byte under
//!   way (the master ACKed the last byte it read and then stopped) is a
//!   misplaced condition: BERR (A10).
//! * A misplaced STOP sets no STOPF; BERR alone ends the transfer.
//! * The ACK pulse of a byte received while DR is full is given when the
//!   byte arrives; the stretch comes after it.
//! * Writes the manual forbids are recorded as violations ([`Violation`])
//!   on top of their effect: SR2 written, a flag cleared (rc_w0) that the
//!   last SR1 read did not show (an event lost), DR written while TXE = 0 or
//!   outside a read, a START/STOP bit set (master mode), FREQ out of range,
//!   OAR1 bit 14 clear, SWRST while the bus is not idle, a BTF clear without
//!   the SR1 read before it.

use std::collections::VecDeque;
use std::fmt;

use drivers_core::i2c_slave::bits::*;
use drivers_core::i2c_slave::{I2cPort, I2cReg};
use drivers_core::Regs;

/// The APB1 clock the model's peripheral runs on (the board's 42 MHz).
pub const APB1_MHZ: u32 = 42;
/// How many register accesses the model keeps for failure messages.
const TRACE: usize = 64;

/// SCL is held low by the slave (clock stretching): the master must wait.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Held;

/// One register access, as the bus saw it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    Read(I2cReg, u32),
    Write(I2cReg, u32),
}

/// Something RM0090 forbids or leaves undefined that a driver did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Violation(pub String);

/// Where the slave stands on the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Bus free (after a STOP, or never used).
    Idle,
    /// START seen: the address byte comes next.
    AwaitAddress,
    /// Another slave's transfer (or ours NACKed).
    Other,
    /// Addressed for a master write.
    Receiver,
    /// Addressed for a master read; the master ACKed every byte so far.
    Transmitter,
    /// The master NACKed a byte: waiting for its STOP or repeated START.
    AfterNack,
}

/// The I2C block (see the module docs).
pub struct I2cModel {
    cr1: u32,
    cr2: u32,
    oar1: u32,
    oar2: u32,
    ccr: u32,
    trise: u32,
    sr1: u32,
    busy: bool,
    tra: bool,
    dualf: bool,
    /// DR holds a byte: received and unread, or written and not yet sent.
    dr: Option<u8>,
    /// What a DR read returns when it holds nothing new.
    dr_last: u8,
    /// The shift register: a received byte waiting behind a full DR (BTF),
    /// or the byte being sent.
    shift: Option<u8>,
    role: Role,
    /// Transmitter, ADDR cleared, first byte not written yet (EV3-1).
    tx_first: bool,
    /// Flags an SR1 read armed for their "read SR1, then …" clear.
    armed: u32,
    /// What the last SR1 read returned.
    last_sr1: u32,
    /// The master stopped in the middle of a byte.
    mid_byte: bool,
    /// Flags to set right after the next SR1 read (a race, for tests).
    after_sr1: u32,
    trace: VecDeque<Access>,
    violations: Vec<Violation>,
}

impl Default for I2cModel {
    fn default() -> Self {
        I2cModel::new()
    }
}

impl fmt::Debug for I2cModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("I2cModel")
            .field("cr1", &format_args!("{:#06x}", self.cr1))
            .field("cr2", &format_args!("{:#06x}", self.cr2))
            .field("sr1", &format_args!("{:#06x}", self.sr1))
            .field("role", &self.role)
            .field("busy", &self.busy)
            .field("dr", &self.dr)
            .field("shift", &self.shift)
            .field("violations", &self.violations)
            .finish()
    }
}

impl I2cModel {
    /// The block as a reset leaves it (RCC reset): every register 0.
    pub fn new() -> I2cModel {
        I2cModel {
            cr1: 0,
            cr2: 0,
            oar1: 0,
            oar2: 0,
            ccr: 0,
            trise: 0x0002,
            sr1: 0,
            busy: false,
            tra: false,
            dualf: false,
            dr: None,
            dr_last: 0,
            shift: None,
            role: Role::Idle,
            tx_first: false,
            armed: 0,
            last_sr1: 0,
            mid_byte: false,
            after_sr1: 0,
            trace: VecDeque::new(),
            violations: Vec::new(),
        }
    }

    // ------------------------------------------------------------ views --

    pub fn cr1(&self) -> u32 {
        self.cr1
    }

    pub fn cr2(&self) -> u32 {
        self.cr2
    }

    pub fn sr1(&self) -> u32 {
        self.sr1
    }

    pub fn oar1(&self) -> u32 {
        self.oar1
    }

    pub fn oar2(&self) -> u32 {
        self.oar2
    }

    pub fn busy(&self) -> bool {
        self.busy
    }

    pub fn role(&self) -> Role {
        self.role
    }

    /// Violations so far (see the module docs).
    pub fn violations(&self) -> &[Violation] {
        &self.violations
    }

    /// The last register accesses, oldest first, one per line.
    pub fn trace(&self) -> String {
        self.trace
            .iter()
            .map(|a| match a {
                Access::Read(r, v) => format!("  read  {r:?} = {v:#06x}"),
                Access::Write(r, v) => format!("  write {r:?} = {v:#06x}"),
            })
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// A15: the event interrupt line.
    pub fn event_irq(&self) -> bool {
        let events = SR1_SB | SR1_ADDR | SR1_ADD10 | SR1_STOPF | SR1_BTF;
        self.cr2 & CR2_ITEVTEN != 0
            && (self.sr1 & events != 0
                || (self.cr2 & CR2_ITBUFEN != 0 && self.sr1 & (SR1_TXE | SR1_RXNE) != 0))
    }

    /// A15: the error interrupt line.
    pub fn error_irq(&self) -> bool {
        self.cr2 & CR2_ITERREN != 0 && self.sr1 & SR1_RC_W0 != 0
    }

    /// SCL held low by the slave (A2, A3, A4, A6).
    pub fn scl_held(&self) -> bool {
        if self.cr1 & CR1_PE == 0 || self.cr1 & CR1_NOSTRETCH != 0 {
            return false;
        }
        if self.sr1 & SR1_ADDR != 0 {
            return true;
        }
        match self.role {
            Role::Receiver => self.sr1 & SR1_BTF != 0,
            Role::Transmitter => self.sr1 & SR1_BTF != 0 || (self.tx_first && self.shift.is_none()),
            _ => false,
        }
    }

    fn violate(&mut self, what: impl Into<String>) {
        self.violations.push(Violation(what.into()));
    }

    fn set(&mut self, flags: u32) {
        self.sr1 |= flags;
    }

    fn clear(&mut self, flags: u32) {
        self.sr1 &= !flags;
    }

    // ------------------------------------------------------- bus side --

    /// The master's START (or repeated START).
    pub fn start(&mut self) -> Result<(), Held> {
        if self.scl_held() {
            return Err(Held);
        }
        if self.misplaced() {
            // A10: a misplaced START is taken as a restart.
            self.busy = true;
            self.role = Role::AwaitAddress;
            return Ok(());
        }
        self.busy = true;
        self.end_of_transfer();
        self.role = Role::AwaitAddress;
        Ok(())
    }

    /// The address byte after a START; returns whether it was ACKed (A1).
    pub fn address(&mut self, addr: u8, read: bool) -> Result<bool, Held> {
        if self.scl_held() {
            return Err(Held);
        }
        if self.role != Role::AwaitAddress {
            return Ok(false);
        }
        let addr = u32::from(addr & 0x7F);
        let matched = if self.cr1 & CR1_PE == 0 {
            None
        } else if self.oar1 & OAR1_ADDMODE == 0 && (self.oar1 >> 1) & 0x7F == addr {
            Some(false)
        } else if self.oar2 & OAR2_ENDUAL != 0 && (self.oar2 >> 1) & 0x7F == addr {
            Some(true)
        } else {
            None
        };
        let Some(dual) = matched.filter(|_| self.cr1 & CR1_ACK != 0) else {
            self.role = Role::Other;
            return Ok(false);
        };
        self.set(SR1_ADDR);
        self.tra = read;
        self.dualf = dual;
        self.role = if read {
            Role::Transmitter
        } else {
            Role::Receiver
        };
        self.tx_first = read;
        Ok(true)
    }

    /// A data byte from the master (the slave receives it); returns the ACK
    /// bit (A6, A11). Not addressed: nobody ACKs.
    pub fn master_write(&mut self, byte: u8) -> Result<bool, Held> {
        if self.scl_held() {
            return Err(Held);
        }
        if self.role != Role::Receiver {
            return Ok(false);
        }
        let ack = self.cr1 & CR1_ACK != 0;
        if self.dr.is_none() {
            self.dr = Some(byte);
            self.dr_last = byte;
            self.set(SR1_RXNE);
        } else if self.cr1 & CR1_NOSTRETCH != 0 {
            // A11: the new byte is lost.
            self.set(SR1_OVR);
        } else {
            self.shift = Some(byte);
            self.set(SR1_BTF);
        }
        Ok(ack)
    }

    /// The master clocks a byte out of the slave and ACKs it (`ack`) or
    /// not (A4, A5). Not addressed: the bus reads 0xFF.
    pub fn master_read(&mut self, ack: bool) -> Result<u8, Held> {
        if self.scl_held() {
            return Err(Held);
        }
        if self.role != Role::Transmitter {
            return Ok(0xFF);
        }
        let byte = match self.shift.take() {
            Some(b) => b,
            None => {
                // Only reachable with NOSTRETCH = 1 (an underrun, A11).
                self.set(SR1_OVR);
                0xFF
            }
        };
        self.tx_first = false;
        if ack {
            match self.dr.take() {
                Some(next) => {
                    self.shift = Some(next);
                    self.set(SR1_TXE);
                }
                None => self.set(SR1_BTF | SR1_TXE),
            }
        } else {
            self.set(SR1_AF);
            self.role = Role::AfterNack;
        }
        Ok(byte)
    }

    /// The master's STOP (A7, A16).
    pub fn stop(&mut self) -> Result<(), Held> {
        if self.scl_held() {
            return Err(Held);
        }
        self.busy = false;
        if self.misplaced() {
            self.role = Role::Idle;
            return Ok(());
        }
        match self.role {
            Role::Receiver => self.set(SR1_STOPF),
            Role::Transmitter => {
                // The next byte was under way (modelling choice, module docs).
                self.set(SR1_BERR);
                self.shift = None;
            }
            _ => {}
        }
        self.end_of_transfer();
        self.role = Role::Idle;
        Ok(())
    }

    /// The master gives up in the middle of a byte (it resets, or a
    /// glitch): its next START or STOP is misplaced (A10).
    pub fn abandon_mid_byte(&mut self) {
        self.mid_byte = true;
    }

    /// Set error flags as the bus would (BERR, ARLO, OVR; A9).
    pub fn inject(&mut self, flags: u32) {
        self.set(flags & SR1_RC_W0);
    }

    /// Set error flags right after the driver's next SR1 read: a flag that
    /// arrives between a handler's read and its clear (A9).
    pub fn inject_after_next_sr1_read(&mut self, flags: u32) {
        self.after_sr1 = flags & SR1_RC_W0;
    }

    /// A glitch the block took for a START without a STOP after it: BUSY
    /// stays set on an idle bus (what SWRST is for, A13).
    pub fn glitch_stuck_busy(&mut self) {
        self.busy = true;
    }

    /// A10: a START/STOP after the master stopped mid-byte.
    fn misplaced(&mut self) -> bool {
        if !std::mem::take(&mut self.mid_byte) {
            return false;
        }
        if matches!(
            self.role,
            Role::Receiver | Role::Transmitter | Role::AfterNack
        ) {
            self.set(SR1_BERR);
        }
        self.shift = None;
        self.clear(SR1_BTF | SR1_TXE);
        self.tra = false;
        self.dualf = false;
        self.tx_first = false;
        true
    }

    /// A8: what a STOP or repeated START does to the slave's flags.
    fn end_of_transfer(&mut self) {
        if matches!(self.role, Role::Transmitter | Role::AfterNack) {
            self.clear(SR1_TXE | SR1_BTF);
            self.shift = None;
        }
        self.tra = false;
        self.dualf = false;
        self.tx_first = false;
    }

    // --------------------------------------------------- register side --

    fn read_reg(&mut self, reg: I2cReg) -> u32 {
        match reg {
            I2cReg::Cr1 => self.cr1,
            I2cReg::Cr2 => self.cr2,
            I2cReg::Oar1 => self.oar1,
            I2cReg::Oar2 => self.oar2,
            I2cReg::Ccr => self.ccr,
            I2cReg::Trise => self.trise,
            I2cReg::Sr1 => {
                let v = self.sr1;
                // ADDR's clear is armed by any SR1 read (modelling choices).
                self.armed = (v & (SR1_STOPF | SR1_BTF)) | SR1_ADDR;
                self.last_sr1 = v;
                let late = std::mem::take(&mut self.after_sr1);
                self.set(late);
                v
            }
            I2cReg::Sr2 => {
                let v = (u32::from(self.busy) * SR2_BUSY)
                    | (u32::from(self.tra) * SR2_TRA)
                    | (u32::from(self.dualf) * SR2_DUALF);
                if self.armed & SR1_ADDR != 0 && self.sr1 & SR1_ADDR != 0 {
                    self.armed &= !SR1_ADDR;
                    self.addr_cleared();
                }
                v
            }
            I2cReg::Dr => {
                let v = u32::from(self.dr_last);
                self.dr_read();
                self.armed = 0;
                v
            }
        }
    }

    /// A2, A3: what follows the ADDR clear.
    fn addr_cleared(&mut self) {
        self.clear(SR1_ADDR);
        if self.role == Role::Transmitter {
            self.set(SR1_TXE);
            if let Some(stale) = self.dr.take() {
                // A8 (modelling choice): the byte left in DR goes out first.
                self.shift = Some(stale);
                self.tx_first = false;
            }
        }
    }

    /// A6: a DR read in receiver mode.
    fn dr_read(&mut self) {
        if self.sr1 & SR1_RXNE == 0 {
            return;
        }
        self.dr = None;
        self.clear(SR1_RXNE);
        if self.sr1 & SR1_BTF != 0 {
            if self.armed & SR1_BTF != 0 {
                self.clear(SR1_BTF);
            } else {
                self.violate(
                    "BTF (receiver): DR read without the SR1 read before it; SCL stays low",
                );
            }
            if let Some(b) = self.shift.take() {
                self.dr = Some(b);
                self.dr_last = b;
                self.set(SR1_RXNE);
            }
        }
    }

    /// A3, A4: a DR write.
    fn dr_write(&mut self, byte: u8) {
        self.dr_last = byte;
        match self.role {
            Role::Transmitter if self.sr1 & SR1_ADDR == 0 => {
                if self.sr1 & SR1_BTF != 0 {
                    if self.armed & SR1_BTF != 0 {
                        self.clear(SR1_BTF);
                        self.shift = Some(byte);
                        self.set(SR1_TXE);
                    } else {
                        self.violate("BTF (transmitter): DR written without the SR1 read before it; SCL stays low");
                        self.dr = Some(byte);
                        self.clear(SR1_TXE);
                    }
                } else if self.tx_first && self.shift.is_none() {
                    // EV3-1: straight into the shift register; DR empty again.
                    self.shift = Some(byte);
                    self.tx_first = false;
                    self.set(SR1_TXE);
                } else {
                    if self.dr.is_some() {
                        self.violate("DR written while TXE = 0: the unsent byte is overwritten");
                    }
                    self.dr = Some(byte);
                    self.clear(SR1_TXE);
                }
            }
            _ => {
                self.violate(format!(
                    "DR written outside a master read ({:?})",
                    self.role
                ));
                self.dr = Some(byte);
                self.clear(SR1_TXE);
            }
        }
    }

    fn write_reg(&mut self, reg: I2cReg, value: u32) {
        let value = value & 0xFFFF;
        match reg {
            I2cReg::Cr1 => self.cr1_write(value),
            I2cReg::Cr2 => self.cr2 = value & 0x1F3F,
            I2cReg::Oar1 => self.oar1 = value,
            I2cReg::Oar2 => self.oar2 = value & 0xFF,
            I2cReg::Ccr => self.ccr = value,
            I2cReg::Trise => self.trise = value & 0x3F,
            I2cReg::Dr => self.dr_write(value as u8),
            I2cReg::Sr1 => {
                // A9: rc_w0 bits clear on 0, stay on 1; the others are read-only.
                let cleared = self.sr1 & SR1_RC_W0 & !value;
                let unseen = cleared & !self.last_sr1;
                if unseen != 0 {
                    self.violate(format!(
                        "SR1 write cleared {unseen:#06x}, which the last SR1 read did not show (an event lost)"
                    ));
                }
                self.sr1 &= !cleared;
            }
            I2cReg::Sr2 => self.violate("SR2 is read-only"),
        }
        // A write ends every "read SR1, then …" sequence.
        self.armed = 0;
    }

    fn cr1_write(&mut self, value: u32) {
        if value & CR1_SWRST != 0 {
            // A13.
            if self.role != Role::Idle || self.scl_held() {
                self.violate("SWRST while the bus is not idle");
            }
            let trace = std::mem::take(&mut self.trace);
            let violations = std::mem::take(&mut self.violations);
            *self = I2cModel::new();
            self.trace = trace;
            self.violations = violations;
            self.cr1 = CR1_SWRST;
            return;
        }
        if value & (CR1_START | CR1_STOP) != 0 {
            self.violate("START/STOP set: master mode in a slave driver");
        }
        // A7: a CR1 write after an SR1 read that showed STOPF clears it.
        if self.armed & SR1_STOPF != 0 {
            self.clear(SR1_STOPF);
        }
        let was_on = self.cr1 & CR1_PE != 0;
        let mut value = value;
        if value & CR1_PE == 0 {
            // A12: ACK cannot be set while PE = 0; PE = 0 clears the flags.
            value &= !CR1_ACK;
            self.sr1 = 0;
            self.tra = false;
            self.dualf = false;
            self.dr = None;
            self.shift = None;
            self.tx_first = false;
            if matches!(
                self.role,
                Role::Receiver | Role::Transmitter | Role::AfterNack
            ) {
                self.role = Role::Other;
            }
        } else if !was_on {
            // A14: checked when the block is switched on.
            let freq = self.cr2 & CR2_FREQ_MASK;
            if !(2..=APB1_MHZ).contains(&freq) {
                self.violate(format!("PE set with CR2.FREQ = {freq} (2..=42 allowed)"));
            }
            if self.oar1 & OAR1_BIT14 == 0 {
                self.violate("PE set with OAR1 bit 14 = 0");
            }
        }
        self.cr1 = value;
    }

    fn log(&mut self, access: Access) {
        if self.trace.len() == TRACE {
            self.trace.pop_front();
        }
        self.trace.push_back(access);
    }
}

impl Regs<I2cReg> for I2cModel {
    fn read(&mut self, reg: I2cReg) -> u32 {
        let v = self.read_reg(reg);
        self.log(Access::Read(reg, v));
        v
    }

    fn write(&mut self, reg: I2cReg, value: u32) {
        self.log(Access::Write(reg, value));
        self.write_reg(reg, value);
    }
}

impl I2cPort for I2cModel {
    fn lines_high(&mut self) -> bool {
        self.role == Role::Idle && !self.scl_held()
    }
}
