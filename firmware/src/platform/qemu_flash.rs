//! The settings store's flash under QEMU (`platform::qemu`): the store's two
//! erase units in RAM ([`SimFlash`], NOR semantics, alignment and bounds
//! checks), loaded at boot from a host file and written through on every
//! program and erase by semihosting, so settings saved under QEMU survive a
//! restart.
//!
//! * The file is named by the `flash=PATH` semihosting argument
//!   (`cargo xtask qemu-run` passes `target/qemu-flash.bin`, or `QEMU_FLASH`);
//!   a missing file is created erased, a short one reads erased past its
//!   end. Without the argument the flash lives in RAM only: every boot is
//!   factory-fresh.
//! * The file holds [`FLASH_SIZE`] bytes: erase unit k at offset
//!   k · [`FLASH_SECTOR`]. A write-through that fails leaves the RAM copy
//!   new and the operation reports [`SettingsFlashError::HostFile`], so the
//!   store's save fails rather than claiming a write the next boot will not
//!   see.

use core::ffi::CStr;

use bridge_logic::persist::sim::{SimFlash, SimFlashError};
use bridge_logic::persist::MAX_RECORD;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use semihosting::fs::File;
use semihosting::io::{Read as _, Seek as _, SeekFrom, Write as _};
use stm32f4xx_hal::pac;

/// Erase unit of the QEMU settings flash: the smallest power of two that
/// holds the store's largest record (the store needs one record per erase
/// unit; the board's are 128 KiB).
pub const FLASH_SECTOR: usize = MAX_RECORD.next_power_of_two();
/// Erase units (the store uses two).
pub const FLASH_SECTORS: usize = 2;
/// Bytes of the host file.
pub const FLASH_SIZE: usize = FLASH_SECTOR * FLASH_SECTORS;
/// Longest host path taken from the `flash=PATH` argument.
const PATH_MAX: usize = 255;

/// Why a settings-flash operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SettingsFlashError {
    /// Alignment, bounds (as on the board).
    Flash(SimFlashError),
    /// The host file could not be written: the RAM copy has the new content,
    /// the file may not.
    HostFile,
}

impl NorFlashError for SettingsFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SettingsFlashError::Flash(e) => e.kind(),
            SettingsFlashError::HostFile => NorFlashErrorKind::Other,
        }
    }
}

/// The settings store's flash under QEMU: NOR semantics in RAM
/// ([`SimFlash`]), every program and erase written through to the host
/// file (module docs).
pub struct SettingsFlash {
    ram: SimFlash<FLASH_SECTOR, FLASH_SECTORS>,
    /// `None`: RAM only.
    file: Option<File>,
    /// Kept untouched, for [`SettingsFlash::free`].
    flash: pac::FLASH,
}

impl SettingsFlash {
    /// The FLASH peripheral back (the host file is closed).
    pub fn free(self) -> pac::FLASH {
        self.flash
    }

    /// Copy `ram[offset..offset + len]` into the host file.
    fn write_through(&mut self, offset: u32, len: usize) -> Result<(), SettingsFlashError> {
        let Some(file) = self.file.as_mut() else {
            return Ok(());
        };
        let start = offset as usize;
        let mut chunk = [0u8; FLASH_SECTOR];
        let mut done = 0;
        while done < len {
            let n = len.saturating_sub(done).min(FLASH_SECTOR);
            let at = start.saturating_add(done);
            let buf = chunk.get_mut(..n).ok_or(SettingsFlashError::HostFile)?;
            self.ram
                .read(at as u32, buf)
                .map_err(SettingsFlashError::Flash)?;
            file.seek(SeekFrom::Start(at as u64))
                .and_then(|_| file.write_all(buf))
                .map_err(|_| SettingsFlashError::HostFile)?;
            done = done.saturating_add(n);
        }
        Ok(())
    }
}

impl ErrorType for SettingsFlash {
    type Error = SettingsFlashError;
}

impl ReadNorFlash for SettingsFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.ram
            .read(offset, bytes)
            .map_err(SettingsFlashError::Flash)
    }

    fn capacity(&self) -> usize {
        FLASH_SIZE
    }
}

impl NorFlash for SettingsFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = FLASH_SECTOR;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.ram
            .erase(from, to)
            .map_err(SettingsFlashError::Flash)?;
        self.write_through(from, to.saturating_sub(from) as usize)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.ram
            .write(offset, bytes)
            .map_err(SettingsFlashError::Flash)?;
        self.write_through(offset, bytes.len())
    }
}

