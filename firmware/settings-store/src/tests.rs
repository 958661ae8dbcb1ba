//! The store's promises, checked: basics, integrity, where records go,
//! flash trouble, wear, power cuts at every flash operation, fuzz.

#![allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used
)]
#![allow(clippy::expect_used, clippy::panic)]

use embedded_storage::nor_flash::{ErrorType, ReadNorFlash};

use super::*;
use crate::sim::{SimFlash, SimFlashError, SplitMix64};

/// Small sectors (3 full records each) so that moves happen often.
const S: usize = 4096;
type Flash = SimFlash<S, 2>;

fn fresh() -> Store<Flash> {
    Store::new(Flash::new())
}

fn load<F: NorFlash>(store: &mut Store<F>) -> Result<Vec<u8>, StoreError> {
    let mut out = [0u8; MAX_IMAGE];
    let n = store.load(&mut out)?;
    Ok(out[..n].to_vec())
}

/// A fresh store mounted on `flash` (what a reboot does).
fn reboot<F: NorFlash>(store: Store<F>) -> Store<F> {
    Store::new(store.into_inner())
}

fn image(rng: &mut SplitMix64, len: usize) -> Vec<u8> {
    let mut v = vec![0; len];
    rng.fill(&mut v);
    v
}

fn random_image(rng: &mut SplitMix64) -> Vec<u8> {
    let len = rng.range(1, MAX_IMAGE);
    image(rng, len)
}

/// The bytes of a record as the store writes it.
fn raw_record(version: u16, seq: u32, payload: &[u8]) -> Vec<u8> {
    let header = Header {
        version,
        len: payload.len() as u16,
        seq,
    };
    let mut r = header.encode().to_vec();
    r.extend_from_slice(payload);
    r.resize(HEADER_LEN + padded(payload.len()), 0);
    let crc = CRC32.checksum(&r);
    r.extend_from_slice(&crc.to_le_bytes());
    r.extend_from_slice(&COMMIT);
    assert_eq!(r.len(), record_size(payload.len()));
    r
}

fn put<const N: usize>(flash: &mut SimFlash<N, 2>, sector: usize, offset: usize, bytes: &[u8]) {
    flash.sectors_mut()[sector][offset..offset + bytes.len()].copy_from_slice(bytes);
}

// ------------------------------------------------------------ basics

#[test]
fn save_then_load_returns_the_image() {
    let mut store = fresh();
    store.save(b"axis settings").unwrap();
    assert_eq!(load(&mut store).unwrap(), b"axis settings");
    assert_eq!(load(&mut reboot(store)).unwrap(), b"axis settings");
}

#[test]
fn empty_and_full_size_images_round_trip() {
    let mut rng = SplitMix64::new(1);
    for len in [0, 1, 2, 3, 4, 5, MAX_IMAGE - 1, MAX_IMAGE] {
        let img = image(&mut rng, len);
        let mut store = fresh();
        store.save(&img).unwrap();
        assert_eq!(load(&mut reboot(store)).unwrap(), img, "len {len}");
    }
}

#[test]
fn newest_save_wins_also_after_a_reboot() {
    let mut store = fresh();
    for v in [&b"one"[..], b"two", b"three"] {
        store.save(v).unwrap();
        assert_eq!(load(&mut store).unwrap(), v);
    }
    assert_eq!(load(&mut reboot(store)).unwrap(), b"three");
}

#[test]
fn erased_flash_loads_as_empty() {
    assert_eq!(load(&mut fresh()), Err(StoreError::Empty));
}

#[test]
fn random_garbage_loads_as_corrupt() {
    let mut flash = Flash::new();
    let mut rng = SplitMix64::new(2);
    for sector in flash.sectors_mut() {
        rng.fill(sector);
    }
    assert_eq!(load(&mut Store::new(flash)), Err(StoreError::Corrupt));
}

#[test]
fn zeroed_flash_loads_as_corrupt() {
    let mut flash = Flash::new();
    flash.sectors_mut()[1].fill(0);
    assert_eq!(load(&mut Store::new(flash)), Err(StoreError::Corrupt));
}

#[test]
fn one_stray_byte_makes_the_flash_corrupt_not_empty() {
    let mut flash = Flash::new();
    flash.sectors_mut()[1][S - 1] = 0xFE;
    assert_eq!(load(&mut Store::new(flash)), Err(StoreError::Corrupt));
}

