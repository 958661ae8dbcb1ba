//! I2C1 as the PoStep60 I2C slave: the PAC glue under
//! [`drivers_core::i2c_slave`], where the register sequences live (and are
//! tested on the host against the RM0090 I2C model, `host_tests::rm0090`).
//!
//! This module only enables and resets I2C1 through the RCC, maps the
//! driver's register ids to `pac::I2C1`'s registers (one volatile access
//! each) and reads the bus lines' GPIO levels. The module docs of
//! `drivers_core::i2c_slave` state what the driver guarantees and assumes.

// The only unsafe block is the PAC's raw register writer (`W::bits`), which
// the PAC marks unsafe because a raw value is not checked against the SVD.
#![allow(unsafe_code)]

use bridge_logic::transport::i2c::{I2cSlave, I2cTarget, Which, Write, RESPONSE_MAX};
use drivers_core::i2c_slave::{self as core_i2c, I2cPort, I2cReg};
use drivers_core::Regs;
use rtic::Mutex;
use stm32f4xx_hal::rcc::{Enable, Rcc, Reset};

use crate::pins::{HostI2c, HostI2cScl, HostI2cSda};

/// I2C1's registers and its two pins, as the driver's [`I2cPort`].
pub struct I2c1Port {
    i2c: HostI2c,
    scl: HostI2cScl,
    sda: HostI2cSda,
}

impl Regs<I2cReg> for I2c1Port {
    #[inline]
    fn read(&mut self, reg: I2cReg) -> u32 {
        let i2c = &self.i2c;
        u32::from(match reg {
            I2cReg::Cr1 => i2c.cr1().read().bits(),
            I2cReg::Cr2 => i2c.cr2().read().bits(),
            I2cReg::Oar1 => i2c.oar1().read().bits(),
            I2cReg::Oar2 => i2c.oar2().read().bits(),
            I2cReg::Dr => i2c.dr().read().bits(),
            I2cReg::Sr1 => i2c.sr1().read().bits(),
            I2cReg::Sr2 => i2c.sr2().read().bits(),
            I2cReg::Ccr => i2c.ccr().read().bits(),
            I2cReg::Trise => i2c.trise().read().bits(),
        })
    }

    #[inline]
    fn write(&mut self, reg: I2cReg, value: u32) {
        let i2c = &self.i2c;
        // The I2C registers are 16 bits wide (RM0090 §27.6).
        let v = value as u16;
        // SAFETY: one volatile write of the whole register, nothing else.
        // Every value comes from `drivers_core::i2c_slave`, which composes
        // it from the RM0090 bit layout (FREQ clamped to 2..=42, OAR1 bit
        // 14 at 1, rc_w0 flags written 1 unless cleared on purpose) and is
        // checked against the RM0090 model on the host. SR2 is read-only
        // (no writer in the PAC): a write to it does nothing, as on the chip.
        unsafe {
            match reg {
                I2cReg::Cr1 => i2c.cr1().write(|w| w.bits(v)),
                I2cReg::Cr2 => i2c.cr2().write(|w| w.bits(v)),
                I2cReg::Oar1 => i2c.oar1().write(|w| w.bits(v)),
                I2cReg::Oar2 => i2c.oar2().write(|w| w.bits(v)),
                I2cReg::Dr => i2c.dr().write(|w| w.bits(v)),
                I2cReg::Sr1 => i2c.sr1().write(|w| w.bits(v)),
                I2cReg::Ccr => i2c.ccr().write(|w| w.bits(v)),
                I2cReg::Trise => i2c.trise().write(|w| w.bits(v)),
                I2cReg::Sr2 => 0,
            };
        }
    }
}

impl I2cPort for I2c1Port {
    #[inline]
    fn lines_high(&mut self) -> bool {
        self.scl.is_high() && self.sda.is_high()
    }
}

/// The I2C1 peripheral as a PoStep60 I2C slave (`drivers_core::i2c_slave`).
pub struct I2cSlaveDriver(core_i2c::I2cSlaveDriver<I2c1Port>);

impl I2cSlaveDriver {
    /// Enable and reset I2C1 through the RCC and start it as a slave at
    /// `primary` (OAR1) and, if given, `secondary` (OAR2), CR2.FREQ from the
    /// APB1 clock. Interrupts are enabled in the peripheral; the NVIC side is
    /// RTIC's (the tasks bound to I2C1_EV / I2C1_ER).
    pub fn new(
        i2c: HostI2c,
        pins: (HostI2cScl, HostI2cSda),
        primary: u8,
        secondary: Option<u8>,
        rcc: &mut Rcc,
    ) -> I2cSlaveDriver {
        HostI2c::enable(rcc);
        HostI2c::reset(rcc);
        let freq = core_i2c::freq_mhz(rcc.clocks.pclk1().raw());
        let port = I2c1Port {
            i2c,
            scl: pins.0,
            sda: pins.1,
        };
        I2cSlaveDriver(core_i2c::I2cSlaveDriver::new(
            port, freq, primary, secondary,
        ))
    }

    /// The own addresses `(primary, secondary)` in use.
    pub fn addresses(&self) -> (u8, Option<u8>) {
        self.0.addresses()
    }

    /// Change the own addresses (see `drivers_core::i2c_slave`).
    pub fn set_addresses(&mut self, primary: u8, secondary: Option<u8>) {
        self.0.set_addresses(primary, secondary);
    }

    /// CR2.FREQ in use (the APB1 clock in MHz).
    pub fn freq_mhz(&self) -> u8 {
        self.0.freq_mhz()
    }

    /// Peripheral resets since boot (bus errors that left it stuck BUSY).
    pub fn resets(&self) -> u32 {
        self.0.resets()
    }

    /// I2C1_EV: address, data and STOP events.
    pub fn on_event(&mut self, slave: &mut I2cSlave, target: &mut impl I2cTarget) {
        self.0.on_event(slave, target);
    }

    /// I2C1_ER: the master's NACK ending a read, bus errors.
    pub fn on_error(&mut self, slave: &mut I2cSlave, target: &mut impl I2cTarget) {
        self.0.on_error(slave, target);
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
