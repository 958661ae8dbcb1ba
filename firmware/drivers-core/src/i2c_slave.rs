//! Register-level I2C1 slave for the PoStep60 I2C protocol.
//!
//! stm32f4xx-hal 0.23 has no slave mode, so this module drives the STM32F4
//! "v1" I2C block (RM0090 §27: SR1/SR2 event sequences) register by register
//! through an [`I2cPort`] — on the chip the firmware's PAC glue for
//! `pac::I2C1` (`firmware::drivers::i2c_slave`), on the host the RM0090 model
//! `host_tests::rm0090::i2c`. Transaction framing and every byte's
//! meaning belong to [`I2cSlave`] in the logic crate; this module only moves
//! bytes between the peripheral and it.
//!
//! # What it guarantees
//!
//! * 7-bit slave at one or two own addresses: OAR1 = the primary address
//!   (axis 0), OAR2 with ENDUAL = the secondary one (axis 1) if there is
//!   one; SR2.DUALF tells which one the master addressed. No general call,
//!   no 10-bit addressing.
//! * The master sets the bus rate: standard (100 kHz) and fast (400 kHz)
//!   mode both work, because FREQ is APB1 (42 MHz, at least the 4 MHz that
//!   fast mode needs). CCR and TRISE only matter in master mode and stay at
//!   their reset values.
//! * Clock stretching is on (NOSTRETCH = 0): the peripheral holds SCL low
//!   until the handler has served ADDR, a received byte (BTF) or the next
//!   byte to send, so a late interrupt costs time on the bus, never a byte.
//! * The handlers never block, never wait on a flag and never panic. One
//!   call does a bounded amount of work (at most one NACK, one bus error,
//!   two data-register reads, one STOP, one address event, one
//!   data-register write, and the logic calls they lead to); whatever is
//!   left keeps the interrupt pending and is served by the next call.
//! * Every flag seen set gets its clearing action in the same call, so no
//!   flag combination can make the interrupt fire forever.
//! * A bus error (BERR, ARLO, OVR, and the SMBus-only TIMEOUT / PECERR /
//!   SMBALERT, which cannot occur in I2C mode) drops the transaction in
//!   progress. If the peripheral then still claims BUSY while both lines are
//!   high (an idle bus), it is reset through CR1.SWRST and configured again
//!   with the same addresses (RM0090 suggests SWRST for exactly this).
//!
//! # Event sequence (RM0090 slave transfer sequences)
//!
//! `on_event` (I2C1_EV) reads SR1 and serves, in this order (each "read SR1,
//! then …" clear sequence reads SR1 again right before its second half, so
//! nothing else separates the pair):
//!
//! 0. AF and bus errors, exactly as `on_error` below. A NACK or bus error
//!    still pending happened before any pending ADDR (ADDR stretches SCL, so
//!    the new transaction cannot move on), and I2C1_EV is served before
//!    I2C1_ER when both are pending at one priority (lower IRQ number): a
//!    read NACKed and followed at once by a repeated START for a write must
//!    end the read before the write begins, not after.
//! 1. RXNE — a byte of a master write: read SR1, then DR (which also clears
//!    BTF). At most two bytes can wait (DR and the shift register, BTF set),
//!    so it drains up to two. Received bytes come before steps 2 and 3
//!    because a pending byte always belongs to the write that a STOP or a
//!    repeated START ends.
//! 2. STOPF — the end of a master write: read SR1, then write CR1
//!    (re-asserting ACK), which clears STOPF; then `on_stop`.
//! 3. ADDR — read SR1, then SR2, which clears ADDR. SR2.TRA is the direction
//!    (1 = the master reads), SR2.DUALF which own address matched; then
//!    `on_address`. ITBUFEN is switched on, for the RXNE of a write or the
//!    TXE of a read's first byte, which sets only once ADDR is clear: the
//!    call ends here and that TXE is the next interrupt.
//!    If STOPF and ADDR are both pending, the STOP ended the previous
//!    transaction: ADDR stretches SCL, so the new one cannot have reached
//!    its STOP yet.
//! 4. TXE — a master read: the first byte (EV3-1, right after ADDR) is
//!    written to DR at TXE; every later byte at BTF (TXE with the shift
//!    register empty: the previous byte went out and was ACKed; read SR1,
//!    then the DR write clears BTF). After the first byte ITBUFEN goes off,
//!    so TXE alone no longer interrupts. DR is thus never loaded ahead: when
//!    the master NACKs the last byte it wants, no unsent byte is left in DR
//!    to come out first in the next read. The price is SCL stretched for the
//!    interrupt latency (~1 µs) between the bytes of a read.
//!
//! `on_error` (I2C1_ER) reads SR1 and serves:
//!
//! * AF — the master NACKed a byte we sent: the normal end of a read (no
//!   STOPF follows a NACK). AF is cleared by writing 0 to it; `on_stop`.
//!   ITBUFEN goes off (TXE stays set until the master's STOP or repeated
//!   START; the next ADDR switches ITBUFEN on again).
//! * BERR / ARLO / OVR (and the SMBus flags): each flag seen set is cleared
//!   by writing 0 to it; `on_bus_error`; then the BUSY check above. SR2 (for
//!   BUSY) is read only after a fresh SR1 read shows ADDR clear, so the
//!   check can never swallow a pending ADDR.
//!
//! # Assumptions
//!
//! * `on_event` and `on_error` never preempt each other (bind both
//!   interrupts at the same priority).
//! * [`I2cSlaveDriver::set_addresses`] is called from a task that never
//!   preempts the handlers (the same priority): by the I2C event task after
//!   a write that changed the address base (between transactions: the bridge
//!   changes its address after the reply), or by the Modbus server task at
//!   any time. A change takes effect at the next address phase; a
//!   transaction already addressed goes on to its end.
//! * The pins come configured from `firmware::pins::host_i2c_pins`.

