//! The settings store's flash: sectors 10 and 11 of the STM32F405
//! (0x080C_0000 and 0x080E_0000, 128 KiB each), programmed and erased
//! through the flash interface registers (RM0090 §3) of a [`FlashPort`] —
//! on the chip the firmware's PAC glue for `pac::FLASH`
//! (`firmware::drivers::flash`), on the host the RM0090 model
//! `host_tests::rm0090::flash`.
//!
//! [`StoreFlash`] is the [`NorFlash`] that `settings_store::Store`
//! runs on: store offsets `0..128K` are sector 10, `128K..256K` sector 11;
//! `ERASE_SIZE` is one sector, `WRITE_SIZE` 4, `READ_SIZE` 1. Every
//! guarantee of the store (old or new after a power cut, CRCs, wear
//! levelling) lives in the logic crate; this module only moves bytes.
//!
//! # The sequences (RM0090 §3.5)
//!
//! Every program and erase:
//!
//! 1. clears the sticky error flags of FLASH_SR (write 1 to each, §3.8.4:
//!    they are rc_w1 and stay set otherwise, so one old error would fail
//!    every later operation);
//! 2. waits until FLASH_SR.BSY is clear (§3.5.3, §3.5.4 step 1);
//! 3. unlocks FLASH_CR if FLASH_CR.LOCK is set: KEY1 = 0x4567_0123, then
//!    KEY2 = 0xCDEF_89AB into FLASH_KEYR (§3.5.1), and checks LOCK cleared.
//!    It never writes the keys to an unlocked FLASH_CR (a wrong sequence
//!    locks it until the next reset);
//! 4. **erase**: FLASH_CR = PSIZE x8 | SER | SNB, then the same with STRT
//!    (§3.5.3), waits for BSY to clear; **program**: FLASH_CR = PSIZE x8 |
//!    PG, then for each byte one byte write to its flash address and a wait
//!    for BSY (§3.5.4). x8 parallelism is valid over the whole supply range
//!    (1.8–3.6 V, §3.5.2), so a byte write is the access size PSIZE asks
//!    for (a mismatch is PGPERR);
//! 5. reads FLASH_SR: any of OPERR, WRPERR, PGAERR, PGPERR, PGSERR fails
//!    the operation ([`ControllerError`]); a program stops at the first
//!    failed byte;
//! 6. locks FLASH_CR again (LOCK, which also clears SER/PG/SNB/STRT), also
//!    after an error;
//! 7. resets the flash data cache if it is on (FLASH_ACR: DCEN off, DCRST
//!    on, DCRST off, DCEN on; DCRST is writable only with DCEN off, §3.8.1)
//!    — the cache is not coherent with programming, so reading back would
//!    return the old content (UNCONFIRMED on silicon; cheap either way).
//!
//! Costs (datasheet, x8): programming one 1 KiB record ≈ 17 ms, erasing a
//! 128 KiB sector 2 s typical, 4 s worst ([`ERASE_MAX_MS`]). The CPU stalls
//! on every flash fetch meanwhile, interrupts included — hence the store
//! erases only when a save moves to the other sector, and saves only on the
//! explicit command. A BSY wait gives up after [`BUSY_POLLS_MAX`] polls
//! (`ControllerError::Timeout`) instead of spinning for ever.
//!
//! Where programs and erases do nothing (QEMU does not model the flash
//! controller, so the QEMU platform uses a host-file stand-in instead),
//! the store's read-back check turns a save into `StoreError::Flash`.

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

use crate::Regs;

/// The flash interface registers (RM0090 §3.8; offsets in
/// [`FlashReg::offset`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FlashReg {
    Acr,
    Keyr,
    Optkeyr,
    Sr,
    Cr,
    Optcr,
}

