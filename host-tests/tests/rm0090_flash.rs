//! The firmware's settings-flash driver (`drivers_core::flash`, the code the
//! board runs) against the RM0090 §3 flash model
//! (`host_tests::rm0090::flash`): one test per rule of the model's table
//! (F1–F10), then a settings save through driver and model with the
//! store's power-cut test on top (every flash operation of a save torn in
//! turn, the sector erase included).

use bridge_logic::persist::sim::SplitMix64;
use bridge_logic::persist::{Store, StoreError, MAX_IMAGE};
use bridge_logic::postep60::settings::{Settings, IMAGE_LEN};
use drivers_core::flash::bits::*;
use drivers_core::flash::{ControllerError, StoreFlash, StoreFlashError, SECTOR_SIZE};
use drivers_core::Regs;
use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
use host_tests::rm0090::flash::{FlashModel, ACR_AT_168MHZ};

type Flash = StoreFlash<FlashModel>;

fn flash() -> Flash {
    StoreFlash::new(FlashModel::new())
}

/// No violation, FLASH_CR locked, no error flag left, data cache on.
fn assert_clean(f: &Flash) {
    let m = f.port();
    assert_eq!(m.violations(), &[] as &[String]);
    assert_ne!(m.cr() & CR_LOCK, 0, "FLASH_CR locked after the operation");
    assert_eq!(m.acr(), ACR_AT_168MHZ, "FLASH_ACR as the boot left it");
}

fn read(f: &mut Flash, offset: u32, len: usize) -> Vec<u8> {
    let mut buf = vec![0; len];
    f.read(offset, &mut buf).unwrap();
    buf
}

// ------------------------------------------------------------ F1 keys --

#[test]
fn f1_each_operation_unlocks_with_key1_then_key2() {
    let mut f = flash();
    f.write(0, &[1, 2, 3, 4]).unwrap();
    f.erase(0, SECTOR_SIZE as u32).unwrap();
    assert_eq!(f.port().counters().unlocks, 2);
    assert_clean(&f);
}

#[test]
fn f1_an_unlocked_flash_cr_is_not_unlocked_again() {
    let mut f = flash();
    // Someone left it unlocked: writing the keys now would be a bus error.
    f.port_mut()
        .write(drivers_core::flash::FlashReg::Keyr, KEY1);
    f.port_mut()
        .write(drivers_core::flash::FlashReg::Keyr, KEY2);
    f.write(0, &[1, 2, 3, 4]).unwrap();
    assert_eq!(f.port().counters().unlocks, 1, "no second key sequence");
    assert_clean(&f);
}

// -------------------------------------------------------------- F2 lock --

#[test]
fn f2_flash_cr_is_locked_after_every_operation_and_never_written_locked() {
    let mut f = flash();
    f.write(8, &[0; 8]).unwrap();
    assert_ne!(f.port().cr() & CR_LOCK, 0);
    f.erase(SECTOR_SIZE as u32, 2 * SECTOR_SIZE as u32).unwrap();
    assert_ne!(f.port().cr() & CR_LOCK, 0);
    assert_eq!(f.port().counters().locked_writes, 0);
    assert_clean(&f);
}

// ------------------------------------------------------ F3, F4 program --

#[test]
fn f3_f4_a_program_writes_bytes_with_pg_and_psize_x8() {
    let mut f = flash();
    f.write(16, &[0xDE, 0xAD, 0xBE, 0xEF]).unwrap();
    assert_eq!(read(&mut f, 16, 4), [0xDE, 0xAD, 0xBE, 0xEF]);
    assert_eq!(f.port().sr() & (SR_PGSERR | SR_PGPERR | SR_PGAERR), 0);
    assert_eq!(f.port().counters().programs, 4);
    assert_clean(&f);
}

#[test]
fn f3_f4_pg_and_psize_are_set_before_the_first_data_write() {
    // A program of a whole record: every byte lands (PGSERR/PGPERR would
    // leave it erased).
    let mut f = flash();
    let data: Vec<u8> = (0..1048u32).map(|k| (k * 7) as u8 & 0x7F).collect();
    f.write(0, &data).unwrap();
    assert_eq!(read(&mut f, 0, data.len()), data);
    assert_clean(&f);
}

// ------------------------------------------------------------ F5 NOR --

#[test]
fn f5_programming_only_clears_bits() {
    let mut f = flash();
    f.write(0, &[0xF0, 0xFF, 0x0F, 0x00]).unwrap();
    f.write(0, &[0x3C, 0x00, 0xFF, 0xFF]).unwrap();
    assert_eq!(read(&mut f, 0, 4), [0x30, 0x00, 0x0F, 0x00]);
    assert_clean(&f);
}

