//! Replays the fuzz targets' minimised corpora (`fuzz/corpus-min/<target>/`,
//! kept in the repository by `scripts/fuzz-campaign`) through the same
//! bodies the cargo-fuzz targets run, on stable and in `cargo test`: every
//! input the campaign kept still passes its checks.

use std::path::{Path, PathBuf};

fn corpus(target: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/corpus-min")
        .join(target);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut files: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
        .into_iter()
        .filter_map(|p| std::fs::read(&p).ok().map(|b| (p, b)))
        .collect()
}

fn replay(target: &str, body: impl Fn(&[u8])) -> usize {
    let inputs = corpus(target);
    for (path, bytes) in &inputs {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| body(bytes)));
        assert!(r.is_ok(), "{target}: {} fails", path.display());
    }
    inputs.len()
}

#[test]
fn the_modbus_stream_corpus_passes() {
    let n = replay("modbus_stream", |d| {
        let (records, fix_crc) = host_tests::modbus_bench::records_from_fuzz(d);
        host_tests::modbus_bench::check_stream(&records, fix_crc);
    });
    assert!(n > 0, "no corpus in fuzz/corpus-min/modbus_stream");
}

#[test]
fn the_i2c_stream_corpus_passes() {
    let n = replay("i2c_stream", host_tests::i2c_bench::check_i2c_stream);
    assert!(n > 0, "no corpus in fuzz/corpus-min/i2c_stream");
}

#[test]
fn the_usb_reports_corpus_passes() {
    let n = replay("usb_reports", |d| {
        host_tests::usb_bench::check_usb_stream(d);
    });
    assert!(n > 0, "no corpus in fuzz/corpus-min/usb_reports");
}

#[test]
fn the_ioext_registers_corpus_passes() {
    let n = replay("ioext_registers", host_tests::ioext_fuzz::run);
    assert!(n > 0, "no corpus in fuzz/corpus-min/ioext_registers");
}

#[test]
fn the_ext_space_corpus_passes() {
    let n = replay("ext_space", |d| {
        host_tests::ext_fuzz::check_ext_stream(d);
    });
    assert!(n > 0, "no corpus in fuzz/corpus-min/ext_space");
}