#[test]
fn image_over_max_is_too_large_and_touches_nothing() {
    let mut store = fresh();
    assert_eq!(store.save(&[0; MAX_IMAGE + 1]), Err(StoreError::TooLarge));
    assert_eq!(store.flash().ops(), 0);
    assert_eq!(store.flash().counters().reads, 0);
}

#[test]
fn output_shorter_than_the_image_is_too_large() {
    let mut store = fresh();
    store.save(&[7; 100]).unwrap();
    let mut out = [0; 99];
    assert_eq!(store.load(&mut out), Err(StoreError::TooLarge));
    assert_eq!(out, [0; 99], "nothing copied");
    let mut out = [0; 100];
    assert_eq!(store.load(&mut out), Ok(100));
}

#[test]
fn new_and_load_never_program_or_erase() {
    let mut store = fresh();
    for i in 0..20u8 {
        store.save(&[i; 700]).unwrap();
    }
    let flash = store.into_inner();
    let ops = flash.ops();
    let mut store = Store::new(flash);
    assert_eq!(store.flash().counters().reads, flash_reads_before(&store));
    load(&mut store).unwrap();
    assert_eq!(store.flash().ops(), ops);

    fn flash_reads_before(s: &Store<Flash>) -> u64 {
        s.flash().counters().reads
    }
}

#[test]
fn save_without_load_scans_first_and_appends() {
    let mut store = fresh();
    store.save(b"first").unwrap();
    let mut store = reboot(store);
    store.save(b"second").unwrap();
    assert_eq!(store.stats().erases, 0, "appended, no erase");
    assert_eq!(load(&mut store).unwrap(), b"second");
}

// ---------------------------------------------------------- integrity

#[test]
fn record_with_bad_crc_is_skipped() {
    let mut store = fresh();
    for v in [&b"aaaa"[..], b"bbbb", b"cccc"] {
        store.save(v).unwrap();
    }
    let r = record_size(4);
    let mut flash = store.into_inner();
    // Newest record damaged: the one before it is the newest loadable.
    flash.sectors_mut()[0][2 * r + HEADER_LEN] ^= 0x01;
    assert_eq!(load(&mut Store::new(flash.clone())).unwrap(), b"bbbb");
    // A damaged record in the middle does not hide the newest.
    flash.sectors_mut()[0][2 * r + HEADER_LEN] ^= 0x01;
    flash.sectors_mut()[0][r + HEADER_LEN + 4] ^= 0x80; // its CRC
    assert_eq!(load(&mut Store::new(flash)).unwrap(), b"cccc");
}

#[test]
fn record_without_commit_word_is_skipped() {
    let mut flash = Flash::new();
    let a = raw_record(FORMAT_VERSION, 1, b"old");
    let mut b = raw_record(FORMAT_VERSION, 2, b"new");
    let n = b.len();
    b[n - 4..].fill(0xFF);
    put(&mut flash, 0, 0, &a);
    put(&mut flash, 0, a.len(), &b);
    assert_eq!(load(&mut Store::new(flash)).unwrap(), b"old");
}

#[test]
fn damaged_header_does_not_hide_later_records() {
    let mut store = fresh();
    for v in [&b"aaaa"[..], b"bbbb", b"cccc"] {
        store.save(v).unwrap();
    }
    let r = record_size(4);
    let mut flash = store.into_inner();
    flash.sectors_mut()[0][r + 6] ^= 0x04; // length field of "bbbb"
    assert_eq!(load(&mut Store::new(flash)).unwrap(), b"cccc");
}

#[test]
fn record_of_unknown_version_is_not_loaded() {
    let mut flash = Flash::new();
    let old = raw_record(FORMAT_VERSION, 1, b"v1 settings");
    let newer = raw_record(FORMAT_VERSION + 1, 2, b"v2 settings");
    put(&mut flash, 0, 0, &old);
    put(&mut flash, 0, old.len(), &newer);
    assert_eq!(load(&mut Store::new(flash)).unwrap(), b"v1 settings");
}

