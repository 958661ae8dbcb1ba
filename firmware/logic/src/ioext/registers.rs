//! The extension's register page: 16-bit registers at 0x0200..=0x02FF, the
//! same addresses on every bus (Modbus holding registers with high byte
//! 0x02; I2C and USB carry the address and the words).
//!
//! | address | regs | access | register |
//! |---|---|---|---|
//! | 0x0200–0x0201 | 2 | RW | I/O options (u32, high word first): bit 0 enables the extension; other bits read 0 |
//! | 0x0202–0x0203 | 2 | RW | configuration (u32, high word first), Copley's bits; bit 11 status is read-only |
//! | 0x0204–0x0205 | 2 | R | transfers completed (u32, wrapping) |
//! | 0x0206 | 1 | R | auto-restarts skipped because a transfer was still running (saturating) |
//! | 0x0207 | 1 | R | writes whose undocumented bits were dropped (saturating) |
//! | 0x0208–0x0209 | 2 | R | real clock period of the configuration, ps (u32, rounded up) |
//! | 0x020A | 1 | R | engine: 1 SPI2, 2 TIM1 bit engine |
//! | 0x020B | 1 | R | transfers failed (saturating) |
//! | 0x0210–0x021F | 16 | RW | transmit data, words 0..15 |
//! | 0x0220–0x022F | ⌈n/16⌉ | R | receive data, words 0..⌈n/16⌉−1 |
//! | 0x0230 | 1 | RW | debounce K, 1..=255 transfers |
//! | 0x0240–0x027F | 8 per axis | RW | mapping of axis k at 0x0240 + 8k: BIN1, BIN2, end switch, run/stop, moving, fault, idle, reserved (reads 0, writes must be 0) |
//!
//! Rules, checked in this order for the whole request (so Modbus can answer
//! 02, then 03, then 04), and a request that fails changes nothing:
//!
//! 1. [`IoError::IllegalAddress`]: an address outside the table or the
//!    page, a write to a read-only register, a range that splits a 32-bit
//!    register, receive words past the configured bit count.
//! 2. [`IoError::IllegalValue`]: an empty range, a mapping entry with
//!    reserved bits, debounce 0 or above 255, a non-zero reserved mapping
//!    register.
//! 3. [`IoError::Unsupported`] (SLI mode), [`IoError::Busy`],
//!    [`IoError::Disabled`] (see [`IoError`]).
//!
//! Undocumented bits of the two Copley registers are not errors: they are
//! dropped and counted (0x0207). A read that includes a receive word clears
//! the status bit. A write to the transmit data replaces exactly the words
//! it covers (words past the configured count are stored and not sent) and
//! starts a transfer at the next control tick.

use super::config::{options, Config};
use super::extension::IoExtension;
use super::mapping::{input_from_register, output_from_register, Input, Output};
use super::IoError;

/// Register addresses.
pub mod addr {
    pub const FIRST: u16 = 0x0200;
    pub const LAST: u16 = 0x02FF;
    pub const IO_OPTIONS: u16 = 0x0200;
    pub const CONFIG: u16 = 0x0202;
    pub const TRANSFERS: u16 = 0x0204;
    pub const SKIPPED: u16 = 0x0206;
    pub const RESERVED_IGNORED: u16 = 0x0207;
    pub const PERIOD_PS: u16 = 0x0208;
    pub const ENGINE: u16 = 0x020A;
    pub const FAILURES: u16 = 0x020B;
    pub const TX: u16 = 0x0210;
    pub const RX: u16 = 0x0220;
    pub const DEBOUNCE: u16 = 0x0230;
    pub const MAP: u16 = 0x0240;
    /// Registers per axis in the mapping block.
    pub const MAP_STRIDE: u16 = 8;
    /// Offset of each entry in an axis's block.
    pub const BIN1: u16 = 0;
    pub const BIN2: u16 = 1;
    pub const END_SWITCH: u16 = 2;
    pub const RUN: u16 = 3;
    pub const MOVING: u16 = 4;
    pub const FAULT: u16 = 5;
    pub const IDLE: u16 = 6;

