//! The settings store's flash: sectors 10 and 11 of the STM32F405
//! (0x080C_0000 and 0x080E_0000, 128 KiB each), kept free of firmware by
//! `memory.x` (FLASH is 768K, so the image ends before sector 10).
//!
//! [`StoreFlash`] is the [`NorFlash`] that
//! [`bridge_logic::persist::Store`] runs on ([`SettingsStore`]): store
//! offsets `0..128K` are sector 10, `128K..256K` sector 11; `ERASE_SIZE` is
//! one sector, `WRITE_SIZE` 4, `READ_SIZE` 1. Every guarantee (old or new
//! after a power cut, CRCs, wear levelling) lives in the logic crate; this
//! module only moves bytes.
//!
//! * **Reads** are plain memory-mapped reads (the one `unsafe` block here).
//!   The HAL's `ReadNorFlash` is not used: it sizes the flash from the
//!   signature area at 0x1FFF_7A22, next to the unique ID that HardFaults
//!   under QEMU, and panics on a range outside the flash.
//! * **Programs and erases** use the HAL's `UnlockedFlash` (x8 parallelism,
//!   valid over the whole supply range; the flash is locked again when each
//!   call returns). Programming one 1 KiB record takes about 17 ms, erasing
//!   a 128 KiB sector 2 s typical, 4 s worst case (datasheet, x8). The CPU
//!   stalls on every flash fetch meanwhile, interrupts included — hence the
//!   store erases only when a save has to move to the other sector, and
//!   saves only on the explicit command.
//! * Before each operation the sticky error flags of FLASH_SR are cleared:
//!   the HAL reads them but never clears them, so a single error would
//!   fail every later operation until reset.
//! * After each operation the flash data cache (ART, 8 × 128 bit, not
//!   coherent with programming) is reset, so reading back returns the new
//!   content and not a cached copy of the old one.
//! * Where programs and erases do nothing (QEMU does not model the flash
//!   controller, so the QEMU platform uses a host-file stand-in instead),
//!   the store's read-back check turns a save into `StoreError::Flash`.

use bridge_logic::persist::Store;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use stm32f4xx_hal::flash::{self as hal_flash, FlashExt};
use stm32f4xx_hal::pac::FLASH;

/// Memory-mapped start of the on-chip flash.
const FLASH_BASE: usize = 0x0800_0000;
/// Offset of the store's first sector (sector 10) from [`FLASH_BASE`].
const STORE_OFFSET: usize = 0x000C_0000;
/// RM0090 sector numbers of the store's sectors 0 and 1.
const SECTOR_NUMBERS: [u8; 2] = [10, 11];
/// Size of sectors 5..=11.
pub const SECTOR_SIZE: usize = 128 * 1024;
/// Bytes of flash the store owns (up to the end of the 1 MiB flash).
pub const STORE_SIZE: usize = SECTOR_NUMBERS.len() * SECTOR_SIZE;
/// Worst-case erase of one 128 KiB sector at x8 parallelism (STM32F405
/// datasheet): a settings save that erases stalls the CPU, control tick and
/// watchdog feed included, this long.
pub const ERASE_MAX_MS: u32 = 4_000;

const _: () = assert!(STORE_OFFSET + STORE_SIZE == 1024 * 1024);
const _: () = assert!(SECTOR_SIZE >= bridge_logic::persist::MAX_RECORD);

/// The settings store as the firmware uses it.
pub type SettingsStore = Store<StoreFlash>;

/// Why a flash operation failed.
#[derive(Clone, Copy, Debug)]
pub enum StoreFlashError {
    /// Offset or length not a multiple of the read/write/erase unit.
    NotAligned,
    /// Outside the store's two sectors.
    OutOfBounds,
    /// The flash controller flagged an error (FLASH_SR).
    Controller(hal_flash::Error),
}

impl NorFlashError for StoreFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            StoreFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            StoreFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            StoreFlashError::Controller(e) => e.kind(),
        }
    }
}

/// Sectors 10 and 11 as one 256 KiB NOR flash.
pub struct StoreFlash {
    flash: FLASH,
}

