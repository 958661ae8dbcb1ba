//! The bridge at the fastest tick rate its chain fits (`Bridge::new_fitted`,
//! what the firmware's `init` calls): the chain is detected once, and the
//! axes run at the rate returned.

use bridge_logic::bridge::{Bridge, SettingsSource};
use bridge_logic::postep60::{PowerStage, Settings};
use bridge_logic::rate;
use stepbridge_sim::SimChain;

fn windows_of_one_detection(n: usize) -> u64 {
    let b = Bridge::new(
        SimChain::new(n),
        PowerStage::REFERENCE,
        Settings::FACTORY,
        SettingsSource::Stored,
        1000,
    );
    b.chain().bus().windows()
}

#[test]
fn eight_chips_in_a_5_khz_build_run_overlapped_at_the_fitted_rate_after_one_detection() {
    let (b, r) = Bridge::new_fitted(
        SimChain::new(8),
        PowerStage::REFERENCE,
        Settings::FACTORY,
        SettingsSource::Stored,
        5000,
    );
    assert_eq!(r, rate::fit(5000, 8));
    assert!(!r.derated, "8 chips fit 5 kHz overlapped");
    assert!(r.overlapped && b.is_overlapped());
    assert_eq!(b.axes(), 8);
    assert_eq!(b.chain().bus().windows(), windows_of_one_detection(8));
}

#[test]
fn a_chain_that_fits_keeps_the_build_rate() {
    let (b, r) = Bridge::new_fitted(
        SimChain::new(4),
        PowerStage::REFERENCE,
        Settings::FACTORY,
        SettingsSource::Stored,
        5000,
    );
    assert_eq!((r.hz, r.us, r.derated), (5000, 200, false));
    assert!(!r.overlapped && !b.is_overlapped(), "4 chips fit in a row");
    assert_eq!(b.axes(), 4);
}

#[test]
fn a_platform_with_a_costlier_tick_fits_its_own_cost() {
    // The QEMU image's simulated chips: ~200 µs for 4, no 5 kHz.
    let (b, r) = Bridge::new_fitted_with(
        SimChain::new(4),
        PowerStage::REFERENCE,
        Settings::FACTORY,
        SettingsSource::Stored,
        5000,
        |n| rate::Need::serial(20_000 + 45_000 * n as u64),
    );
    assert_eq!(
        (r.hz, r.us, r.derated, r.overlapped),
        (2500, 400, true, false)
    );
    assert_eq!(b.axes(), 4);
    assert_eq!(b.chain().bus().windows(), windows_of_one_detection(4));
}

/// The README's control-tick table as the rate module computes it: one row
/// per chain length (computation, batch, in a row, overlapped, the rate).
fn control_tick_table(build_hz: u32) -> Vec<String> {
    let bus = rate::BOARD_BUS;
    let us = |ns: u64| format!("{:.1} µs", ns as f64 / 1000.0);
    (1..=8)
        .map(|n| {
            let need = rate::need(n);
            let r = rate::fit(build_hz, n);
            let mode = if r.overlapped {
                "overlapped"
            } else {
                "in a row"
            };
            format!(
                "| {n} | {} | {} | {} µs | {} µs | {} kHz, {mode} |",
                us(rate::compute_ns(n)),
                us(bus.batch_ns(rate::STREAM_WINDOWS, n as u32)),
                need.serial_ns.div_ceil(1000),
                need.overlapped_ns.div_ceil(1000),
                r.hz / 1000
            )
        })
        .collect()
}

#[test]
fn the_readme_states_the_rate_every_chain_length_runs_at() {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../README.md"))
        .expect("README");
    let table = control_tick_table(5000);
    for row in &table {
        assert!(
            readme.contains(row.as_str()),
            "README's control-tick table lacks (or differs from) the row\n{row}\nthe table:\n{}",
            table.join("\n")
        );
    }
}
