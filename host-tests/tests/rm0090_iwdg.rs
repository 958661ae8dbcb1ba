//! The firmware's watchdog driver (`drivers_core::iwdg`, the code the board
//! runs) against the RM0090 §21 model (`host_tests::rm0090::iwdg`): one
//! test per rule (W1–W5); the two windows (`SHORT` whenever an axis may
//! move, `LONG` only around a settings save) over the LSI's 17–47 kHz
//! spread; window changes while the watchdog runs (PVU/RVU obeyed, the
//! reload from the new RLR, the long window in effect before an erase and
//! the short one after it); and what happens when the LSI domain does not
//! take an update.

use bridge_logic::bridge::WatchdogWindow;
use bridge_logic::rate::PERIOD_MAX_US;
use drivers_core::flash::ERASE_MAX_MS;
use drivers_core::iwdg::bits::KEY_ACCESS;
use drivers_core::iwdg::IwdgReg;
use drivers_core::iwdg::{
    prescaler_and_reload, timeout_us, Watchdog, Window, WindowError, LONG, LONG_MAX_US,
    LONG_MIN_US, LONG_MS, LSI_MAX_HZ, LSI_MIN_HZ, SAVE_STALL_MAX_US, SHORT, SHORT_MAX_US,
    SHORT_MIN_US, WINDOW_POLLS_MAX,
};
use drivers_core::Regs;
use host_tests::rm0090::iwdg::IwdgModel;

/// The fastest and the slowest LSI, Hz.
const FAST: u64 = LSI_MAX_HZ as u64;
const SLOW: u64 = LSI_MIN_HZ as u64;

/// Started as the firmware starts it: the long window (init's chain
/// detection and set-up).
fn started() -> Watchdog<IwdgModel> {
    Watchdog::start(IwdgModel::new(), LONG)
}

/// Started, then in the short window (as at the end of init).
fn short() -> Watchdog<IwdgModel> {
    let mut w = started();
    assert_eq!(w.set_window(SHORT), Ok(()));
    w
}

/// LSI cycles in `ms` at `hz`.
fn cycles(ms: u64, hz: u64) -> u64 {
    ms * hz / 1000
}

fn no_violations(w: &Watchdog<IwdgModel>) {
    assert_eq!(w.port().violations(), &[] as &[String]);
    assert_eq!(w.port().protected_writes, 0, "a PR/RLR write was protected");
}

/// A control tick every `period_us` for `total_us` at `hz`, each feeding
/// in `window` (the LSI runs on its own clock: the cycles are accumulated
/// from the µs, not rounded per tick).
fn ticks(w: &mut Watchdog<IwdgModel>, hz: u64, period_us: u64, total_us: u64, window: Window) {
    let (mut t, mut done) = (0u64, 0u64);
    while t < total_us {
        t += period_us;
        let due = t * hz / 1_000_000;
        w.port_mut().lsi(due - done);
        done = due;
        assert_eq!(w.feed_in(window), Ok(()));
    }
}

/// µs from now (right after a feed) to the watchdog's reset, unfed, if it
/// comes within `limit_us`.
fn unfed_until_reset(w: &mut Watchdog<IwdgModel>, hz: u64, limit_us: u64) -> Option<u64> {
    let from = w.port().cycles();
    w.port_mut().lsi(limit_us * hz / 1_000_000);
    w.port().reset_at().map(|at| (at - from) * 1_000_000 / hz)
}

// ----------------------------------------------------------- W1–W5 ----

#[test]
fn w1_start_runs_the_watchdog() {
    let w = started();
    assert!(w.port().running());
    assert_eq!(w.port().violations(), &[] as &[String]);
}