use bridge_logic::transport::i2c::{I2cSlave, I2cTarget, Which};

use crate::Regs;

/// The I2C block's registers (RM0090 §27.6; byte offsets in [`I2cReg::offset`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum I2cReg {
    Cr1,
    Cr2,
    Oar1,
    Oar2,
    Dr,
    Sr1,
    Sr2,
    Ccr,
    Trise,
}

impl I2cReg {
    /// Offset from the peripheral's base address (RM0090 §27.6.10, register map).
    pub const fn offset(self) -> usize {
        match self {
            I2cReg::Cr1 => 0x00,
            I2cReg::Cr2 => 0x04,
            I2cReg::Oar1 => 0x08,
            I2cReg::Oar2 => 0x0C,
            I2cReg::Dr => 0x10,
            I2cReg::Sr1 => 0x14,
            I2cReg::Sr2 => 0x18,
            I2cReg::Ccr => 0x1C,
            I2cReg::Trise => 0x20,
        }
    }
}

/// Register bits (RM0090 §27.6.1–§27.6.7).
pub mod bits {
    // CR1
    pub const CR1_PE: u32 = 1 << 0;
    pub const CR1_SMBUS: u32 = 1 << 1;
    pub const CR1_ENGC: u32 = 1 << 6;
    pub const CR1_NOSTRETCH: u32 = 1 << 7;
    pub const CR1_START: u32 = 1 << 8;
    pub const CR1_STOP: u32 = 1 << 9;
    pub const CR1_ACK: u32 = 1 << 10;
    pub const CR1_SWRST: u32 = 1 << 15;
    // CR2
    pub const CR2_FREQ_MASK: u32 = 0x3F;
    pub const CR2_ITERREN: u32 = 1 << 8;
    pub const CR2_ITEVTEN: u32 = 1 << 9;
    pub const CR2_ITBUFEN: u32 = 1 << 10;
    // OAR1 / OAR2
    /// OAR1 bit 14 "should always be kept at 1 by software" (RM0090 §27.6.3).
    pub const OAR1_BIT14: u32 = 1 << 14;
    pub const OAR1_ADDMODE: u32 = 1 << 15;
    pub const OAR2_ENDUAL: u32 = 1 << 0;
    // SR1
    pub const SR1_SB: u32 = 1 << 0;
    pub const SR1_ADDR: u32 = 1 << 1;
    pub const SR1_BTF: u32 = 1 << 2;
    pub const SR1_ADD10: u32 = 1 << 3;
    pub const SR1_STOPF: u32 = 1 << 4;
    pub const SR1_RXNE: u32 = 1 << 6;
    pub const SR1_TXE: u32 = 1 << 7;
    pub const SR1_BERR: u32 = 1 << 8;
    pub const SR1_ARLO: u32 = 1 << 9;
    pub const SR1_AF: u32 = 1 << 10;
    pub const SR1_OVR: u32 = 1 << 11;
    pub const SR1_PECERR: u32 = 1 << 12;
    pub const SR1_TIMEOUT: u32 = 1 << 14;
    pub const SR1_SMBALERT: u32 = 1 << 15;
    /// The SR1 flags cleared by writing 0 (rc_w0); writing 1 leaves them.
    pub const SR1_RC_W0: u32 =
        SR1_BERR | SR1_ARLO | SR1_AF | SR1_OVR | SR1_PECERR | SR1_TIMEOUT | SR1_SMBALERT;
    /// The bus-error flags (everything rc_w0 but AF).
    pub const SR1_BUS_ERRORS: u32 = SR1_RC_W0 & !SR1_AF;
    // SR2
    pub const SR2_MSL: u32 = 1 << 0;
    pub const SR2_BUSY: u32 = 1 << 1;
    pub const SR2_TRA: u32 = 1 << 2;
    pub const SR2_DUALF: u32 = 1 << 7;
}

