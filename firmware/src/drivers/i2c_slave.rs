//! Register-level I2C1 slave for the PoStep60 I2C protocol.
//!
//! stm32f4xx-hal 0.23 has no slave mode, so this module drives the STM32F4
//! "v1" I2C block (RM0090, I2C chapter: SR1/SR2 event sequences) directly
//! through the owned `pac::I2C1`. Transaction framing and every byte's
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
//! * The pins come configured from [`crate::board::host_i2c_pins`].

// Register access goes through the owned `pac::I2C1`, which needs no unsafe;
// the only unsafe blocks are the two field writers the PAC marks unsafe
// because the SVD gives no value range (CR2.FREQ, and OAR1's raw bits for
// bit 14, which the SVD does not describe at all).
#![allow(unsafe_code)]

use bridge_logic::transport::i2c::{I2cSlave, I2cTarget, Which, Write, RESPONSE_MAX};
use rtic::Mutex;
use stm32f4xx_hal::pac::i2c1::sr1 as pac_sr1;
use stm32f4xx_hal::rcc::{Enable, Rcc, Reset};

use crate::board::{HostI2c, HostI2cScl, HostI2cSda};

/// CR2.FREQ limits: RM0090 allows 2 MHz (standard mode; fast mode needs
/// 4 MHz) up to the APB1 maximum, which is 42 MHz on the F405.
const FREQ_MIN_MHZ: u32 = 2;
const FREQ_MAX_MHZ: u32 = 42;
/// OAR1 bit 14 "should always be kept at 1 by software" (RM0090).
const OAR1_BIT14: u16 = 1 << 14;
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

/// The I2C1 peripheral as a PoStep60 I2C slave (see the module docs).
pub struct I2cSlaveDriver {
    i2c: HostI2c,
    scl: HostI2cScl,
    sda: HostI2cSda,
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

impl I2cSlaveDriver {
    /// Enable and reset I2C1 through the RCC and start it as a slave at
    /// `primary` (OAR1) and, if given, `secondary` (OAR2). Addresses are
    /// 7-bit; an eighth bit is ignored. Interrupts are enabled in the
    /// peripheral; the NVIC side is RTIC's (the tasks bound to I2C1_EV /
    /// I2C1_ER).
    pub fn new(
        i2c: HostI2c,
        pins: (HostI2cScl, HostI2cSda),
        primary: u8,
        secondary: Option<u8>,
        rcc: &mut Rcc,
    ) -> I2cSlaveDriver {
        HostI2c::enable(rcc);
        HostI2c::reset(rcc);
        let mhz = (rcc.clocks.pclk1().raw() / 1_000_000).clamp(FREQ_MIN_MHZ, FREQ_MAX_MHZ);
        let mut driver = I2cSlaveDriver {
            i2c,
            scl: pins.0,
            sda: pins.1,
            freq_mhz: u8::try_from(mhz).unwrap_or(FREQ_MAX_MHZ as u8),
            primary: primary & 0x7F,
            secondary: secondary.map(|a| a & 0x7F),
            mode: Mode::Idle,
            resets: 0,
        };
        driver.configure();
        driver
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
        let sr1 = self.i2c.sr1().read();

        // 0. A NACK or bus error still pending belongs to the transaction
        // before any pending ADDR (ADDR stretches SCL): serve it first.
        // I2C1_EV outranks I2C1_ER at equal priority, so this is the place.
        // After a peripheral reset the rest of `sr1` is stale: stop there.
        if self.serve_errors(&sr1, slave, target) {
            return;
        }

        // 1. Bytes of a master write (and BTF in receiver mode).
        if sr1.rx_ne().bit_is_set() {
            self.drain_rx(slave);
        }

        // 2. STOP after a master write: read SR1, then write CR1. SR1 is
        // read again so nothing separates the pair.
        if sr1.stopf().bit_is_set() {
            let _ = self.i2c.sr1().read();
            self.i2c.cr1().modify(|_, w| w.ack().set_bit());
            slave.on_stop(target);
            self.mode = Mode::Idle;
        }

        // 3. Own address matched: read SR1, then SR2, which clears ADDR.
        if sr1.addr().bit_is_set() {
            let _ = self.i2c.sr1().read();
            let sr2 = self.i2c.sr2().read();
            let which = if sr2.dualf().bit_is_set() {
                Which::Secondary
            } else {
                Which::Primary
            };
            let read = sr2.tra().bit_is_set();
            slave.on_address(which, read, target);
            self.mode = if read {
                Mode::SendingFirst
            } else {
                Mode::Receiving
            };
            // RXNE of the write, or the TXE (EV3-1) of the read's first
            // byte: that TXE sets only now, so it is the next interrupt.
            self.i2c.cr2().modify(|_, w| w.itbufen().set_bit());
            return;
        }

        // 4. A master read: the first byte at TXE, the others at BTF. A fresh
        // SR1 read is the first half of the BTF clear (SR1, then DR write).
        let sr1 = self.i2c.sr1().read();
        if sr1.tx_e().bit_is_set() {
            if self.mode == Mode::SendingFirst || sr1.btf().bit_is_set() {
                let byte = slave.on_byte_requested();
                self.i2c.dr().write(|w| w.dr().set(byte));
                self.mode = Mode::Sending;
            }
            // From here on BTF (an ITEVTEN event) paces the read; TXE alone
            // must not interrupt (it stays set until the master's STOP or
            // repeated START after its NACK).
            self.i2c.cr2().modify(|_, w| w.itbufen().clear_bit());
        }
    }