#[test]
fn only_unknown_versions_load_as_corrupt() {
    let mut flash = Flash::new();
    put(&mut flash, 1, 0, &raw_record(0, 5, b"v0"));
    put(&mut flash, 1, 64, &raw_record(2, 6, b"v2"));
    assert_eq!(load(&mut Store::new(flash)), Err(StoreError::Corrupt));
}

#[test]
fn save_after_unknown_version_is_newer_than_it() {
    let mut flash = Flash::new();
    put(
        &mut flash,
        1,
        0,
        &raw_record(FORMAT_VERSION + 1, 1000, b"v2"),
    );
    let mut store = Store::new(flash);
    store.save(b"v1 again").unwrap();
    let mount = store.mount.unwrap();
    assert_eq!(mount.next_seq, 1002, "saved with sequence 1001");
    assert_eq!(
        mount.head,
        Head::Active {
            sector: 1,
            free: Some(record_size(2) + record_size(8))
        },
        "appended after the v2 record, in its sector"
    );
    assert_eq!(load(&mut reboot(store)).unwrap(), b"v1 again");
}

#[test]
fn sequence_numbers_wrap_and_the_newest_still_wins() {
    let mut flash = Flash::new();
    put(
        &mut flash,
        0,
        0,
        &raw_record(FORMAT_VERSION, u32::MAX - 20, &[9; 1000]),
    );
    put(
        &mut flash,
        1,
        0,
        &raw_record(FORMAT_VERSION, u32::MAX - 2, &[0; 1000]),
    );
    let mut store = Store::new(flash);
    assert_eq!(load(&mut store).unwrap(), [0; 1000]);
    for i in 1..=12u8 {
        store.save(&[i; 1000]).unwrap();
        assert_eq!(load(&mut store).unwrap(), [i; 1000]);
        store = reboot(store);
    }
    // 3 appends after u32::MAX - 2, then moves at sequences 1, 5 and 9.
    assert_eq!(store.flash().sector_erases(), &[2, 1]);
}

// --------------------------------------------------- where records go

#[test]
fn records_are_appended_until_the_sector_is_full_then_the_other_sector_is_used() {
    let r = record_size(1000); // 1024: four per 4 KiB sector
    let mut store = fresh();
    store.save(&[1; 1000]).unwrap();
    assert_eq!(
        store.flash().sector_erases(),
        &[1, 0],
        "first save erases sector 0"
    );
    for i in 2..=4u8 {
        store.save(&[i; 1000]).unwrap();
    }
    assert_eq!(
        store.flash().sector_erases(),
        &[1, 0],
        "appends erase nothing"
    );
    assert_eq!(store.stats().used as usize, 4 * r);
    store.save(&[5; 1000]).unwrap();
    assert_eq!(store.flash().sector_erases(), &[1, 1], "moved to sector 1");
    assert_eq!(store.stats().sector, Some(1));
    for i in 6..=8u8 {
        store.save(&[i; 1000]).unwrap();
    }
    assert_eq!(
        store.flash().sector_erases(),
        &[1, 1],
        "sector 0 kept until needed"
    );
    store.save(&[9; 1000]).unwrap();
    assert_eq!(
        store.flash().sector_erases(),
        &[2, 1],
        "moved back to sector 0"
    );
    assert_eq!(load(&mut reboot(store)).unwrap(), [9; 1000]);
}

#[test]
fn garbage_after_the_last_record_closes_the_sector() {
    let mut store = fresh();
    store.save(b"kept").unwrap();
    let mut flash = store.into_inner();
    flash.sectors_mut()[0][S / 2] = 0x00;
    let mut store = Store::new(flash);
    assert_eq!(load(&mut store).unwrap(), b"kept");
    assert_eq!(store.stats().used as usize, S, "closed: counts as full");
    store.save(b"moved").unwrap();
    assert_eq!(store.flash().sector_erases(), &[1, 1]);
    assert_eq!(store.stats().sector, Some(1));
    assert_eq!(store.flash().counters().overwrites, 0);
    assert_eq!(load(&mut reboot(store)).unwrap(), b"moved");
}