use bits::*;

/// What the driver needs of I2C1 besides its registers: the bus lines'
/// levels (GPIO inputs), for the stuck-BUSY check.
pub trait I2cPort: Regs<I2cReg> {
    /// SCL and SDA both read high (an idle bus).
    fn lines_high(&mut self) -> bool;
}

/// CR2.FREQ limits: RM0090 allows 2 MHz (standard mode; fast mode needs
/// 4 MHz) up to the APB1 maximum, which is 42 MHz on the F405.
pub const FREQ_MIN_MHZ: u32 = 2;
pub const FREQ_MAX_MHZ: u32 = 42;
/// At most this many received bytes wait in the peripheral: DR plus the
/// shift register (BTF).
const RX_DEPTH: usize = 2;

/// Where the current transaction stands, as far as the driver cares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mode {
    /// No transaction of ours in progress.
    Idle,
    /// Addressed for a master write: bytes arrive at RXNE.
    Receiving,
    /// Addressed for a master read, first byte not yet in DR (goes at TXE).
    SendingFirst,
    /// Master read in progress: each further byte goes at BTF.
    Sending,
}

/// CR2.FREQ for an APB1 clock of `pclk1_hz`, clamped to what RM0090 allows.
pub fn freq_mhz(pclk1_hz: u32) -> u8 {
    let mhz = (pclk1_hz / 1_000_000).clamp(FREQ_MIN_MHZ, FREQ_MAX_MHZ);
    u8::try_from(mhz).unwrap_or(FREQ_MAX_MHZ as u8)
}

/// An I2C block as a PoStep60 I2C slave (see the module docs).
#[derive(Debug)]
pub struct I2cSlaveDriver<P> {
    port: P,
    /// CR2.FREQ: the APB1 clock in MHz.
    freq_mhz: u8,
    /// OAR1, 7-bit.
    primary: u8,
    /// OAR2, 7-bit; `None`: dual addressing off.
    secondary: Option<u8>,
    mode: Mode,
    /// Peripheral resets (SWRST) after a bus error left it stuck BUSY.
    resets: u32,
}

impl<P: I2cPort> I2cSlaveDriver<P> {
    /// Start `port` (enabled and reset through the RCC by the caller) as a
    /// slave at `primary` (OAR1) and, if given, `secondary` (OAR2), with
    /// CR2.FREQ = `freq_mhz` (see [`freq_mhz`]). Addresses are 7-bit; an
    /// eighth bit is ignored. Interrupts are enabled in the peripheral; the
    /// NVIC side is the caller's.
    pub fn new(port: P, freq_mhz: u8, primary: u8, secondary: Option<u8>) -> Self {
        let mut driver = I2cSlaveDriver {
            port,
            freq_mhz: freq_mhz.clamp(FREQ_MIN_MHZ as u8, FREQ_MAX_MHZ as u8),
            primary: primary & 0x7F,
            secondary: secondary.map(|a| a & 0x7F),
            mode: Mode::Idle,
            resets: 0,
        };
        driver.configure();
        driver
    }