/// The settings flash, loaded from the host file named by the `flash=PATH`
/// semihosting argument (created erased if missing). The FLASH peripheral
/// stays untouched (QEMU does not model its controller).
pub fn settings_flash(flash: pac::FLASH) -> SettingsFlash {
    let mut flash = SettingsFlash {
        ram: SimFlash::new(),
        file: None,
        flash,
    };
    let mut path = [0u8; PATH_MAX + 1];
    let Some(path) = flash_path(&mut path) else {
        defmt::warn!(
            "settings flash: RAM only (no flash=PATH argument): factory-fresh at every boot"
        );
        return flash;
    };
    let name = path.to_str().unwrap_or("?");
    match File::options().read(true).write(true).open(path) {
        Ok(mut file) => {
            let mut got: usize = 0;
            for sector in flash.ram.sectors_mut() {
                got = got.saturating_add(read_up_to(&mut file, sector));
            }
            defmt::info!(
                "settings flash: host file {=str} ({=usize} of {=usize} bytes read)",
                name,
                got,
                FLASH_SIZE
            );
            flash.file = Some(file);
        }
        Err(_) => match File::options()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)
        {
            Ok(file) => {
                flash.file = Some(file);
                // Size the new file: all of it erased.
                if flash.write_through(0, FLASH_SIZE).is_err() {
                    defmt::warn!("settings flash: cannot write {=str}", name);
                }
                defmt::info!("settings flash: new host file {=str} (factory-fresh)", name);
            }
            Err(_) => {
                defmt::warn!(
                    "settings flash: cannot open or create {=str}: RAM only",
                    name
                )
            }
        },
    }
    flash
}

/// Read as much of `file` as fits in `buf` (short at the end of the file:
/// the rest keeps its erased state). Returns the bytes read.
fn read_up_to(file: &mut File, buf: &mut [u8]) -> usize {
    let mut got = 0;
    while let Some(rest) = buf.get_mut(got..).filter(|r| !r.is_empty()) {
        match file.read(rest) {
            Ok(0) | Err(_) => break,
            Ok(n) => got = got.saturating_add(n),
        }
    }
    got
}

/// The `flash=PATH` semihosting argument, NUL-terminated in `buf`.
fn flash_path(buf: &mut [u8; PATH_MAX + 1]) -> Option<&CStr> {
    flash_path_with(buf, b"")
}

/// The `flash=PATH` semihosting argument followed by `suffix`,
/// NUL-terminated in `buf`.
fn flash_path_with<'a>(buf: &'a mut [u8; PATH_MAX + 1], suffix: &[u8]) -> Option<&'a CStr> {
    let args = semihosting::experimental::env::args::<{ PATH_MAX + 64 }>().ok()?;
    let path = (&args)
        .filter_map(Result::ok)
        .find_map(|arg| arg.strip_prefix("flash="))?
        .as_bytes();
    let len = path.len().saturating_add(suffix.len());
    if path.is_empty() || path.contains(&0) || len > PATH_MAX {
        return None;
    }
    buf.get_mut(..path.len())?.copy_from_slice(path);
    buf.get_mut(path.len()..len)?.copy_from_slice(suffix);
    *buf.get_mut(len)? = 0;
    CStr::from_bytes_until_nul(buf).ok()
}

/// Longest boot file read, bytes.
const BOOT_FILE_MAX: usize = 512;

/// Each line of the host file `<flash PATH>.boot`, if there is one: the
/// test console's lines applied at boot (`platform::qemu`, module docs).
pub fn boot_lines(mut each: impl FnMut(&[u8])) {
    let mut path = [0u8; PATH_MAX + 1];
    let Some(path) = flash_path_with(&mut path, b".boot") else {
        return;
    };
    let Ok(mut file) = File::open(path) else {
        return;
    };
    let mut text = [0u8; BOOT_FILE_MAX];
    let n = read_up_to(&mut file, &mut text);
    defmt::info!(
        "sim: boot file {=str} ({=usize} bytes)",
        path.to_str().unwrap_or("?"),
        n
    );
    for line in text.get(..n).unwrap_or(&[]).split(|b| *b == b'\n') {
        each(line.strip_suffix(b"\r").unwrap_or(line));
    }
}