#[test]
fn torn_record_with_intact_header_is_stepped_over() {
    let mut store = fresh();
    store.save(b"old").unwrap();
    let before = store.flash().ops();
    // Ops of the next save: header, payload words, tail+CRC, commit.
    store.flash_mut().cut_power_at(before + 1, 3);
    assert_eq!(store.save(&[5; 200]), Err(StoreError::Flash));
    let mut flash = store.into_inner();
    flash.restore_power();
    let mut store = Store::new(flash);
    assert_eq!(load(&mut store).unwrap(), b"old");
    assert_eq!(
        store.stats().used as usize,
        record_size(3) + record_size(200),
        "the next record goes after the torn one"
    );
    store.save(b"new").unwrap();
    assert_eq!(store.flash().sector_erases(), &[1, 0], "no move");
    assert_eq!(load(&mut reboot(store)).unwrap(), b"new");
}

#[test]
fn stats_report_saves_erases_sector_and_usage() {
    let mut store = fresh();
    assert_eq!(store.stats(), StoreStats::default());
    store.save(&[0; 10]).unwrap();
    store.save(&[0; 20]).unwrap();
    assert_eq!(
        store.stats(),
        StoreStats {
            saves: 2,
            erases: 1,
            sector: Some(0),
            used: (record_size(10) + record_size(20)) as u32,
        }
    );
}

#[test]
fn flash_mut_makes_the_store_scan_again() {
    let mut store = fresh();
    store.save(b"a").unwrap();
    store.flash_mut().sectors_mut()[0][40] = 0; // garbage after the record
    store.save(b"b").unwrap();
    assert_eq!(store.flash().counters().overwrites, 0);
    assert_eq!(store.stats().sector, Some(1), "saw the garbage and moved");
    assert_eq!(load(&mut store).unwrap(), b"b");
}

// ---------------------------------------------------- flash trouble

#[test]
fn flash_smaller_than_two_sectors_is_a_flash_error() {
    let mut store = Store::new(SimFlash::<S, 1>::new());
    assert_eq!(load(&mut store), Err(StoreError::Flash));
    assert_eq!(store.save(b"x"), Err(StoreError::Flash));
}

#[test]
fn flash_errors_are_reported_and_the_store_recovers() {
    let mut store = fresh();
    store.save(b"before").unwrap();
    let ops = store.flash().ops();
    store.flash_mut().cut_power_at(ops, 0);
    assert_eq!(store.save(b"during"), Err(StoreError::Flash));
    assert_eq!(
        load(&mut store),
        Err(StoreError::Flash),
        "reads fail unpowered"
    );
    assert_eq!(store.stats().sector, None);
    store.flash_mut().restore_power();
    let got = load(&mut store).unwrap();
    assert!(got == b"before" || got == b"during");
    store.save(b"after").unwrap();
    assert_eq!(load(&mut store).unwrap(), b"after");
}

/// A flash that accepts programs and erases but does nothing (like
/// QEMU's STM32F405, whose flash controller is not modelled).
#[derive(Debug)]
struct InertFlash(Flash);

impl ErrorType for InertFlash {
    type Error = SimFlashError;
}

impl ReadNorFlash for InertFlash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), SimFlashError> {
        self.0.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl NorFlash for InertFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = S;
    fn erase(&mut self, _: u32, _: u32) -> Result<(), SimFlashError> {
        Ok(())
    }
    fn write(&mut self, _: u32, _: &[u8]) -> Result<(), SimFlashError> {
        Ok(())
    }
}

#[test]
fn a_save_that_does_not_reach_the_flash_is_a_flash_error() {
    let mut store = Store::new(InertFlash(Flash::new()));
    assert_eq!(store.save(b"lost"), Err(StoreError::Flash));
    let mut garbage = Flash::new();
    garbage.sectors_mut()[0].fill(0x55);
    let mut store = Store::new(InertFlash(garbage));
    assert_eq!(
        store.save(b"lost"),
        Err(StoreError::Flash),
        "erase did not erase"
    );
}

// ---------------------------------------------------------- wear

