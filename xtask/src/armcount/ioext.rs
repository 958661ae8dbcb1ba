//! `cargo xtask ioext-cpu`: the I/O extension's CPU work per 256-bit
//! transfer (8 axes, every input and lamp mapped; `ioext-armcount`), then
//! the board driver's start of a transfer (drivers::ioext_spi,
//! IoExtPort::run) on its own code, built for QEMU
//! (firmware/tests/ioext_cost.rs): QEMU has no DMA and no TIM1, so only the
//! start runs as on a board (its end never comes and is not counted). Per
//! region, the empty-marker calibration subtracted.

use super::*;

/// Iterations of both benches (the counts are divided by it).
const N: f64 = 200.0;

/// The bench image's markers; counter 5 is the calibration.
const IMAGE: Run = Run {
    image: Image::Bench("ioext-armcount", &[]),
    marks: &[
        "mark_off",
        "mark_tick",
        "mark_spi",
        "mark_complete",
        "mark_timer",
        "mark_cal",
    ],
    dump: "mark_dump",
    epoch: None,
    out: "ioext.out",
};

/// The driver test's markers; counter 3 is the calibration.
const DRIVER: Run = Run {
    image: Image::FirmwareTest("ioext_cost"),
    marks: &["mark_off", "mark_spi", "mark_timer", "mark_cal"],
    dump: "mark_dump",
    epoch: None,
    out: "ioext-cost.out",
};

/// The image's regions, each a label and its counter.
const IMAGE_ROWS: [(&str, usize); 4] = [
    ("IoExtension::tick (plan, 24 lamps):", 1),
    ("SPI engine: pack 32 bytes + unpack:", 2),
    ("IoExtension::complete (32 inputs):", 3),
    ("timer engine: BSRR table + port samples:", 4),
];

/// The driver test's regions.
const DRIVER_ROWS: [(&str, usize); 2] = [
    ("driver start, SPI engine, 256 bits (N = 0):", 1),
    ("driver start, bit engine, 256 bits (N = 255):", 2),
];

/// `cargo xtask ioext-cpu`.
pub fn ioext_cpu(_args: &[String]) -> Result {
    let armcount = Armcount::new()?;
    let (_, c) = armcount.run(&IMAGE, false)?;
    print_rows(&c, 5, &IMAGE_ROWS);
    let (_, c) = armcount.run(&DRIVER, false)?;
    print_rows(&c, 3, &DRIVER_ROWS);
    Ok(())
}

/// One line per region (its label and counter): its instructions per run,
/// less the calibration counter `cal`'s, right-aligned at column 50.
fn print_rows(c: &Counts, cal: usize, rows: &[(&str, usize)]) {
    for (label, k) in rows {
        let insns = c.insns(*k) as f64 / N - c.insns(cal) as f64 / N;
        let n = format!("{insns:.0}");
        let width = 50usize.saturating_sub(label.len() + 1);
        println!("{label} {n:>width$} instructions");
    }
}