impl StoreFlash {
    pub fn new(flash: FLASH) -> Self {
        StoreFlash { flash }
    }

    pub fn free(self) -> FLASH {
        self.flash
    }

    /// Start of `len` bytes at store offset `offset`, if inside the store
    /// and aligned to `unit`.
    fn check(offset: u32, len: usize, unit: usize) -> Result<usize, StoreFlashError> {
        let start = usize::try_from(offset).map_err(|_| StoreFlashError::OutOfBounds)?;
        let end = start.checked_add(len).ok_or(StoreFlashError::OutOfBounds)?;
        if end > STORE_SIZE {
            return Err(StoreFlashError::OutOfBounds);
        }
        if start % unit != 0 || len % unit != 0 {
            return Err(StoreFlashError::NotAligned);
        }
        Ok(start)
    }

    /// Clears the sticky error flags (write 1 to clear).
    fn clear_errors(&mut self) {
        self.flash.sr().write(|w| {
            w.operr().clear();
            w.wrperr().clear();
            w.pgaerr().clear();
            w.pgperr().clear();
            w.pgserr().clear()
        });
    }

    /// Drops whatever the data cache holds (it may be reset only while
    /// disabled).
    fn reset_data_cache(&mut self) {
        if self.flash.acr().read().dcen().bit_is_set() {
            self.flash.acr().modify(|_, w| w.dcen().clear_bit());
            self.flash.acr().modify(|_, w| w.dcrst().set_bit());
            self.flash.acr().modify(|_, w| w.dcrst().clear_bit());
            self.flash.acr().modify(|_, w| w.dcen().set_bit());
        }
    }
}

impl ErrorType for StoreFlash {
    type Error = StoreFlashError;
}

impl ReadNorFlash for StoreFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let start = Self::check(offset, bytes.len(), Self::READ_SIZE)?;
        copy_from_store(start, bytes)
    }

    fn capacity(&self) -> usize {
        STORE_SIZE
    }
}

impl NorFlash for StoreFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = SECTOR_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let len = to.checked_sub(from).ok_or(StoreFlashError::OutOfBounds)? as usize;
        let start = Self::check(from, len, Self::ERASE_SIZE)?;
        let first = start / SECTOR_SIZE;
        let sectors = SECTOR_NUMBERS
            .get(first..first + len / SECTOR_SIZE)
            .ok_or(StoreFlashError::OutOfBounds)?;
        for &number in sectors {
            self.clear_errors();
            let result = self.flash.unlocked().erase(number);
            self.reset_data_cache();
            result.map_err(StoreFlashError::Controller)?;
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let start = Self::check(offset, bytes.len(), Self::WRITE_SIZE)?;
        self.clear_errors();
        let result = self
            .flash
            .unlocked()
            .program(STORE_OFFSET + start, bytes.iter());
        self.reset_data_cache();
        result.map_err(StoreFlashError::Controller)
    }
}

/// Copies the store's bytes at `start..start + dst.len()` into `dst`.
#[allow(unsafe_code)]
fn copy_from_store(start: usize, dst: &mut [u8]) -> Result<(), StoreFlashError> {
    if start
        .checked_add(dst.len())
        .is_none_or(|end| end > STORE_SIZE)
    {
        return Err(StoreFlashError::OutOfBounds);
    }
    let src = (FLASH_BASE + STORE_OFFSET + start) as *const u8;
    // SAFETY: `src..src + dst.len()` lies in 0x080C_0000..0x0810_0000 (checked
    // above), on-chip flash that is always mapped and readable on the
    // STM32F405RG (1 MiB) and holds no Rust object (memory.x ends the
    // firmware at 0x080C_0000), so it cannot overlap `dst`. No reference to
    // it is formed, and no program or erase runs meanwhile: those happen
    // only inside `&mut StoreFlash` methods that wait for BSY to clear.
    unsafe { core::ptr::copy_nonoverlapping(src, dst.as_mut_ptr(), dst.len()) };
    Ok(())
}