#[test]
fn many_saves_wear_level_both_sectors() {
    let mut rng = SplitMix64::new(1000);
    let mut store = fresh();
    let mut bytes = 0;
    for i in 0..1000 {
        let img = random_image(&mut rng);
        bytes += record_size(img.len());
        store.save(&img).unwrap();
        assert_eq!(load(&mut store).unwrap(), img);
        if i % 50 == 0 {
            store = reboot(store);
        }
    }
    let [e0, e1] = *store.flash().sector_erases();
    let erases = (e0 + e1) as usize;
    // A move wastes less than one record at the end of a sector.
    let most = bytes.div_ceil(S - MAX_RECORD) + 1;
    let least = bytes / S;
    assert!(
        (least..=most).contains(&erases),
        "{erases} erases for {bytes} record bytes, expected {least}..={most}"
    );
    assert!(e0.abs_diff(e1) <= 1, "sectors alternate: {e0} / {e1}");
    assert_eq!(store.flash().counters().overwrites, 0);
}

#[test]
fn device_geometry_erases_once_per_84_full_saves() {
    // STM32F405 sectors 10 and 11: 128 KiB each; a full record is 1 560 bytes.
    let mut flash = Box::new(SimFlash::<{ 128 * 1024 }, 2>::new());
    let mut store = Store::new(&mut *flash);
    for i in 0..300u32 {
        store.save(&[i as u8; MAX_IMAGE]).unwrap();
    }
    // The module doc states both numbers.
    assert_eq!(MAX_RECORD, 1560);
    assert_eq!((128 * 1024) / MAX_RECORD, 84);
    assert_eq!(store.stats().erases, 4, "saves 1, 85, 169 and 253 erase");
    assert_eq!(load(&mut store).unwrap(), [43; MAX_IMAGE]);
}

// ------------------------------------------------------ power cuts

/// Whether the load after a cut gave the old or the new image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Outcome {
    Old,
    New,
}

#[derive(Debug, Default)]
struct Tally {
    cut_points: u64,
    old: u64,
    new: u64,
}

/// After a cut: power back, reboot, load. Asserts the image is exactly
/// `old` (or nothing when there was none) or exactly `new`, then that a
/// further save works and reads back, also after another reboot.
fn recover<const N: usize>(
    mut flash: SimFlash<N, 2>,
    old: Option<&[u8]>,
    new: &[u8],
    rng: &mut SplitMix64,
) -> (Outcome, Store<SimFlash<N, 2>>) {
    flash.restore_power();
    let mut store = Store::new(flash);
    let got = load(&mut store);
    let outcome = match (&got, old) {
        (Ok(v), _) if v == new => Outcome::New,
        (Ok(v), Some(o)) if v == o => Outcome::Old,
        (Err(StoreError::Empty | StoreError::Corrupt), None) => Outcome::Old,
        _ => panic!(
            "after a cut: {:?} (len {:?}); old len {:?}, new len {}",
            got.as_ref().map(|v| v.first()),
            got.as_ref().map(Vec::len),
            old.map(<[u8]>::len),
            new.len()
        ),
    };
    let mut check = store.clone();
    let next = random_image(rng);
    check.save(&next).unwrap();
    assert_eq!(load(&mut check).unwrap(), next);
    let mut check = reboot(check);
    assert_eq!(load(&mut check).unwrap(), next);
    assert_eq!(
        check.flash().counters().overwrites,
        0,
        "a word programmed twice"
    );
    (outcome, store)
}

/// Runs `saves` random saves (sizes 1..=MAX_IMAGE) and, for every flash
/// operation of every save, a branch where power is cut at exactly that
/// operation. The main line itself gets cut now and then, and reboots
/// now and then, so later cut points land on torn and dirty flash.
fn campaign<const N: usize>(seed: u64, saves: usize, tally: &mut Tally) {
    let mut rng = SplitMix64::new(seed);
    let mut store = Store::new(SimFlash::<N, 2>::new());
    let mut last: Option<Vec<u8>> = None;
    for _ in 0..saves {
        let img = random_image(&mut rng);
        // The in-memory state must be what a scan finds, so that a
        // branch (which scans again) does exactly what the main line does.
        if let Some(m) = store.mount {
            let mut scan = Store::new(store.flash().clone());
            assert_eq!(scan.scan_all().unwrap().0, m);
        }
        let start = store.flash().ops();
        let mut done = store.clone();
        done.save(&img).unwrap();
        let ops = done.flash().ops() - start;
        assert!((3..=5).contains(&ops), "{ops} operations in one save");
        for k in 0..ops {
            let mut cut = store.clone();
            cut.flash_mut().cut_power_at(start + k, rng.next_u64());
            assert_eq!(cut.save(&img), Err(StoreError::Flash));
            let (outcome, _) = recover(cut.into_inner(), last.as_deref(), &img, &mut rng);
            tally.cut_points += 1;
            match outcome {
                Outcome::Old => tally.old += 1,
                Outcome::New => tally.new += 1,
            }
        }
        if rng.below(6) == 0 {
            // The main line loses power too and carries the torn state on.
            let mut cut = store;
            let k = rng.below(ops as usize) as u64;
            cut.flash_mut().cut_power_at(start + k, rng.next_u64());
            assert_eq!(cut.save(&img), Err(StoreError::Flash));
            let (outcome, s) = recover(cut.into_inner(), last.as_deref(), &img, &mut rng);
            if outcome == Outcome::New {
                last = Some(img);
            }
            store = s;
        } else {
            store = done;
            last = Some(img);
        }
        if rng.below(8) == 0 {
            store = reboot(store);
        }
    }
}