    /// The port (on the host: the peripheral model).
    pub fn port(&self) -> &P {
        &self.port
    }

    /// The port, mutably (on the host: to drive the model's bus side).
    pub fn port_mut(&mut self) -> &mut P {
        &mut self.port
    }

    /// The own addresses `(primary, secondary)` in use.
    pub fn addresses(&self) -> (u8, Option<u8>) {
        (self.primary, self.secondary)
    }

    /// Change the own addresses (7-bit; an eighth bit is ignored; no
    /// secondary: dual addressing off). Call it between transactions; it
    /// takes effect at the next address phase. Writes nothing when both are
    /// unchanged.
    pub fn set_addresses(&mut self, primary: u8, secondary: Option<u8>) {
        let (primary, secondary) = (primary & 0x7F, secondary.map(|a| a & 0x7F));
        if (primary, secondary) != (self.primary, self.secondary) {
            self.primary = primary;
            self.secondary = secondary;
            self.write_addresses();
        }
    }

    /// CR2.FREQ in use (the APB1 clock in MHz).
    pub fn freq_mhz(&self) -> u8 {
        self.freq_mhz
    }

    /// Peripheral resets since boot (bus errors that left it stuck BUSY).
    pub fn resets(&self) -> u32 {
        self.resets
    }

    /// I2C1_EV: serve address, data and STOP events (module docs, steps 0–4).
    pub fn on_event(&mut self, slave: &mut I2cSlave, target: &mut impl I2cTarget) {
        let sr1 = self.port.read(I2cReg::Sr1);

        // 0. A NACK or bus error still pending belongs to the transaction
        // before any pending ADDR (ADDR stretches SCL): serve it first.
        // I2C1_EV outranks I2C1_ER at equal priority, so this is the place.
        // After a peripheral reset the rest of `sr1` is stale: stop there.
        if self.serve_errors(sr1, slave, target) {
            return;
        }

        // 1. Bytes of a master write (and BTF in receiver mode).
        if sr1 & SR1_RXNE != 0 {
            self.drain_rx(slave);
        }

        // 2. STOP after a master write: read SR1, then write CR1. SR1 is
        // read again so nothing separates the pair.
        if sr1 & SR1_STOPF != 0 {
            let _ = self.port.read(I2cReg::Sr1);
            self.port.modify(I2cReg::Cr1, |cr1| cr1 | CR1_ACK);
            slave.on_stop(target);
            self.mode = Mode::Idle;
        }

        // 3. Own address matched: read SR1, then SR2, which clears ADDR.
        if sr1 & SR1_ADDR != 0 {
            let _ = self.port.read(I2cReg::Sr1);
            let sr2 = self.port.read(I2cReg::Sr2);
            let which = if sr2 & SR2_DUALF != 0 {
                Which::Secondary
            } else {
                Which::Primary
            };
            let read = sr2 & SR2_TRA != 0;
            slave.on_address(which, read, target);
            self.mode = if read {
                Mode::SendingFirst
            } else {
                Mode::Receiving
            };
            // RXNE of the write, or the TXE (EV3-1) of the read's first
            // byte: that TXE sets only now, so it is the next interrupt.
            self.port.modify(I2cReg::Cr2, |cr2| cr2 | CR2_ITBUFEN);
            return;
        }

        // 4. A master read: the first byte at TXE, the others at BTF. A fresh
        // SR1 read is the first half of the BTF clear (SR1, then DR write).
        let sr1 = self.port.read(I2cReg::Sr1);
        if sr1 & SR1_TXE != 0 {
            if self.mode == Mode::SendingFirst || sr1 & SR1_BTF != 0 {
                let byte = slave.on_byte_requested();
                self.port.write(I2cReg::Dr, u32::from(byte));
                self.mode = Mode::Sending;
            }
            // From here on BTF (an ITEVTEN event) paces the read; TXE alone
            // must not interrupt (it stays set until the master's STOP or
            // repeated START after its NACK).
            self.port.modify(I2cReg::Cr2, |cr2| cr2 & !CR2_ITBUFEN);
        }
    }

    /// I2C1_ER: master NACK (end of a read) and bus errors (module docs).
    /// Needs the target because a NACK ends the transaction (`on_stop`).
    pub fn on_error(&mut self, slave: &mut I2cSlave, target: &mut impl I2cTarget) {
        let sr1 = self.port.read(I2cReg::Sr1);
        self.serve_errors(sr1, slave, target);
    }