impl FlashReg {
    /// Offset from FLASH_R_BASE (0x4002_3C00).
    pub const fn offset(self) -> usize {
        match self {
            FlashReg::Acr => 0x00,
            FlashReg::Keyr => 0x04,
            FlashReg::Optkeyr => 0x08,
            FlashReg::Sr => 0x0C,
            FlashReg::Cr => 0x10,
            FlashReg::Optcr => 0x14,
        }
    }
}

/// Register bits and keys (RM0090 §3.8.1–§3.8.5).
pub mod bits {
    pub const KEY1: u32 = 0x4567_0123;
    pub const KEY2: u32 = 0xCDEF_89AB;
    // ACR
    pub const ACR_DCEN: u32 = 1 << 10;
    pub const ACR_DCRST: u32 = 1 << 12;
    // SR
    pub const SR_EOP: u32 = 1 << 0;
    pub const SR_OPERR: u32 = 1 << 1;
    pub const SR_WRPERR: u32 = 1 << 4;
    pub const SR_PGAERR: u32 = 1 << 5;
    pub const SR_PGPERR: u32 = 1 << 6;
    pub const SR_PGSERR: u32 = 1 << 7;
    pub const SR_BSY: u32 = 1 << 16;
    /// The error flags (rc_w1).
    pub const SR_ERRORS: u32 = SR_OPERR | SR_WRPERR | SR_PGAERR | SR_PGPERR | SR_PGSERR;
    // CR
    pub const CR_PG: u32 = 1 << 0;
    pub const CR_SER: u32 = 1 << 1;
    pub const CR_MER: u32 = 1 << 2;
    pub const CR_SNB_SHIFT: u32 = 3;
    pub const CR_SNB_MASK: u32 = 0xF << CR_SNB_SHIFT;
    pub const CR_PSIZE_SHIFT: u32 = 8;
    pub const CR_PSIZE_MASK: u32 = 0b11 << CR_PSIZE_SHIFT;
    /// PSIZE = 00: x8 (byte) parallelism.
    pub const CR_PSIZE_X8: u32 = 0b00 << CR_PSIZE_SHIFT;
    pub const CR_STRT: u32 = 1 << 16;
    pub const CR_EOPIE: u32 = 1 << 24;
    pub const CR_ERRIE: u32 = 1 << 25;
    pub const CR_LOCK: u32 = 1 << 31;
}

use bits::*;

/// The flash array besides the registers: memory-mapped reads, and the
/// byte writes that program it.
pub trait FlashPort: Regs<FlashReg> {
    /// Copy the flash bytes at `address..address + dst.len()` (absolute
    /// addresses, inside the store: the driver checks) into `dst`.
    fn read_array(&mut self, address: u32, dst: &mut [u8]);
    /// One byte write to the flash address `address` (inside the store).
    fn write_array_u8(&mut self, address: u32, byte: u8);
}

/// Memory-mapped start of the on-chip flash.
pub const FLASH_BASE: u32 = 0x0800_0000;
/// Address of the store's first sector (sector 10).
pub const STORE_BASE: u32 = FLASH_BASE + 0x000C_0000;
/// RM0090 sector numbers of the store's sectors 0 and 1.
pub const SECTOR_NUMBERS: [u8; 2] = [10, 11];
/// Size of sectors 5..=11.
pub const SECTOR_SIZE: usize = 128 * 1024;
/// Bytes of flash the store owns (up to the end of the 1 MiB flash).
pub const STORE_SIZE: usize = SECTOR_NUMBERS.len() * SECTOR_SIZE;
/// Worst-case erase of one 128 KiB sector at x8 parallelism (STM32F405
/// datasheet): a settings save that erases stalls the CPU, control tick and
/// watchdog feed included, this long.
pub const ERASE_MAX_MS: u32 = 4_000;
/// Worst-case programming of one byte at x8 parallelism (STM32F405
/// datasheet, t_prog: 16 µs typical, 100 µs maximum); the CPU stalls this
/// long per byte.
pub const PROGRAM_BYTE_MAX_US: u32 = 100;
/// BSY polls before a wait gives up. While the flash is busy the CPU stalls
/// on every fetch from it, so each poll takes at least one flash access;
/// 2³⁰ polls outlast a 4 s erase by far at any clock.
pub const BUSY_POLLS_MAX: u32 = 1 << 30;