#[test]
fn power_cut_at_every_operation_leaves_old_or_new() {
    let mut tally = Tally::default();
    for seed in 0..30 {
        campaign::<4096>(seed, 80, &mut tally);
    }
    println!("power_cut_at_every_operation_leaves_old_or_new: {tally:?}");
    assert!(tally.cut_points > 9_000, "{tally:?}");
    assert!(
        tally.old > 0 && tally.new > 0,
        "both outcomes seen: {tally:?}"
    );
}

#[test]
fn power_cut_with_one_full_record_per_sector_leaves_old_or_new() {
    let mut tally = Tally::default();
    for seed in 100..110 {
        campaign::<2048>(seed, 60, &mut tally);
    }
    println!("power_cut_with_one_full_record_per_sector_leaves_old_or_new: {tally:?}");
    assert!(tally.cut_points > 2_000, "{tally:?}");
    assert!(
        tally.old > 0 && tally.new > 0,
        "both outcomes seen: {tally:?}"
    );
}

/// Long run (a few minutes in the dev profile): `cargo test -p
/// bridge-logic --features sim persist::tests::power_cut_long --
/// --ignored --nocapture`.
#[test]
#[ignore = "long: millions of cut points"]
fn power_cut_long_campaign() {
    let mut tally = Tally::default();
    for seed in 0..2_000 {
        campaign::<4096>(1_000_000 + seed, 200, &mut tally);
    }
    for seed in 0..500 {
        campaign::<2048>(2_000_000 + seed, 200, &mut tally);
    }
    for seed in 0..300 {
        campaign::<8192>(3_000_000 + seed, 300, &mut tally);
    }
    println!("power_cut_long_campaign: {tally:?}");
}

#[test]
fn torn_erase_of_the_next_sector_keeps_the_latest() {
    for seed in 0..50 {
        let mut store = fresh();
        for i in 0..4u8 {
            store.save(&[i; 1000]).unwrap(); // sector 0 full
        }
        let ops = store.flash().ops();
        store.flash_mut().cut_power_at(ops, seed); // the erase of sector 1
        assert_eq!(store.save(&[9; 1000]), Err(StoreError::Flash));
        assert_eq!(store.flash().sector_erases(), &[1, 1]);
        let mut flash = store.into_inner();
        flash.restore_power();
        assert_eq!(load(&mut Store::new(flash)).unwrap(), [3; 1000]);
    }
}

#[test]
fn cut_between_erase_and_record_keeps_the_old_sector() {
    let mut store = fresh();
    for i in 0..4u8 {
        store.save(&[i; 1000]).unwrap();
    }
    let ops = store.flash().ops();
    // Operation `ops` erases sector 1; `ops + 1` is the header, cut
    // before any of it lands.
    store.flash_mut().cut_power_at(ops + 1, 0);
    let _ = store.save(&[9; 1000]);
    let mut flash = store.into_inner();
    flash.restore_power();
    flash.sectors_mut()[1].fill(0xFF); // whatever the torn header did
    let mut store = Store::new(flash);
    assert_eq!(load(&mut store).unwrap(), [3; 1000]);
    assert_eq!(store.stats().sector, Some(0));
}

// ---------------------------------------------------------- fuzz