    /// Address of `entry` of `axis`'s mapping.
    pub const fn map(axis: u8, entry: u16) -> u16 {
        // At most 0x0240 + 7·8 + 7: never wraps.
        MAP.wrapping_add((axis as u16 % 8).wrapping_mul(MAP_STRIDE))
            .wrapping_add(entry % MAP_STRIDE)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Half {
    Hi,
    Lo,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Reg {
    Options(Half),
    Config(Half),
    Transfers(Half),
    Skipped,
    ReservedIgnored,
    Period(Half),
    Engine,
    Failures,
    Tx(usize),
    Rx(usize),
    Debounce,
    /// (axis, entry 0..8)
    Map(usize, usize),
}

impl Reg {
    fn at(a: u16) -> Option<Reg> {
        let off = |base: u16| usize::from(a.wrapping_sub(base));
        Some(match a {
            0x0200 => Reg::Options(Half::Hi),
            0x0201 => Reg::Options(Half::Lo),
            0x0202 => Reg::Config(Half::Hi),
            0x0203 => Reg::Config(Half::Lo),
            0x0204 => Reg::Transfers(Half::Hi),
            0x0205 => Reg::Transfers(Half::Lo),
            0x0206 => Reg::Skipped,
            0x0207 => Reg::ReservedIgnored,
            0x0208 => Reg::Period(Half::Hi),
            0x0209 => Reg::Period(Half::Lo),
            0x020A => Reg::Engine,
            0x020B => Reg::Failures,
            0x0210..=0x021F => Reg::Tx(off(addr::TX)),
            0x0220..=0x022F => Reg::Rx(off(addr::RX)),
            0x0230 => Reg::Debounce,
            0x0240..=0x027F => Reg::Map(off(addr::MAP) / 8, off(addr::MAP) % 8),
            _ => return None,
        })
    }

    fn half(self) -> Option<Half> {
        match self {
            Reg::Options(h) | Reg::Config(h) | Reg::Transfers(h) | Reg::Period(h) => Some(h),
            _ => None,
        }
    }

    fn writable(self) -> bool {
        matches!(
            self,
            Reg::Options(_) | Reg::Config(_) | Reg::Tx(_) | Reg::Debounce | Reg::Map(..)
        )
    }
}

fn hi(v: u32) -> u16 {
    (v >> 16) as u16
}

fn lo(v: u32) -> u16 {
    (v & 0xFFFF) as u16
}

fn sat16(v: u32) -> u16 {
    u16::try_from(v).unwrap_or(u16::MAX)
}

impl IoExtension {
    /// The registers of `addr..addr + len` (rule 1 of the module doc).
    fn registers(
        &self,
        addr: u16,
        len: usize,
        write: bool,
    ) -> Result<impl Iterator<Item = Reg>, IoError> {
        if len == 0 {
            return Err(IoError::IllegalValue);
        }
        let last = u16::try_from(len.saturating_sub(1))
            .ok()
            .and_then(|l| addr.checked_add(l))
            .ok_or(IoError::IllegalAddress)?;
        if addr < addr::FIRST || last > addr::LAST {
            return Err(IoError::IllegalAddress);
        }
        let words = self.config.words();
        for a in addr..=last {
            let r = Reg::at(a).ok_or(IoError::IllegalAddress)?;
            if write && !r.writable() {
                return Err(IoError::IllegalAddress);
            }
            if let Reg::Rx(i) = r {
                if i >= words {
                    return Err(IoError::IllegalAddress);
                }
            }
            // A 32-bit register is accessed whole: no range starts on its
            // low word or ends on its high word.
            if (a == addr && r.half() == Some(Half::Lo))
                || (a == last && r.half() == Some(Half::Hi))
            {
                return Err(IoError::IllegalAddress);
            }
        }
        Ok((addr..=last).filter_map(Reg::at))
    }

    /// Read `out.len()` registers from `addr`. A read that includes a
    /// receive word clears the status bit.
    pub fn read(&mut self, addr: u16, out: &mut [u16]) -> Result<(), IoError> {
        let regs = self.registers(addr, out.len(), false)?;
        let options = u32::from(self.enabled) & options::ENABLE;
        let config = self.config.register(self.status);
        let plan = self.clock_plan();
        let period = u32::try_from(plan.period.picos_ceil()).unwrap_or(u32::MAX);
        let d = self.diag;
        let mut rx_read = false;
        for (r, o) in regs.zip(out.iter_mut()) {
            let pick = |v: u32, h: Half| if h == Half::Hi { hi(v) } else { lo(v) };
            *o = match r {
                Reg::Options(h) => pick(options, h),
                Reg::Config(h) => pick(config, h),
                Reg::Transfers(h) => pick(d.transfers, h),
                Reg::Skipped => sat16(d.skipped_restarts),
                Reg::ReservedIgnored => sat16(d.reserved_ignored),
                Reg::Period(h) => pick(period, h),
                Reg::Engine => plan.engine_code(),
                Reg::Failures => sat16(d.failures),
                Reg::Tx(i) => self.tx.words().get(i).copied().unwrap_or(0),
                Reg::Rx(i) => {
                    rx_read = true;
                    self.rx.words().get(i).copied().unwrap_or(0)
                }
                Reg::Debounce => u16::from(self.mapping.debounce),
                Reg::Map(axis, e) => self.map_register(axis, e),
            };
        }
        if rx_read {
            self.status = false;
        }
        Ok(())
    }

    fn map_register(&self, axis: usize, e: usize) -> u16 {
        let Some(m) = self.mapping.axes.get(axis) else {
            return 0;
        };
        match e {
            0..=3 => super::mapping::input_register(m.inputs.get(e).copied().flatten()),
            4..=6 => {
                super::mapping::output_register(m.outputs.get(e.wrapping_sub(4)).copied().flatten())
            }
            _ => 0,
        }
    }

    /// Write `data` to the registers from `addr`: all or nothing (see the
    /// module doc for the order of the checks).
    pub fn write(&mut self, addr: u16, data: &[u16]) -> Result<(), IoError> {
        let regs = self.registers(addr, data.len(), true)?;
        // Rule 2: values.
        for (r, &v) in regs.zip(data.iter()) {
            let ok = match r {
                Reg::Debounce => (1..=255).contains(&v),
                Reg::Map(_, 0..=3) => input_from_register(v).is_ok(),
                Reg::Map(_, 4..=6) => output_from_register(v).is_ok(),
                Reg::Map(..) => v == 0,
                _ => true,
            };
            if !ok {
                return Err(IoError::IllegalValue);
            }
        }
        // Rule 3, on a copy that replaces the state only if all is well.
        let mut next = *self;
        let mut tx_written = false;
        let mut high = 0u16;
        let regs = self.registers(addr, data.len(), true)?;
        for (r, &v) in regs.zip(data.iter()) {
            let joined = (u32::from(high) << 16) | u32::from(v);
            match r {
                Reg::Options(Half::Hi) | Reg::Config(Half::Hi) => high = v,
                Reg::Options(Half::Lo) => {
                    next.enabled = joined & options::ENABLE != 0;
                    if joined & !options::WRITABLE != 0 {
                        next.count_reserved();
                    }
                }
                Reg::Config(Half::Lo) => {
                    let (c, reserved) = Config::from_register(joined)?;
                    if reserved {
                        next.count_reserved();
                    }
                    let held = self.cs_low || self.in_flight.is_some_and(|f| f.cs_hold);
                    if held && c.mode().cpol != self.config.mode().cpol {
                        return Err(IoError::Busy);
                    }
                    next.config = c;
                }
                Reg::Tx(i) => {
                    if let Some(w) = next.tx.words_mut().get_mut(i) {
                        *w = v;
                    }
                    tx_written = true;
                }
                Reg::Debounce => next.mapping.debounce = u8::try_from(v).unwrap_or(u8::MAX),
                Reg::Map(axis, e) => next.set_map_entry(axis, e, v),
                // Not writable: excluded by `registers`.
                _ => return Err(IoError::IllegalAddress),
            }
        }
        if tx_written {
            if !next.enabled {
                return Err(IoError::Disabled);
            }
            if !next.config.auto_restart() && self.pending {
                return Err(IoError::Busy);
            }
            next.pending = true;
        }
        *self = next;
        Ok(())
    }

    fn count_reserved(&mut self) {
        self.diag.reserved_ignored = self.diag.reserved_ignored.saturating_add(1);
    }

    fn set_map_entry(&mut self, axis: usize, e: usize, v: u16) {
        let Some(m) = self.mapping.axes.get_mut(axis) else {
            return;
        };
        if let Some(i) = Input::ALL.get(e).copied() {
            let new = input_from_register(v).ok().flatten();
            if m.input(i) != new {
                m.set_input(i, new);
                self.filter.reset_input(axis, i);
            }
        } else if let Some(o) = Output::ALL.get(e.wrapping_sub(4)).copied() {
            m.set_output(o, output_from_register(v).ok().flatten());
        }
    }
}