const _: () = assert!(STORE_BASE as usize - FLASH_BASE as usize + STORE_SIZE == 1024 * 1024);
const _: () = assert!(SECTOR_SIZE >= settings_store::MAX_RECORD);

/// What FLASH_SR reported, or what the driver saw go wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ControllerError {
    /// OPERR: the operation failed (read-while-write, ECC; §3.8.4).
    Operation,
    /// WRPERR: the address is write-protected.
    WriteProtection,
    /// PGAERR: the data does not fit one 128-bit row.
    Alignment,
    /// PGPERR: the access size is not PSIZE's.
    Parallelism,
    /// PGSERR: a flash write while FLASH_CR was not set up for it.
    Sequence,
    /// FLASH_CR stayed locked after the key sequence.
    Locked,
    /// BSY did not clear within [`BUSY_POLLS_MAX`] polls.
    Timeout,
}

impl ControllerError {
    /// The first error flag set in FLASH_SR, if any.
    pub fn from_sr(sr: u32) -> Option<ControllerError> {
        if sr & SR_WRPERR != 0 {
            Some(ControllerError::WriteProtection)
        } else if sr & SR_PGSERR != 0 {
            Some(ControllerError::Sequence)
        } else if sr & SR_PGPERR != 0 {
            Some(ControllerError::Parallelism)
        } else if sr & SR_PGAERR != 0 {
            Some(ControllerError::Alignment)
        } else if sr & SR_OPERR != 0 {
            Some(ControllerError::Operation)
        } else {
            None
        }
    }
}

/// Why a flash operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreFlashError {
    /// Offset or length not a multiple of the read/write/erase unit.
    NotAligned,
    /// Outside the store's two sectors.
    OutOfBounds,
    /// The flash controller flagged an error (FLASH_SR) or stayed locked.
    Controller(ControllerError),
}

impl NorFlashError for StoreFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            StoreFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            StoreFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            StoreFlashError::Controller(_) => NorFlashErrorKind::Other,
        }
    }
}

/// Sectors 10 and 11 as one 256 KiB NOR flash.
#[derive(Clone, Debug)]
pub struct StoreFlash<P> {
    port: P,
}

impl<P: FlashPort> StoreFlash<P> {
    pub fn new(port: P) -> Self {
        StoreFlash { port }
    }

    pub fn free(self) -> P {
        self.port
    }

    /// The port (on the host: the flash model).
    pub fn port(&self) -> &P {
        &self.port
    }

    pub fn port_mut(&mut self) -> &mut P {
        &mut self.port
    }

    /// Start of `len` bytes at store offset `offset`, if inside the store
    /// and aligned to `unit`.
    fn check(offset: u32, len: usize, unit: usize) -> Result<usize, StoreFlashError> {
        let start = usize::try_from(offset).map_err(|_| StoreFlashError::OutOfBounds)?;
        let end = start.checked_add(len).ok_or(StoreFlashError::OutOfBounds)?;
        if end > STORE_SIZE {
            return Err(StoreFlashError::OutOfBounds);
        }
        let aligned = |v: usize| v.checked_rem(unit) == Some(0);
        if !aligned(start) || !aligned(len) {
            return Err(StoreFlashError::NotAligned);
        }
        Ok(start)
    }

    /// The bus address of store offset `start` (< [`STORE_SIZE`], 256 KiB,
    /// after [`Self::check`]: the sum stays far below 4 GiB).
    fn address(start: usize) -> u32 {
        STORE_BASE.saturating_add(u32::try_from(start).unwrap_or(u32::MAX))
    }

    /// Step 2: wait for BSY to clear.
    fn wait_idle(&mut self) -> Result<(), ControllerError> {
        for _ in 0..BUSY_POLLS_MAX {
            if self.port.read(FlashReg::Sr) & SR_BSY == 0 {
                return Ok(());
            }
        }
        Err(ControllerError::Timeout)
    }

