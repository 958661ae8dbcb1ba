//! The independent watchdog (RM0090 §21) through an [`IwdgPort`] — on the
//! chip the firmware's PAC glue for `pac::IWDG` (`firmware::drivers::iwdg`),
//! on the host the RM0090 model `host_tests::rm0090::iwdg`.
//!
//! # The sequences
//!
//! * **Start** ([`Watchdog::start`], §21.3): KR = 0xCCCC (the IWDG and the
//!   LSI start; from here on nothing stops it), KR = 0x5555 (PR and RLR
//!   writable), PR, RLR, then a bounded wait for SR.PVU and SR.RVU to clear
//!   (each update crosses into the LSI domain and takes up to 5 LSI cycles;
//!   PR/RLR may only be written while their flag is clear, and the reload
//!   below would load the old RLR before RVU clears), then KR = 0xAAAA
//!   (reload with the new RLR; any key but 0x5555 also write-protects PR
//!   and RLR again, §21.3.2).
//! * **Feed** ([`Watchdog::feed`]): KR = 0xAAAA. One register write; it
//!   never waits.
//!
//! The timeout is (RLR + 1) · 4 · 2^PR / f_LSI. [`prescaler_and_reload`]
//! picks the smallest prescaler whose 12-bit reload reaches the requested
//! time at the nominal 32 kHz (finest resolution); the LSI of the STM32F405
//! runs anywhere from 17 to 47 kHz (datasheet), so the real timeout is 0.68
//! to 1.88 times the nominal one.

use crate::Regs;

/// The IWDG's registers (RM0090 §21.4; offsets in [`IwdgReg::offset`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum IwdgReg {
    Kr,
    Pr,
    Rlr,
    Sr,
}

impl IwdgReg {
    pub const fn offset(self) -> usize {
        match self {
            IwdgReg::Kr => 0x00,
            IwdgReg::Pr => 0x04,
            IwdgReg::Rlr => 0x08,
            IwdgReg::Sr => 0x0C,
        }
    }
}

/// Keys and bits (RM0090 §21.4.1–§21.4.4).
pub mod bits {
    /// KR: PR and RLR writable.
    pub const KEY_ACCESS: u32 = 0x5555;
    /// KR: reload the counter with RLR (the feed).
    pub const KEY_RELOAD: u32 = 0xAAAA;
    /// KR: start the watchdog.
    pub const KEY_START: u32 = 0xCCCC;
    pub const SR_PVU: u32 = 1 << 0;
    pub const SR_RVU: u32 = 1 << 1;
    pub const PR_MAX: u32 = 0b110;
    pub const RLR_MAX: u32 = 0xFFF;
}

use bits::*;

/// The IWDG registers (nothing else).
pub trait IwdgPort: Regs<IwdgReg> {}

impl<T: Regs<IwdgReg>> IwdgPort for T {}

/// The LSI frequency the timeout is computed for (RM0090 §21.3; the
/// datasheet's typical 32 kHz).
pub const LSI_NOMINAL_HZ: u32 = 32_000;
/// SR polls before the start gives up waiting for PVU/RVU (5 LSI cycles at
/// 17 kHz are 294 µs; a poll takes a few APB1 cycles).
pub const UPDATE_POLLS_MAX: u32 = 1 << 20;

/// PR and RLR for `timeout_ms` at `lsi_hz`: the smallest prescaler (finest
/// step) whose reload fits in 12 bits; the longest timeout if none does.
pub fn prescaler_and_reload(timeout_ms: u32, lsi_hz: u32) -> (u32, u32) {
    let cycles = u64::from(timeout_ms) * u64::from(lsi_hz) / 1000;
    for pr in 0..=PR_MAX {
        let divider = 4u64 << pr;
        let reload = (cycles / divider).saturating_sub(1);
        if reload <= u64::from(RLR_MAX) {
            return (pr, reload as u32);
        }
    }
    (PR_MAX, RLR_MAX)
}

/// The timeout of `pr`, `rlr` at `lsi_hz`, in µs.
pub fn timeout_us(pr: u32, rlr: u32, lsi_hz: u32) -> u64 {
    (u64::from(rlr) + 1) * (4u64 << pr.min(PR_MAX)) * 1_000_000 / u64::from(lsi_hz.max(1))
}

/// The running independent watchdog.
#[derive(Debug)]
pub struct Watchdog<P> {
    port: P,
    /// PVU/RVU were clear before the first reload (false: the first period
    /// may still run on the reset values, 512 ms nominal).
    updated: bool,
}

impl<P: IwdgPort> Watchdog<P> {
    /// Start the watchdog with a nominal timeout of `timeout_ms` (module
    /// docs). It cannot be stopped again.
    pub fn start(port: P, timeout_ms: u32) -> Watchdog<P> {
        let (pr, rlr) = prescaler_and_reload(timeout_ms, LSI_NOMINAL_HZ);
        let mut w = Watchdog {
            port,
            updated: false,
        };
        w.port.write(IwdgReg::Kr, KEY_START);
        w.port.write(IwdgReg::Kr, KEY_ACCESS);
        w.port.write(IwdgReg::Pr, pr);
        w.port.write(IwdgReg::Rlr, rlr);
        for _ in 0..UPDATE_POLLS_MAX {
            if w.port.read(IwdgReg::Sr) & (SR_PVU | SR_RVU) == 0 {
                w.updated = true;
                break;
            }
        }
        w.port.write(IwdgReg::Kr, KEY_RELOAD);
        w
    }

    /// Reload the counter (every control tick).
    pub fn feed(&mut self) {
        self.port.write(IwdgReg::Kr, KEY_RELOAD);
    }

    /// Whether PR and RLR were in effect before the first reload.
    pub fn updated(&self) -> bool {
        self.updated
    }

    pub fn port(&self) -> &P {
        &self.port
    }

    pub fn port_mut(&mut self) -> &mut P {
        &mut self.port
    }
}
