//! The settings store's flash (`platform::settings_flash`) on the target:
//! flash sectors 10 and 11 on the board (**erases them**: the board boots
//! with factory settings afterwards), the semihosting host file under QEMU
//! (`cargo qemu-test` gives it a fresh file). Erase and program read back,
//! misuse is refused, and the store's saves survive opening the flash anew
//! (what a reboot sees). Board and QEMU.
#![cfg_attr(target_os = "none", no_std, no_main)]
// An on-target test, not bus input: it may index, unwrap, panic and (like
// the drivers) touch registers in `unsafe` blocks.
#![allow(unsafe_code, clippy::indexing_slicing, clippy::arithmetic_side_effects)]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#[cfg(not(target_os = "none"))]
fn main() {}

#[cfg(target_os = "none")]
mod common;

#[cfg(target_os = "none")]
mod support {
    use embedded_storage::nor_flash::{NorFlash, NorFlashError, ReadNorFlash};
    use firmware::platform::SettingsFlash;

    pub const SECTOR: u32 = SettingsFlash::ERASE_SIZE as u32;

    pub struct State {
        pub flash: Option<SettingsFlash>,
    }

    impl State {
        pub fn flash(&mut self) -> &mut SettingsFlash {
            match self.flash.as_mut() {
                Some(flash) => flash,
                None => defmt::panic!("flash handed out"),
            }
        }
    }

    /// Which refusal, as text (`NorFlashErrorKind` has no defmt::Format).
    pub fn refusal<E: NorFlashError>(r: Result<(), E>) -> &'static str {
        use embedded_storage::nor_flash::NorFlashErrorKind as Kind;
        match r.err().map(|e| e.kind()) {
            None => "accepted",
            Some(Kind::NotAligned) => "not aligned",
            Some(Kind::OutOfBounds) => "out of bounds",
            Some(_) => "other",
        }
    }

    /// Every byte of the store's two erase units is 0xFF.
    pub fn all_erased(flash: &mut SettingsFlash) -> bool {
        let mut buf = [0u8; 256];
        let mut offset = 0u32;
        while offset < 2 * SECTOR {
            if flash.read(offset, &mut buf).is_err() || buf.iter().any(|&b| b != 0xFF) {
                return false;
            }
            offset += buf.len() as u32;
        }
        true
    }
}

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use bridge_logic::persist::{Store, MAX_IMAGE};
    use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
    use firmware::platform::{self, SettingsFlash};

    use super::common;
    use super::support::{all_erased, refusal, State, SECTOR};

    #[init]
    fn init() -> State {
        let t = common::setup();
        State {
            flash: Some(platform::settings_flash(t.flash)),
        }
    }

    #[test]
    fn erase_leaves_both_sectors_erased(s: &mut State) {
        let flash = s.flash();
        defmt::assert!(flash.capacity() >= 2 * SettingsFlash::ERASE_SIZE);
        defmt::assert!(flash.erase(0, 2 * SECTOR).is_ok());
        defmt::assert!(all_erased(flash));
    }

    #[test]
    fn programmed_words_read_back_in_both_sectors(s: &mut State) {
        let flash = s.flash();
        let data: [u8; 16] = core::array::from_fn(|i| 0x10 + i as u8);
        for at in [0, 64, SECTOR, SECTOR + 32] {
            defmt::assert!(flash.write(at, &data).is_ok());
            let mut back = [0u8; 16];
            defmt::assert!(flash.read(at, &mut back).is_ok());
            defmt::assert_eq!(back, data);
        }
        // The words next to them stay erased.
        let mut after = [0u8; 4];
        defmt::assert!(flash.read(16, &mut after).is_ok());
        defmt::assert_eq!(after, [0xFF; 4]);
        defmt::assert!(flash.erase(0, 2 * SECTOR).is_ok());
        defmt::assert!(all_erased(flash));
    }

    #[test]
    fn misaligned_and_out_of_range_operations_are_refused(s: &mut State) {
        let flash = s.flash();
        let end = flash.capacity() as u32;
        let aligned = "not aligned";
        let bounds = "out of bounds";
        defmt::assert_eq!(refusal(flash.write(1, &[0; 4])), aligned);
        defmt::assert_eq!(refusal(flash.write(0, &[0; 3])), aligned);
        defmt::assert_eq!(refusal(flash.erase(0, 1)), aligned);
        defmt::assert_eq!(refusal(flash.write(end, &[0; 4])), bounds);
        defmt::assert_eq!(refusal(flash.read(end - 1, &mut [0; 2])), bounds);
        defmt::assert_eq!(refusal(flash.erase(0, end + SECTOR)), bounds);
        // Nothing was written.
        defmt::assert!(all_erased(flash));
    }

    #[test]
    fn saved_settings_survive_opening_the_flash_anew(s: &mut State) {
        let Some(flash) = s.flash.take() else {
            defmt::panic!("flash handed out");
        };
        let mut store = Store::new(flash);
        let first: [u8; 40] = core::array::from_fn(|i| i as u8);
        let second: [u8; 300] = core::array::from_fn(|i| (i * 7) as u8);
        let mut out = [0u8; MAX_IMAGE];
        defmt::assert!(store.save(&first).is_ok());
        defmt::assert_eq!(store.load(&mut out).ok(), Some(first.len()));
        defmt::assert_eq!(&out[..first.len()], &first[..]);
        defmt::assert!(store.save(&second).is_ok());

        // What a reboot sees: the flash opened again from its peripheral
        // (the board's memory-mapped sectors, QEMU's host file).
        let flash = platform::settings_flash(store.into_inner().free());
        let mut store = Store::new(flash);
        out.fill(0);
        defmt::assert_eq!(store.load(&mut out).ok(), Some(second.len()));
        defmt::assert_eq!(&out[..second.len()], &second[..]);
        s.flash = Some(store.into_inner());
    }
}