    /// I2C1_ER: master NACK (end of a read) and bus errors (module docs).
    /// Needs the target because a NACK ends the transaction (`on_stop`).
    pub fn on_error(&mut self, slave: &mut I2cSlave, target: &mut impl I2cTarget) {
        let sr1 = self.i2c.sr1().read();
        self.serve_errors(&sr1, slave, target);
    }

    /// AF and the bus-error flags set in `sr1` (both handlers call this).
    /// Returns whether the peripheral was reset.
    fn serve_errors(
        &mut self,
        sr1: &pac_sr1::R,
        slave: &mut I2cSlave,
        target: &mut impl I2cTarget,
    ) -> bool {
        if sr1.af().bit_is_set() {
            // SR1 flags are cleared by writing 0; the PAC's `write` leaves
            // every other flag at 1 (unchanged).
            self.i2c.sr1().write(|w| w.af().clear());
            self.i2c.cr2().modify(|_, w| w.itbufen().clear_bit());
            slave.on_stop(target);
            self.mode = Mode::Idle;
        }

        let berr = sr1.berr().bit_is_set();
        let arlo = sr1.arlo().bit_is_set();
        let ovr = sr1.ovr().bit_is_set();
        let timeout = sr1.timeout().bit_is_set();
        let pecerr = sr1.pecerr().bit_is_set();
        let smbalert = sr1.smbalert().bit_is_set();
        if berr || arlo || ovr || timeout || pecerr || smbalert {
            // Clear exactly the flags seen set: one that sets after the read
            // above stays pending for the next call.
            self.i2c.sr1().write(|w| {
                if berr {
                    w.berr().clear();
                }
                if arlo {
                    w.arlo().clear();
                }
                if ovr {
                    w.ovr().clear();
                }
                if timeout {
                    w.timeout().clear();
                }
                if pecerr {
                    w.pecerr().clear();
                }
                if smbalert {
                    w.smbalert().clear();
                }
                w
            });
            slave.on_bus_error();
            self.mode = Mode::Idle;
            if self.stuck_busy() {
                self.resets = self.resets.wrapping_add(1);
                self.i2c.cr1().write(|w| w.swrst().set_bit());
                self.i2c.cr1().write(|w| w.swrst().clear_bit());
                self.configure();
                return true;
            }
        }
        false
    }