/// Fills `flash` with one of several kinds of hostile content.
fn hostile<const N: usize>(flash: &mut SimFlash<N, 2>, rng: &mut SplitMix64, kind: usize) {
    match kind {
        // Uniform noise.
        0 => {
            for s in flash.sectors_mut() {
                rng.fill(s);
            }
        }
        // Real records, then bit flips and overwritten bytes.
        1 => {
            let mut store = Store::new(flash.clone());
            for _ in 0..rng.range(1, 12) {
                let img = random_image(rng);
                store.save(&img).unwrap();
            }
            *flash = store.into_inner();
            for _ in 0..rng.range(1, 20) {
                let s = rng.below(2);
                let at = rng.below(N);
                if rng.coin() {
                    flash.sectors_mut()[s][at] ^= 1 << rng.below(8);
                } else {
                    flash.sectors_mut()[s][at] = rng.next_u32() as u8;
                }
            }
        }
        // Framed headers (valid header CRC) with hostile fields, some
        // complete records of any version, runs of 0xFF and 0x00.
        // Kind 2 gives the complete records sequence numbers from one
        // window, as the store writes them; kind 3 any sequence numbers.
        _ => {
            let base = rng.next_u32();
            for s in 0..2 {
                let mut at = 0;
                while at + 64 < N {
                    match rng.below(5) {
                        0 => {
                            let h = Header {
                                version: rng.next_u32() as u16,
                                len: rng.next_u32() as u16,
                                seq: rng.next_u32(),
                            };
                            put(flash, s, at, &h.encode());
                            at += HEADER_LEN;
                        }
                        1 => {
                            let len = rng.range(0, (N - at - 28).min(MAX_IMAGE + 8));
                            let payload = image(rng, len);
                            let version = if rng.coin() { 1 } else { rng.below(4) as u16 };
                            let seq = if kind == 2 {
                                base.wrapping_add(rng.below(1000) as u32)
                            } else {
                                rng.next_u32()
                            };
                            let r = raw_record(version, seq, &payload);
                            put(flash, s, at, &r);
                            at += r.len();
                        }
                        2 => at += rng.range(1, 300),
                        3 => {
                            let n = rng.range(1, 64);
                            flash.sectors_mut()[s][at..at + n].fill(0);
                            at += n;
                        }
                        _ => {
                            let n = rng.range(1, 64);
                            rng.fill(&mut flash.sectors_mut()[s][at..at + n]);
                            at += n;
                        }
                    }
                    // Sometimes unaligned.
                    if rng.below(4) == 0 {
                        at += rng.below(4);
                    }
                }
            }
        }
    }
}

#[test]
fn random_flash_contents_never_panic_and_a_save_always_recovers() {
    for seed in 0..600u64 {
        let mut rng = SplitMix64::new(seed);
        let mut flash = Flash::new();
        hostile(&mut flash, &mut rng, (seed % 3) as usize);
        let mut store = Store::new(flash.clone());
        match load(&mut store) {
            Ok(v) => assert!(v.len() <= MAX_IMAGE),
            Err(e) => assert!(matches!(e, StoreError::Corrupt), "seed {seed}: {e:?}"),
        }
        let _ = store.stats();
        for mut s in [store, Store::new(flash)] {
            let img = random_image(&mut rng);
            s.save(&img).unwrap();
            assert_eq!(load(&mut s).unwrap(), img, "seed {seed}");
            let mut s = reboot(s);
            assert_eq!(load(&mut s).unwrap(), img, "seed {seed}");
            assert_eq!(s.flash().counters().overwrites, 0, "seed {seed}");
        }
    }
}

/// Intact records with sequence numbers all over the circle are not
/// something the store writes (see the module docs): which of them is
/// "newest" is then arbitrary, but nothing panics and saves succeed.
#[test]
fn forged_records_with_any_sequence_numbers_never_panic() {
    for seed in 0..300u64 {
        let mut rng = SplitMix64::new(seed);
        let mut flash = Flash::new();
        hostile(&mut flash, &mut rng, 3);
        let mut store = Store::new(flash);
        if let Ok(v) = load(&mut store) {
            assert!(v.len() <= MAX_IMAGE);
        }
        for _ in 0..3 {
            store.save(&random_image(&mut rng)).unwrap();
            assert!(load(&mut store).is_ok());
        }
        assert_eq!(store.flash().counters().overwrites, 0, "seed {seed}");
    }
}