    /// Steps 1–3: errors cleared, idle, FLASH_CR unlocked.
    fn begin(&mut self) -> Result<(), ControllerError> {
        self.port.write(FlashReg::Sr, SR_ERRORS);
        self.wait_idle()?;
        if self.port.read(FlashReg::Cr) & CR_LOCK != 0 {
            self.port.write(FlashReg::Keyr, KEY1);
            self.port.write(FlashReg::Keyr, KEY2);
            if self.port.read(FlashReg::Cr) & CR_LOCK != 0 {
                return Err(ControllerError::Locked);
            }
        }
        Ok(())
    }

    /// Step 5: the outcome FLASH_SR reports.
    fn outcome(&mut self) -> Result<(), ControllerError> {
        match ControllerError::from_sr(self.port.read(FlashReg::Sr)) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Steps 6–7: lock, then drop what the data cache holds.
    fn end(&mut self) {
        self.port.write(FlashReg::Cr, CR_LOCK);
        if self.port.read(FlashReg::Acr) & ACR_DCEN != 0 {
            self.port.modify(FlashReg::Acr, |acr| acr & !ACR_DCEN);
            self.port.modify(FlashReg::Acr, |acr| acr | ACR_DCRST);
            self.port.modify(FlashReg::Acr, |acr| acr & !ACR_DCRST);
            self.port.modify(FlashReg::Acr, |acr| acr | ACR_DCEN);
        }
    }

    /// Erase one sector (RM0090 number `number`).
    fn erase_sector(&mut self, number: u8) -> Result<(), ControllerError> {
        let result = self.begin().and_then(|()| {
            let cr = CR_PSIZE_X8 | CR_SER | ((u32::from(number) << CR_SNB_SHIFT) & CR_SNB_MASK);
            self.port.write(FlashReg::Cr, cr);
            self.port.write(FlashReg::Cr, cr | CR_STRT);
            self.wait_idle()?;
            self.outcome()
        });
        self.end();
        result
    }

    /// Program `bytes` at the absolute address `address`, byte by byte.
    fn program(&mut self, address: u32, bytes: &[u8]) -> Result<(), ControllerError> {
        let result = self.begin().and_then(|()| {
            self.port.write(FlashReg::Cr, CR_PSIZE_X8 | CR_PG);
            let mut at = address;
            for &byte in bytes {
                self.port.write_array_u8(at, byte);
                self.wait_idle()?;
                self.outcome()?;
                at = at.wrapping_add(1);
            }
            Ok(())
        });
        self.end();
        result
    }
}

impl<P: FlashPort> ErrorType for StoreFlash<P> {
    type Error = StoreFlashError;
}

impl<P: FlashPort> ReadNorFlash for StoreFlash<P> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let start = Self::check(offset, bytes.len(), Self::READ_SIZE)?;
        let address = Self::address(start);
        self.port.read_array(address, bytes);
        Ok(())
    }

    fn capacity(&self) -> usize {
        STORE_SIZE
    }
}

impl<P: FlashPort> NorFlash for StoreFlash<P> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = SECTOR_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let len = to.checked_sub(from).ok_or(StoreFlashError::OutOfBounds)? as usize;
        let start = Self::check(from, len, Self::ERASE_SIZE)?;
        let first = start / SECTOR_SIZE;
        let sectors = SECTOR_NUMBERS
            .get(first..first.saturating_add(len / SECTOR_SIZE))
            .ok_or(StoreFlashError::OutOfBounds)?;
        for &number in sectors {
            self.erase_sector(number)
                .map_err(StoreFlashError::Controller)?;
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let start = Self::check(offset, bytes.len(), Self::WRITE_SIZE)?;
        self.program(Self::address(start), bytes)
            .map_err(StoreFlashError::Controller)
    }
}