// ----------------------------------------------------------- F6 erase --

#[test]
fn f6_erase_picks_the_sector_by_snb_and_leaves_only_it_erased() {
    let mut f = flash();
    f.write(0, &[0; 4]).unwrap();
    f.write(SECTOR_SIZE as u32, &[0; 4]).unwrap();
    f.erase(SECTOR_SIZE as u32, 2 * SECTOR_SIZE as u32).unwrap();
    assert_eq!(read(&mut f, 0, 4), [0; 4], "sector 10 untouched");
    assert_eq!(
        read(&mut f, SECTOR_SIZE as u32, 4),
        [0xFF; 4],
        "sector 11 erased"
    );
    assert_eq!(f.port().counters().erases, 1);
    assert_clean(&f);
}

#[test]
fn f6_erasing_both_sectors_erases_each_once() {
    let mut f = flash();
    f.write(0, &[0; 4]).unwrap();
    f.erase(0, 2 * SECTOR_SIZE as u32).unwrap();
    assert_eq!(f.port().counters().erases, 2);
    assert!(f.port().array().iter().all(|&b| b == 0xFF));
    assert_clean(&f);
}

// -------------------------------------------------------------- F7 BSY --

#[test]
fn f7_no_operation_starts_while_bsy() {
    let mut f = flash();
    for k in 0..8u32 {
        f.write(k * 4, &[k as u8; 4]).unwrap();
    }
    f.erase(0, SECTOR_SIZE as u32).unwrap();
    f.write(0, &[1; 4]).unwrap();
    assert_clean(&f); // "… while BSY" would be a violation
}

// ------------------------------------------------------ F8 error flags --

#[test]
fn f8_a_sticky_error_left_from_before_does_not_fail_the_next_operation() {
    let mut f = flash();
    f.port_mut().inject_sr(SR_PGSERR | SR_PGPERR); // as after some resets
    f.write(0, &[9; 4]).unwrap();
    assert_eq!(read(&mut f, 0, 4), [9; 4]);
    assert_clean(&f);
}

#[test]
fn f8_an_error_during_a_program_is_reported_and_the_flash_locked() {
    let mut f = flash();
    f.port_mut().fail_next_operation(SR_WRPERR);
    assert_eq!(
        f.write(0, &[1; 4]),
        Err(StoreFlashError::Controller(
            ControllerError::WriteProtection
        ))
    );
    assert_eq!(
        f.port().counters().programs,
        0,
        "stopped at the failed byte"
    );
    assert_clean(&f);
    f.write(4, &[2; 4]).unwrap();
}

#[test]
fn f8_an_error_during_an_erase_is_reported() {
    let mut f = flash();
    f.port_mut().fail_next_operation(SR_OPERR);
    assert_eq!(
        f.erase(0, SECTOR_SIZE as u32),
        Err(StoreFlashError::Controller(ControllerError::Operation))
    );
    assert_clean(&f);
}

// ------------------------------------------------------ F9 data cache --

#[test]
fn f9_reads_after_a_program_see_the_new_data_through_the_data_cache() {
    let mut f = flash();
    assert_eq!(read(&mut f, 0, 4), [0xFF; 4]); // now cached
    f.write(0, &[1, 2, 3, 4]).unwrap();
    assert_eq!(read(&mut f, 0, 4), [1, 2, 3, 4]);
    f.erase(0, SECTOR_SIZE as u32).unwrap();
    assert_eq!(read(&mut f, 0, 4), [0xFF; 4]);
    assert_clean(&f); // DCRST with DCEN = 1 would be a violation
}

// ------------------------------------------------ F10 store bounds --

#[test]
fn f10_misuse_is_refused_before_any_register_access() {
    let mut f = flash();
    assert_eq!(f.write(2, &[0; 4]), Err(StoreFlashError::NotAligned));
    assert_eq!(
        f.write(2 * SECTOR_SIZE as u32, &[0; 4]),
        Err(StoreFlashError::OutOfBounds)
    );
    assert_eq!(
        f.erase(0, 3 * SECTOR_SIZE as u32),
        Err(StoreFlashError::OutOfBounds)
    );
    assert_eq!(
        f.erase(4, SECTOR_SIZE as u32 + 4),
        Err(StoreFlashError::NotAligned)
    );
    assert_eq!(f.port().counters().unlocks, 0);
    assert_eq!(f.port().ops(), 0);
    assert_clean(&f);
}

// ----------------------------------------- the store on driver + model --