    /// BUSY set while SCL and SDA are both high: the peripheral missed a STOP
    /// (a glitch) and would stay busy. Reads SR2 only if SR1, read just
    /// before, shows no ADDR (an SR1-then-SR2 read would clear it).
    fn stuck_busy(&self) -> bool {
        if self.i2c.sr1().read().addr().bit_is_set() {
            return false;
        }
        self.i2c.sr2().read().busy().bit_is_set() && self.scl.is_high() && self.sda.is_high()
    }

    /// Read the waiting received bytes (at most [`RX_DEPTH`]) into `slave`.
    fn drain_rx(&mut self, slave: &mut I2cSlave) {
        for _ in 0..RX_DEPTH {
            if self.i2c.sr1().read().rx_ne().bit_is_clear() {
                break;
            }
            slave.on_byte_received(self.i2c.dr().read().dr().bits());
        }
    }

    /// Full configuration from the reset state: clock, interrupts, own
    /// addresses, then enable with ACK. Used at start and after SWRST.
    fn configure(&mut self) {
        self.i2c.cr1().write(|w| w.pe().clear_bit());
        let freq = self.freq_mhz;
        // SAFETY: FREQ is a plain 6-bit field; `freq` is clamped to
        // 2..=42 (MHz), inside the range RM0090 allows (2 MHz up to the APB1
        // maximum). The PAC marks the writer unsafe only because the SVD
        // states no range.
        self.i2c.cr2().write(|w| unsafe {
            w.freq()
                .bits(freq)
                .itevten()
                .set_bit()
                .itbufen()
                .set_bit()
                .iterren()
                .set_bit()
        });
        self.write_addresses();
        // Slave only: no general call, no SMBus, clock stretching on.
        self.i2c.cr1().write(|w| {
            w.pe()
                .set_bit()
                .engc()
                .clear_bit()
                .nostretch()
                .clear_bit()
                .smbus()
                .clear_bit()
        });
        // ACK is cleared by hardware while PE = 0: set it once PE is on.
        self.i2c.cr1().modify(|_, w| w.ack().set_bit());
        self.mode = Mode::Idle;
    }

    /// OAR1 = primary (7-bit mode, bit 14 kept at 1), OAR2 = secondary with
    /// dual addressing on, or dual addressing off without one.
    fn write_addresses(&mut self) {
        let oar1 = OAR1_BIT14 | (u16::from(self.primary) << 1);
        // SAFETY: the value has ADDMODE = 0 (7-bit), bit 14 = 1 as RM0090
        // requires, and the 7-bit address in ADD[7:1]; every other bit is 0
        // (reserved or ADD0/ADD[9:8], unused in 7-bit mode). Raw bits are
        // needed only because the SVD does not describe bit 14.
        self.i2c.oar1().write(|w| unsafe { w.bits(oar1) });
        match self.secondary {
            Some(secondary) => self
                .i2c
                .oar2()
                .write(|w| w.add2().set(secondary).endual().dual()),
            None => self.i2c.oar2().write(|w| w.endual().single()),
        };
    }
}

/// An [`I2cTarget`] behind an RTIC lock, locked only for each call: pass
/// `&mut LockedTarget(cx.shared.bridge)` to the handlers, and the bridge is
/// locked around `i2c_write` / `i2c_read` alone, not around register access.
pub struct LockedTarget<M>(pub M);

impl<M> I2cTarget for LockedTarget<M>
where
    M: Mutex,
    M::T: I2cTarget,
{
    fn i2c_write(&mut self, write: Write<'_>) {
        self.0.lock(|target| target.i2c_write(write));
    }

    fn i2c_read(&mut self, which: Which, out: &mut [u8; RESPONSE_MAX]) -> usize {
        self.0.lock(|target| target.i2c_read(which, out))
    }
}