#[test]
fn w2_pr_and_rlr_are_written_unlocked_and_protected_again_after() {
    let w = started();
    let (pr, rlr) = prescaler_and_reload(LONG_MS, 32_000);
    assert_eq!((w.port().pr(), w.port().rlr()), (pr, rlr));
    assert_eq!(
        w.port().protected_writes,
        0,
        "no write hit a protected PR/RLR"
    );
    assert!(!w.port().access(), "protected again after the start");
    assert_eq!(w.port().violations(), &[] as &[String]);
    assert_eq!(w.window(), Some(LONG));
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
fn w4_w5_fed_every_millisecond_the_long_window_never_resets_at_any_lsi_rate() {
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
fn w5_unfed_the_long_window_resets_within_its_bounds_and_outlasts_a_sector_erase() {
    for hz in [FAST, SLOW] {
        let mut w = started();
        w.feed();
        let us = unfed_until_reset(&mut w, hz, 13_000_000).expect("reset");
        assert!(
            (LONG_MIN_US..=LONG_MAX_US).contains(&us),
            "{hz} Hz: reset after {us} µs"
        );
        assert!(us > u64::from(ERASE_MAX_MS) * 1000 + 2 * u64::from(PERIOD_MAX_US));
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
    let mut m = IwdgModel::new();
    m.write(IwdgReg::Kr, 0xCCCC);
    m.write(IwdgReg::Pr, 4);
    m.lsi(10);
    assert_eq!(m.pr(), 0);
    assert_eq!(m.protected_writes, 1);
}

// ------------------------------------------------------ the windows ----

#[test]
fn the_short_window_is_16_9_to_47_1_ms_and_the_long_one_4_42_to_12_24_s() {
    assert_eq!(SHORT, Window { pr: 0, rlr: 199 });
    assert_eq!(timeout_us(SHORT.pr, SHORT.rlr, 32_000), 25_000);
    assert_eq!((SHORT_MIN_US, SHORT_MAX_US), (16_936, 47_059));
    assert_eq!(LONG, Window { pr: 4, rlr: 3249 });
    assert_eq!((LONG_MIN_US, LONG_MAX_US), (4_424_170, 12_235_295));
    assert_eq!(SAVE_STALL_MAX_US, 4_156_000);
    assert_eq!(Window::of(WatchdogWindow::Short), SHORT);
    assert_eq!(Window::of(WatchdogWindow::Long), LONG);
}

#[test]
fn fed_every_tick_the_short_window_never_resets_at_17_or_47_khz() {
    // The slowest tick (500 Hz) and the fastest (10 kHz).
    for hz in [SLOW, FAST] {
        for period_us in [u64::from(PERIOD_MAX_US), 100] {
            let mut w = short();
            ticks(&mut w, hz, period_us, 5_000_000, SHORT);
            assert_eq!(w.port().reset_at(), None, "{hz} Hz, {period_us} µs");
            no_violations(&w);
        }
    }
}

#[test]
fn a_tick_late_by_seven_periods_at_500_hz_still_feeds_the_short_window_in_time_at_47_khz() {
    let mut w = short();
    ticks(&mut w, FAST, 8 * u64::from(PERIOD_MAX_US), 5_000_000, SHORT);
    assert_eq!(w.port().reset_at(), None);
}

#[test]
fn unfed_the_short_window_resets_within_its_bounds_at_47_and_17_khz() {
    for hz in [FAST, 32_000, SLOW] {
        let mut w = short();
        // A few ticks first: the prescaler's phase at the last feed is
        // whatever the ticks left it at.
        ticks(&mut w, hz, 1_000, 7_000, SHORT);
        let us = unfed_until_reset(&mut w, hz, 100_000).expect("reset");
        assert!(
            (SHORT_MIN_US..=SHORT_MAX_US).contains(&us),
            "{hz} Hz: reset after {us} µs"
        );
        assert!(us <= 50_000, "tens of ms: {us} µs");
    }
}

// ------------------------------------------------- window changes ----

#[test]
fn switching_to_long_and_back_obeys_pvu_and_rvu_and_reloads_from_the_new_rlr() {
    let mut w = started();
    for window in [SHORT, LONG, SHORT, LONG, SHORT] {
        // Back to back, no LSI time between them but the polls'.
        assert_eq!(w.set_window(window), Ok(()));
        assert_eq!((w.port().pr(), w.port().rlr()), (window.pr, window.rlr));
        assert_eq!(w.port().counter(), window.rlr, "reloaded from the new RLR");
        assert_eq!(w.window(), Some(window));
        assert!(!w.port().access(), "protected again");
        no_violations(&w);
    }
    assert_eq!(w.port().reset_at(), None);
}

#[test]
fn a_4_s_erase_inside_the_long_window_does_not_reset_at_the_fastest_lsi_and_short_follows() {
    let mut w = short();
    ticks(&mut w, FAST, 1_000, 1_000_000, SHORT);
    // Housekeeping after take_save: the long window, then the erase (the
    // CPU stalls, nothing feeds) — with a margin of a tick.
    assert_eq!(w.feed_in(LONG), Ok(()));
    w.port_mut()
        .lsi((SAVE_STALL_MAX_US + u64::from(PERIOD_MAX_US)) * FAST / 1_000_000);
    assert_eq!(
        w.port().reset_at(),
        None,
        "reset in the middle of the erase"
    );
    // Ticks again (still long until `saved`), then short from the first
    // tick after `saved`.
    ticks(&mut w, FAST, 1_000, 100_000, LONG);
    ticks(&mut w, FAST, 1_000, 100_000, SHORT);
    assert_eq!(w.window(), Some(SHORT));
    let us = unfed_until_reset(&mut w, FAST, 100_000).expect("reset");
    assert!((SHORT_MIN_US..=SHORT_MAX_US).contains(&us), "{us} µs");
    no_violations(&w);
}

#[test]
fn the_change_to_long_waits_for_rvu_before_the_reload() {
    // A reload before RVU clears would load the short RLR (199) at the
    // long prescaler (÷64): 272 ms at 47 kHz, a reset in the middle of
    // the erase.
    let mut w = short();
    assert_eq!(w.set_window(LONG), Ok(()));
    assert_eq!(w.port().counter(), LONG.rlr);
    assert_eq!(unfed_until_reset(&mut w, FAST, 1_000_000), None);
}

#[test]
fn feed_in_writes_pr_and_rlr_only_when_the_window_changes() {
    let mut w = short();
    let reads = w.port().sr_reads;
    for _ in 0..100 {
        w.port_mut().lsi(30);
        assert_eq!(w.feed_in(SHORT), Ok(()));
    }
    assert_eq!(w.port().sr_reads, reads, "a plain feed polls nothing");
    assert_eq!(w.port().counter(), SHORT.rlr);
    assert_eq!(w.feed_in(LONG), Ok(()));
    assert!(w.port().sr_reads > reads, "a change waits for PVU/RVU");
    assert_eq!(w.port().rlr(), LONG.rlr);
    no_violations(&w);
}

#[test]
fn a_change_while_an_update_still_runs_writes_nothing_and_is_busy() {
    let mut w = started();
    // An update in flight (as after a change whose wait gave up).
    w.port_mut().write(IwdgReg::Kr, KEY_ACCESS);
    w.port_mut().write(IwdgReg::Pr, 3);
    assert_eq!(w.set_window(SHORT), Err(WindowError::Busy));
    assert_eq!(w.window(), None);
    no_violations(&w);
    // Once it is through, the change goes ahead.
    w.port_mut().lsi(5);
    assert_eq!(w.feed_in(SHORT), Ok(()));
    assert_eq!((w.port().pr(), w.port().rlr()), (SHORT.pr, SHORT.rlr));
    no_violations(&w);
}

#[test]
fn the_model_catches_a_window_written_while_pvu_and_rvu_are_set() {
    // What a driver that skipped the waits would do: KR = 0x5555, PR, RLR,
    // 0xAAAA at once, twice in a row.
    let mut m = IwdgModel::new();
    m.write(IwdgReg::Kr, 0xCCCC);
    for window in [SHORT, LONG] {
        m.write(IwdgReg::Kr, KEY_ACCESS);
        m.write(IwdgReg::Pr, window.pr);
        m.write(IwdgReg::Rlr, window.rlr);
        m.write(IwdgReg::Kr, 0xAAAA);
    }
    assert_eq!(
        m.violations(),
        &[
            "Pr written while its update flag is set".to_string(),
            "Rlr written while its update flag is set".to_string()
        ]
    );
    // And the reloads came before the updates: the counter holds the reset
    // value, not the new RLR.
    assert_eq!(m.counter(), 0xFFF);
}

#[test]
fn a_dead_lsi_fails_one_change_after_a_bounded_wait_then_costs_one_sr_read() {
    let mut w = short();
    w.port_mut().stop_lsi();
    let reads = w.port().sr_reads;
    assert_eq!(w.set_window(LONG), Err(WindowError::Timeout));
    let waited = w.port().sr_reads - reads;
    assert_eq!(waited, 1 + u64::from(WINDOW_POLLS_MAX));
    assert_eq!(w.window(), None);
    // Every later call: one look at SR, no write into a running update.
    for _ in 0..10 {
        let reads = w.port().sr_reads;
        assert_eq!(w.feed_in(SHORT), Err(WindowError::Busy));
        assert_eq!(w.port().sr_reads - reads, 1);
    }
    no_violations(&w);
}

/// The model behind a bus that loses every RLR write.
struct LosesRlr(IwdgModel);

impl Regs<IwdgReg> for LosesRlr {
    fn read(&mut self, reg: IwdgReg) -> u32 {
        self.0.read(reg)
    }

    fn write(&mut self, reg: IwdgReg, value: u32) {
        if reg != IwdgReg::Rlr {
            self.0.write(reg, value);
        }
    }
}

#[test]
fn a_window_that_does_not_read_back_is_not_taken_as_in_effect() {
    let mut w = Watchdog::start(LosesRlr(IwdgModel::new()), SHORT);
    assert_eq!(w.window(), None, "RLR reads back 0xFFF");
    assert_eq!(w.set_window(LONG), Err(WindowError::Mismatch));
    assert_eq!(w.window(), None);
    // Tried again next time, not fed as if it were long.
    assert_eq!(w.feed_in(LONG), Err(WindowError::Mismatch));
}