fn store() -> Store<Flash> {
    Store::new(flash())
}

fn load(s: &mut Store<Flash>) -> Result<Vec<u8>, StoreError> {
    let mut buf = vec![0; MAX_IMAGE];
    s.load(&mut buf).map(|n| buf[..n].to_vec())
}

/// The next boot after a power cut: power back, new driver, new store.
fn reboot(s: Store<Flash>) -> Store<Flash> {
    let mut model = s.into_inner().free();
    model.restore_power();
    Store::new(StoreFlash::new(model))
}

fn settings_image(speed: u8) -> Vec<u8> {
    let mut image = [0u8; IMAGE_LEN];
    Settings::FACTORY.to_image(&mut image);
    // A different image per save: one byte changed (the store does not
    // look inside).
    image[IMAGE_LEN - 1] ^= speed;
    image.to_vec()
}

#[test]
fn a_settings_save_through_the_driver_loads_back_after_a_reboot() {
    let mut s = store();
    assert_eq!(load(&mut s), Err(StoreError::Empty));
    let image = settings_image(0);
    s.save(&image).unwrap();
    let mut s = reboot(s);
    let loaded = load(&mut s).unwrap();
    assert_eq!(loaded, image);
    assert!(Settings::from_image(&loaded).is_ok());
    assert_eq!(s.flash().port().counters().overwrites, 0);
    assert_clean(s.flash());
}

/// Tears every operation of a save of `image` on a copy of `s` and checks
/// that the next boot loads exactly `old` (or nothing, if there was none)
/// or exactly `image`. `every`: cut every n-th operation (1: all), plus the
/// first and last. Returns the cut points tried.
fn cut_every_operation(
    s: &Store<Flash>,
    old: Option<&[u8]>,
    image: &[u8],
    every: u64,
    rng: &mut SplitMix64,
) -> u64 {
    let start = s.flash().port().ops();
    let mut probe = s.clone();
    probe.save(image).unwrap();
    let ops = probe.flash().port().ops() - start;
    let mut tried = 0;
    for k in (0..ops).filter(|k| k % every == 0 || *k + 1 == ops) {
        let mut cut = s.clone();
        cut.flash_mut()
            .port_mut()
            .cut_power_at(start + k, rng.next_u64());
        assert_eq!(
            cut.save(image),
            Err(StoreError::Flash),
            "cut at op {k} of {ops}"
        );
        let mut after = reboot(cut);
        let got = load(&mut after);
        match (&got, old) {
            (Ok(v), _) if v == image => {}
            (Ok(v), Some(o)) if v == o => {}
            (Err(StoreError::Empty | StoreError::Corrupt), None) => {}
            _ => panic!("cut at op {k} of {ops}: loaded {:?}", got.map(|v| v.len())),
        }
        // And the store goes on working (checked at every 16th cut point:
        // each check is two more scans of both sectors).
        if tried % 16 == 0 {
            after.save(image).unwrap();
            assert_eq!(load(&mut reboot(after)).unwrap(), image);
        }
        tried += 1;
    }
    tried
}

#[test]
fn a_power_cut_at_every_flash_operation_of_a_save_leaves_old_or_new_settings() {
    let mut rng = SplitMix64::new(15);
    let mut s = store();
    let mut last: Option<Vec<u8>> = None;
    let mut tried = 0;
    for save in 0..2u8 {
        let image = settings_image(save + 1);
        tried += cut_every_operation(&s, last.as_deref(), &image, 1, &mut rng);
        s.save(&image).unwrap();
        last = Some(image);
    }
    assert!(tried > 2 * 100, "{tried} cut points");
    assert_clean(s.flash());
}

#[test]
fn a_power_cut_during_the_sector_erase_of_a_save_leaves_the_old_settings() {
    let mut rng = SplitMix64::new(16);
    let mut s = store();
    let mut last = None;
    // Fill sector 10 until the next save has to erase sector 11.
    let mut save = 0u8;
    loop {
        let image = settings_image(save);
        let mut probe = s.clone();
        let erases = probe.flash().port().counters().erases;
        probe.save(&image).unwrap();
        // (The first save erases sector 10: nothing old to keep yet.)
        if probe.flash().port().counters().erases > erases && last.is_some() {
            // This save erases first (its operation 0), then writes.
            let tried = cut_every_operation(&s, last.as_deref(), &image, 97, &mut rng);
            assert!(tried >= 3);
            assert!(save > 100, "sector 10 was full after {save} saves");
            break;
        }
        s = probe;
        last = Some(image);
        save = save.wrapping_add(1);
    }
    assert_clean(s.flash());
}
