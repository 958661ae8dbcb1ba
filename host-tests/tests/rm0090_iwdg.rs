//! The firmware's watchdog driver (`drivers_core::iwdg`, the code the board
//! runs) against the RM0090 §21 model (`host_tests::rm0090::iwdg`): one
//! test per rule (W1–W5), and the firmware's timeout over the LSI's
//! 17–47 kHz spread.

use drivers_core::flash::ERASE_MAX_MS;
use drivers_core::iwdg::{prescaler_and_reload, timeout_us, Watchdog};
use host_tests::rm0090::iwdg::IwdgModel;

/// The board's nominal timeout (`platform::Watchdog::TIMEOUT_MS`).
const TIMEOUT_MS: u32 = 6_500;

fn started() -> Watchdog<IwdgModel> {
    Watchdog::start(IwdgModel::new(), TIMEOUT_MS)
}

/// LSI cycles in `ms` at `hz`.
fn cycles(ms: u64, hz: u64) -> u64 {
    ms * hz / 1000
}

#[test]
fn w1_start_runs_the_watchdog() {
    let w = started();
    assert!(w.port().running());
    assert_eq!(w.port().violations(), &[] as &[String]);
}

#[test]
fn w2_pr_and_rlr_are_written_unlocked_and_protected_again_after() {
    let w = started();
    let (pr, rlr) = prescaler_and_reload(TIMEOUT_MS, 32_000);
    assert_eq!((w.port().pr(), w.port().rlr()), (pr, rlr));
    assert_eq!(
        w.port().protected_writes,
        0,
        "no write hit a protected PR/RLR"
    );
    assert!(!w.port().access(), "protected again after the start");
    assert_eq!(w.port().violations(), &[] as &[String]);
}

#[test]
fn w3_w4_the_first_reload_waits_for_pvu_and_rvu_so_the_first_period_is_the_full_timeout() {
    let mut w = started();
    assert!(w.updated());
    // Unfed from the start: not reset at the reset values' 512 ms…
    w.port_mut().lsi(cycles(600, 32_000));
    assert_eq!(w.port().reset_at(), None);
    // …but at 6.5 s.
    w.port_mut().lsi(cycles(6_000, 32_000));
    let at = w.port().reset_at().expect("reset");
    let ms = at * 1000 / 32_000;
    assert!((6_400..=6_600).contains(&ms), "reset after {ms} ms");
}

#[test]
fn w4_w5_fed_every_millisecond_it_never_resets_at_any_lsi_rate() {
    for hz in [17_000, 32_000, 47_000] {
        let mut w = started();
        for _ in 0..13_000 {
            w.port_mut().lsi(hz / 1000);
            w.feed();
        }
        assert_eq!(w.port().reset_at(), None, "{hz} Hz");
    }
}

#[test]
fn w5_unfed_it_resets_within_the_lsi_spread_and_outlasts_a_sector_erase() {
    for (hz, min_ms, max_ms) in [(47_000u64, 4_400u64, 4_500u64), (17_000, 12_200, 12_300)] {
        let mut w = started();
        w.feed();
        w.port_mut().lsi(cycles(13_000, hz));
        let ms = w.port().reset_at().expect("reset") * 1000 / hz;
        assert!(
            (min_ms..=max_ms).contains(&ms),
            "{hz} Hz: reset after {ms} ms"
        );
        assert!(ms > u64::from(ERASE_MAX_MS) + 2);
    }
}

#[test]
fn the_6500_ms_timeout_is_prescaler_64_and_reload_3249() {
    assert_eq!(prescaler_and_reload(6_500, 32_000), (4, 3249));
    assert_eq!(timeout_us(4, 3249, 32_000), 6_500_000);
    assert_eq!(prescaler_and_reload(100_000, 32_000), (6, 0xFFF), "capped");
    assert_eq!(prescaler_and_reload(0, 32_000), (0, 0));
}

#[test]
fn model_pr_written_without_the_access_key_is_ignored() {
    use drivers_core::iwdg::IwdgReg;
    use drivers_core::Regs;
    let mut m = IwdgModel::new();
    m.write(IwdgReg::Kr, 0xCCCC);
    m.write(IwdgReg::Pr, 4);
    m.lsi(10);
    assert_eq!(m.pr(), 0);
    assert_eq!(m.protected_writes, 1);
}