    /// AF and the bus-error flags set in `sr1` (both handlers call this).
    /// Returns whether the peripheral was reset.
    fn serve_errors(
        &mut self,
        sr1: u32,
        slave: &mut I2cSlave,
        target: &mut impl I2cTarget,
    ) -> bool {
        if sr1 & SR1_AF != 0 {
            // rc_w0: write 0 to AF and 1 to every other rc_w0 flag (which
            // leaves them as they are).
            self.port.write(I2cReg::Sr1, SR1_RC_W0 & !SR1_AF);
            self.port.modify(I2cReg::Cr2, |cr2| cr2 & !CR2_ITBUFEN);
            slave.on_stop(target);
            self.mode = Mode::Idle;
        }

        let errors = sr1 & SR1_BUS_ERRORS;
        if errors != 0 {
            // Clear exactly the flags seen set: one that sets after the read
            // above stays pending for the next call.
            self.port.write(I2cReg::Sr1, SR1_RC_W0 & !errors);
            slave.on_bus_error();
            self.mode = Mode::Idle;
            if self.stuck_busy() {
                self.resets = self.resets.wrapping_add(1);
                self.port.write(I2cReg::Cr1, CR1_SWRST);
                self.port.write(I2cReg::Cr1, 0);
                self.configure();
                return true;
            }
        }
        false
    }

    /// BUSY set while SCL and SDA are both high: the peripheral missed a STOP
    /// (a glitch) and would stay busy. The lines are checked first: while a
    /// master clocks a byte they are not both high, and SR2 is not read then,
    /// so an ADDR that sets between the SR1 and the SR2 read below (an
    /// SR1-then-SR2 pair clears it) cannot be lost: an address byte takes
    /// ≥ 22 µs from the lines' last idle sample. SR2 is also read only if
    /// SR1 shows no ADDR.
    fn stuck_busy(&mut self) -> bool {
        if !self.port.lines_high() {
            return false;
        }
        if self.port.read(I2cReg::Sr1) & SR1_ADDR != 0 {
            return false;
        }
        self.port.read(I2cReg::Sr2) & SR2_BUSY != 0
    }

    /// Read the waiting received bytes (at most [`RX_DEPTH`]) into `slave`:
    /// each one SR1 (RXNE, and the first half of a BTF clear), then DR.
    fn drain_rx(&mut self, slave: &mut I2cSlave) {
        for _ in 0..RX_DEPTH {
            if self.port.read(I2cReg::Sr1) & SR1_RXNE == 0 {
                break;
            }
            // DR is 8 bits wide; the truncation is the register's.
            slave.on_byte_received(self.port.read(I2cReg::Dr) as u8);
        }
    }

    /// Full configuration from the reset state: clock, interrupts, own
    /// addresses, then enable with ACK. Used at start and after SWRST.
    fn configure(&mut self) {
        self.port.write(I2cReg::Cr1, 0);
        // FREQ is clamped to 2..=42 (MHz), the range RM0090 allows.
        self.port.write(
            I2cReg::Cr2,
            (u32::from(self.freq_mhz) & CR2_FREQ_MASK) | CR2_ITEVTEN | CR2_ITBUFEN | CR2_ITERREN,
        );
        self.write_addresses();
        // Slave only: no general call, no SMBus, clock stretching on.
        self.port.write(I2cReg::Cr1, CR1_PE);
        // ACK is cleared by hardware while PE = 0: set it once PE is on.
        self.port.modify(I2cReg::Cr1, |cr1| cr1 | CR1_ACK);
        self.mode = Mode::Idle;
    }

    /// OAR1 = primary (7-bit mode, bit 14 kept at 1), OAR2 = secondary with
    /// dual addressing on, or dual addressing off without one.
    fn write_addresses(&mut self) {
        let oar1 = OAR1_BIT14 | (u32::from(self.primary) << 1);
        self.port.write(I2cReg::Oar1, oar1);
        let oar2 = match self.secondary {
            Some(secondary) => (u32::from(secondary) << 1) | OAR2_ENDUAL,
            None => 0,
        };
        self.port.write(I2cReg::Oar2, oar2);
    }
}
