//! The settings store's flash (sectors 10 and 11): the PAC glue under
//! [`drivers_core::flash`], where the unlock / erase / program / lock
//! sequences live (and are tested on the host against the RM0090 flash
//! model, `host_tests::rm0090::flash`, with the store's power-cut test on
//! top). This module maps the driver's register ids to `pac::FLASH`'s
//! registers and gives it the array: memory-mapped reads and byte writes.
//! `memory.x` keeps sectors 10 and 11 free of firmware (FLASH and RAMTEXT_LOAD end at 768K).

// The array accesses are raw pointer accesses, and the PAC's raw register
// writer is unsafe; each block says why it is sound.
#![allow(unsafe_code)]

use bridge_logic::persist::Store;
use drivers_core::flash::{FlashPort, FlashReg, STORE_BASE, STORE_SIZE};
use drivers_core::Regs;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use stm32f4xx_hal::pac::FLASH;

pub use drivers_core::flash::{ControllerError, StoreFlashError, ERASE_MAX_MS, SECTOR_SIZE};

/// Sectors 10 and 11 as one 256 KiB NOR flash: `drivers_core::flash`'s
/// driver on `pac::FLASH`.
pub struct StoreFlash(drivers_core::flash::StoreFlash<FlashPeripheral>);

/// The settings store as the firmware uses it.
pub type SettingsStore = Store<StoreFlash>;

impl StoreFlash {
    /// The store's flash on `flash` (the FLASH interface registers).
    pub fn new(flash: FLASH) -> StoreFlash {
        StoreFlash(drivers_core::flash::StoreFlash::new(FlashPeripheral {
            flash,
        }))
    }

    pub fn free(self) -> FLASH {
        self.0.free().flash
    }
}

impl ErrorType for StoreFlash {
    type Error = StoreFlashError;
}

impl ReadNorFlash for StoreFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl NorFlash for StoreFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = SECTOR_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0.erase(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.write(offset, bytes)
    }
}

/// `pac::FLASH` and the store's part of the array, as the driver's
/// [`FlashPort`].
pub struct FlashPeripheral {
    flash: FLASH,
}

/// Whether `address..address + len` lies inside the store's sectors.
fn in_store(address: u32, len: usize) -> bool {
    let Some(off) = address.checked_sub(STORE_BASE) else {
        return false;
    };
    (off as usize)
        .checked_add(len)
        .is_some_and(|end| end <= STORE_SIZE)
}

impl Regs<FlashReg> for FlashPeripheral {
    #[inline]
    fn read(&mut self, reg: FlashReg) -> u32 {
        let f = &self.flash;
        match reg {
            FlashReg::Acr => f.acr().read().bits(),
            FlashReg::Keyr => 0,
            FlashReg::Optkeyr => 0,
            FlashReg::Sr => f.sr().read().bits(),
            FlashReg::Cr => f.cr().read().bits(),
            FlashReg::Optcr => f.optcr().read().bits(),
        }
    }

    #[inline]
    fn write(&mut self, reg: FlashReg, value: u32) {
        let f = &self.flash;
        // SAFETY: one volatile write of the whole register. The values come
        // from `drivers_core::flash` (the RM0090 key sequence, PSIZE x8 with
        // SER/SNB 10..=11 or PG, LOCK, rc_w1 error flags, ACR cache bits),
        // checked against the RM0090 model on the host. The option-byte
        // registers are never written (the model flags it).
        unsafe {
            match reg {
                FlashReg::Acr => f.acr().write(|w| w.bits(value)),
                FlashReg::Keyr => f.keyr().write(|w| w.bits(value)),
                FlashReg::Sr => f.sr().write(|w| w.bits(value)),
                FlashReg::Cr => f.cr().write(|w| w.bits(value)),
                FlashReg::Optkeyr | FlashReg::Optcr => 0,
            };
        }
    }
}

impl FlashPort for FlashPeripheral {
    fn read_array(&mut self, address: u32, dst: &mut [u8]) {
        if !in_store(address, dst.len()) {
            dst.fill(0xFF);
            return;
        }
        let src = address as usize as *const u8;
        // SAFETY: `src..src + dst.len()` lies in 0x080C_0000..0x0810_0000
        // (checked above), on-chip flash that is always mapped and readable
        // on the STM32F405RG (1 MiB) and holds no Rust object (memory.x ends
        // the firmware at 0x080C_0000), so it cannot overlap `dst`. No
        // reference to it is formed; a program or erase in progress only
        // stalls the read until it ends.
        unsafe { core::ptr::copy_nonoverlapping(src, dst.as_mut_ptr(), dst.len()) };
    }

    fn write_array_u8(&mut self, address: u32, byte: u8) {
        if !in_store(address, 1) {
            return;
        }
        // SAFETY: a volatile byte write to the store's flash (checked
        // above), which the driver has set up for programming (PG, PSIZE
        // x8): the flash interface turns it into a program operation. No
        // Rust object lives there (memory.x).
        unsafe { core::ptr::write_volatile(address as usize as *mut u8, byte) };
    }
}
