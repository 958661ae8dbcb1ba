//! The independent watchdog (RM0090 §21) through an [`IwdgPort`] — on the
//! chip the firmware's PAC glue for `pac::IWDG` (`firmware::drivers::iwdg`),
//! on the host the RM0090 model `host_tests::rm0090::iwdg`.
//!
//! # The sequences
//!
//! * **Start** ([`Watchdog::start`], §21.3): KR = 0xCCCC (the IWDG and the
//!   LSI start; from here on nothing stops it), KR = 0x5555 (PR and RLR
//!   writable), PR, RLR, then a bounded wait for SR.PVU and SR.RVU to clear
//!   (each update crosses into the LSI domain and takes up to 5 LSI cycles;
//!   PR/RLR may only be written while their flag is clear, and the reload
//!   below would load the old RLR before RVU clears), then KR = 0xAAAA
//!   (reload with the new RLR; any key but 0x5555 also write-protects PR
//!   and RLR again, §21.3.2); PR and RLR read back tell whether the window
//!   is in effect ([`Watchdog::window`]).
//! * **Window change** ([`Watchdog::set_window`], §21.3, §21.4.4): KR =
//!   0xAAAA first (a full period of the old window for what follows: a
//!   faster prescaler may take effect before the new reload value), PVU
//!   and RVU must already be clear (else nothing is written:
//!   [`WindowError::Busy`]), KR = 0x5555, PR, RLR, a wait for PVU and RVU
//!   to clear bounded by [`WINDOW_POLLS_MAX`], KR = 0xAAAA (the counter
//!   reloads from the new RLR), then PR and RLR read back (valid once
//!   their flags are clear) must be the new window.
//! * **Feed** ([`Watchdog::feed`]): KR = 0xAAAA. One register write; it
//!   never waits. [`Watchdog::feed_in`] feeds while the window asked for is
//!   in effect and changes it otherwise.
//!
//! # The windows
//!
//! The timeout is (RLR + 1) · 4 · 2^PR / f_LSI. [`prescaler_and_reload`]
//! picks the smallest prescaler whose 12-bit reload reaches the requested
//! time at the nominal 32 kHz (finest resolution); the LSI of the STM32F405
//! runs anywhere from [`LSI_MIN_HZ`] to [`LSI_MAX_HZ`] (datasheet), so the
//! real timeout is 0.68 to 1.88 times the nominal one. The firmware uses
//! two ([`Window::of`] a `bridge_logic::bridge::WatchdogWindow`):
//!
//! | window | nominal | PR, RLR | fastest LSI (47 kHz) | slowest LSI (17 kHz) | bound by |
//! |---|---|---|---|---|---|
//! | [`SHORT`] (any axis may move) | 25 ms | 0 (÷4), 199 | 16.9 ms ([`SHORT_MIN_US`]) | 47.1 ms ([`SHORT_MAX_US`]) | ≤ 50 ms of runaway; ≥ 8 periods of the slowest tick (16 ms at 500 Hz) |
//! | [`LONG`] (a save's erase, every axis at rest) | 6.5 s | 4 (÷64), 3249 | 4.42 s ([`LONG_MIN_US`]) | 12.24 s ([`LONG_MAX_US`]) | > a save's longest stall, 4.16 s ([`SAVE_STALL_MAX_US`]) |
//!
//! The bounds count from the last feed: at least RLR counts (the
//! prescaler's phase at the feed is not known, so the first count may come
//! at once) and at most RLR + 1.

use bridge_logic::bridge::WatchdogWindow;
use bridge_logic::rate::PERIOD_MAX_US;
use settings_store::MAX_RECORD;

use crate::flash::{ERASE_MAX_MS, PROGRAM_BYTE_MAX_US};
use crate::Regs;

/// The IWDG's registers (RM0090 §21.4; offsets in [`IwdgReg::offset`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum IwdgReg {
    Kr,
    Pr,
    Rlr,
    Sr,
}

impl IwdgReg {
    pub const fn offset(self) -> usize {
        match self {
            IwdgReg::Kr => 0x00,
            IwdgReg::Pr => 0x04,
            IwdgReg::Rlr => 0x08,
            IwdgReg::Sr => 0x0C,
        }
    }
}

/// Keys and bits (RM0090 §21.4.1–§21.4.4).
pub mod bits {
    /// KR: PR and RLR writable.
    pub const KEY_ACCESS: u32 = 0x5555;
    /// KR: reload the counter with RLR (the feed).
    pub const KEY_RELOAD: u32 = 0xAAAA;
    /// KR: start the watchdog.
    pub const KEY_START: u32 = 0xCCCC;
    pub const SR_PVU: u32 = 1 << 0;
    pub const SR_RVU: u32 = 1 << 1;
    pub const PR_MAX: u32 = 0b110;
    /// PR's bits.
    pub const PR_MASK: u32 = 0b111;
    pub const RLR_MAX: u32 = 0xFFF;
}

use bits::*;

/// The IWDG registers (nothing else).
pub trait IwdgPort: Regs<IwdgReg> {}

impl<T: Regs<IwdgReg>> IwdgPort for T {}

/// The LSI frequency the timeout is computed for (RM0090 §21.3; the
/// datasheet's typical 32 kHz).
pub const LSI_NOMINAL_HZ: u32 = 32_000;
/// The slowest LSI of the STM32F405 (datasheet, LSI oscillator: 17 kHz
/// minimum): the longest timeouts.
pub const LSI_MIN_HZ: u32 = 17_000;
/// The fastest LSI (47 kHz maximum): the shortest timeouts.
pub const LSI_MAX_HZ: u32 = 47_000;
/// SR polls before the start gives up waiting for PVU/RVU (5 LSI cycles at
/// 17 kHz are 294 µs; a poll takes a few APB1 cycles).
pub const UPDATE_POLLS_MAX: u32 = 1 << 20;
/// SR polls before a window change gives up waiting for PVU/RVU: 2¹⁵ polls
/// of at least 4 CPU cycles (one APB1 cycle at 42 MHz) are at least 780 µs
/// at 168 MHz, more than twice the 294 µs of an update at 17 kHz, and at
/// ~100 ns a poll still only ~3.3 ms — a fifth of [`SHORT_MIN_US`], so a
/// change that never completes cannot itself make the short window expire.
pub const WINDOW_POLLS_MAX: u32 = 1 << 15;

/// PR and RLR for `timeout_ms` at `lsi_hz`: the smallest prescaler (finest
/// step) whose reload fits in 12 bits; the longest timeout if none does.
// u32 × u32 in u64; the divider is 4 << pr with pr ≤ PR_MAX (6).
#[allow(clippy::arithmetic_side_effects)]
pub const fn prescaler_and_reload(timeout_ms: u32, lsi_hz: u32) -> (u32, u32) {
    let cycles = timeout_ms as u64 * lsi_hz as u64 / 1000;
    let mut pr = 0;
    while pr <= PR_MAX {
        let divider = 4u64 << pr;
        let reload = (cycles / divider).saturating_sub(1);
        if reload <= RLR_MAX as u64 {
            return (pr, reload as u32);
        }
        pr += 1;
    }
    (PR_MAX, RLR_MAX)
}

/// The timeout of `pr`, `rlr` at `lsi_hz`, in µs: RLR + 1 counts.
// rlr + 1 in u64.
#[allow(clippy::arithmetic_side_effects)]
pub const fn timeout_us(pr: u32, rlr: u32, lsi_hz: u32) -> u64 {
    Window { pr, rlr }.counts_us(rlr as u64 + 1, lsi_hz, false)
}

/// One timeout: the prescaler and the reload value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Window {
    /// PR: the counter counts at f_LSI / (4 · 2^pr); 0..=6.
    pub pr: u32,
    /// RLR: the counter's value after a feed; 0..=0xFFF.
    pub rlr: u32,
}

impl Window {
    /// `timeout_ms` at the nominal LSI ([`prescaler_and_reload`]).
    pub const fn nominal(timeout_ms: u32) -> Window {
        let (pr, rlr) = prescaler_and_reload(timeout_ms, LSI_NOMINAL_HZ);
        Window { pr, rlr }
    }

    /// The window the bridge asks for.
    pub const fn of(window: WatchdogWindow) -> Window {
        match window {
            WatchdogWindow::Short => SHORT,
            WatchdogWindow::Long => LONG,
        }
    }

    /// LSI cycles of one count.
    const fn divider(self) -> u64 {
        4u64 << if self.pr > PR_MAX { PR_MAX } else { self.pr }
    }

    /// `counts` counts at `lsi_hz`, µs, rounded down or up.
    // counts ≤ 0x1000, divider ≤ 256: the product is far below u64::MAX; hz ≥ 1.
    #[allow(clippy::arithmetic_side_effects)]
    const fn counts_us(self, counts: u64, lsi_hz: u32, up: bool) -> u64 {
        let hz = if lsi_hz == 0 { 1 } else { lsi_hz as u64 };
        let cycles_e6 = counts * self.divider() * 1_000_000;
        if up {
            cycles_e6.div_ceil(hz)
        } else {
            cycles_e6 / hz
        }
    }

    /// The shortest time from a feed to the reset at `lsi_hz`, µs (rounded
    /// down): RLR counts.
    pub const fn min_us(self, lsi_hz: u32) -> u64 {
        self.counts_us(self.rlr as u64, lsi_hz, false)
    }

    /// The longest, µs (rounded up): RLR + 1 counts.
    // rlr + 1 in u64.
    #[allow(clippy::arithmetic_side_effects)]
    pub const fn max_us(self, lsi_hz: u32) -> u64 {
        self.counts_us(self.rlr as u64 + 1, lsi_hz, true)
    }
}

/// The short window's nominal timeout, ms: the window whenever an axis may
/// move (module docs' table).
pub const SHORT_MS: u32 = 25;
/// PR 0 (÷4), RLR 199: 200 counts of 125 µs at 32 kHz.
pub const SHORT: Window = Window::nominal(SHORT_MS);
/// 16 936 µs: the short window at the fastest LSI (199 counts of 4 cycles
/// at 47 kHz) — how long a control tick may be late before the MCU resets.
pub const SHORT_MIN_US: u64 = SHORT.min_us(LSI_MAX_HZ);
/// 47 059 µs: the short window at the slowest LSI (200 counts of 4 cycles
/// at 17 kHz) — the longest a chip runs on its last Run after the control
/// tick stopped, until the MCU resets and STBY's pull-down turns the
/// bridges off.
pub const SHORT_MAX_US: u64 = SHORT.max_us(LSI_MIN_HZ);
/// The short window must outlast this many periods of the slowest control
/// tick ([`PERIOD_MAX_US`], 2 ms at 500 Hz) at the fastest LSI: a tick may
/// start late by seven periods (14 ms) — far more than anything can hold
/// it off: the chain's and the Modbus UART's handlers (µs), a lower task's
/// bridge lock (~10 µs), a window change's wait (≤ 5 LSI cycles, 0.3 ms).
pub const SHORT_PERIODS_MIN: u64 = 8;

const _: () = assert!(
    SHORT_MAX_US <= 50_000,
    "the short window must end a runaway within tens of ms at the slowest LSI"
);
const _: () = assert!(
    SHORT_MIN_US >= SHORT_PERIODS_MIN * PERIOD_MAX_US as u64,
    "the short window must outlast 8 periods of the slowest tick at the fastest LSI"
);
const _: () = assert!(SHORT.pr == 0 && SHORT.rlr == 199);

/// The long window's nominal timeout, ms: only around a settings save
/// (module docs' table).
pub const LONG_MS: u32 = 6_500;
/// PR 4 (÷64), RLR 3249: 3250 counts of 2 ms at 32 kHz.
pub const LONG: Window = Window::nominal(LONG_MS);
/// 4 424 170 µs: the long window at the fastest LSI.
pub const LONG_MIN_US: u64 = LONG.min_us(LSI_MAX_HZ);
/// 12 235 295 µs: the long window at the slowest LSI.
pub const LONG_MAX_US: u64 = LONG.max_us(LSI_MIN_HZ);
/// 4 156 000 µs: the longest the CPU can go without a feed in a save — a
/// worst-case sector erase ([`ERASE_MAX_MS`]) plus a whole record
/// ([`MAX_RECORD`] bytes) at the worst byte programming time
/// ([`PROGRAM_BYTE_MAX_US`]) as if no tick ran between them (it does: the
/// CPU only stalls while the flash is busy).
pub const SAVE_STALL_MAX_US: u64 =
    ERASE_MAX_MS as u64 * 1000 + MAX_RECORD as u64 * PROGRAM_BYTE_MAX_US as u64;

const _: () = assert!(
    LONG_MIN_US > SAVE_STALL_MAX_US + 2 * PERIOD_MAX_US as u64,
    "the long window must outlast a save's stall and two ticks at the fastest LSI"
);

/// Why a window change did not complete ([`Watchdog::set_window`]). The
/// counter was reloaded in every case; the window in effect is unknown
/// ([`Watchdog::window`] is `None`) until a change completes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WindowError {
    /// An earlier PR/RLR update was still running (its wait had given up):
    /// nothing written. The LSI domain is not taking updates — a stopped
    /// LSI — so this call does not wait again.
    Busy,
    /// PVU/RVU still set [`WINDOW_POLLS_MAX`] polls after PR and RLR were
    /// written.
    Timeout,
    /// The update completed, but PR/RLR read back other values.
    Mismatch,
}

/// The running independent watchdog.
#[derive(Debug)]
pub struct Watchdog<P> {
    port: P,
    /// PVU/RVU were clear before the first reload (false: the first period
    /// may still run on the reset values, 512 ms nominal).
    updated: bool,
    /// The window in effect, as far as the driver knows.
    window: Option<Window>,
}

impl<P: IwdgPort> Watchdog<P> {
    /// Start the watchdog in `window` (module docs). It cannot be stopped
    /// again.
    pub fn start(port: P, window: Window) -> Watchdog<P> {
        let mut w = Watchdog {
            port,
            updated: false,
            window: None,
        };
        w.port.write(IwdgReg::Kr, KEY_START);
        w.port.write(IwdgReg::Kr, KEY_ACCESS);
        w.port.write(IwdgReg::Pr, window.pr);
        w.port.write(IwdgReg::Rlr, window.rlr);
        w.updated = w.wait_updates(UPDATE_POLLS_MAX);
        w.port.write(IwdgReg::Kr, KEY_RELOAD);
        if w.updated && w.reads_back(window) {
            w.window = Some(window);
        }
        w
    }

    /// Reload the counter (every control tick).
    pub fn feed(&mut self) {
        self.port.write(IwdgReg::Kr, KEY_RELOAD);
    }

    /// Change the window while the watchdog runs (module docs): in effect,
    /// and the counter reloaded from it, when this returns `Ok`. Takes up to
    /// 5 LSI cycles (0.3 ms at 17 kHz), at most [`WINDOW_POLLS_MAX`] polls.
    pub fn set_window(&mut self, window: Window) -> Result<(), WindowError> {
        // A full period of the window in effect for the change.
        self.port.write(IwdgReg::Kr, KEY_RELOAD);
        if self.updating() {
            self.window = None;
            return Err(WindowError::Busy);
        }
        self.window = None;
        self.port.write(IwdgReg::Kr, KEY_ACCESS);
        self.port.write(IwdgReg::Pr, window.pr);
        self.port.write(IwdgReg::Rlr, window.rlr);
        let done = self.wait_updates(WINDOW_POLLS_MAX);
        // From the new RLR once RVU is clear (from the old one if not); any
        // key but 0x5555 protects PR and RLR again.
        self.port.write(IwdgReg::Kr, KEY_RELOAD);
        if !done {
            return Err(WindowError::Timeout);
        }
        if !self.reads_back(window) {
            return Err(WindowError::Mismatch);
        }
        self.window = Some(window);
        Ok(())
    }

    /// Feed in `window`: a plain [`Watchdog::feed`] while it is in effect,
    /// else [`Watchdog::set_window`] (which reloads the counter too).
    pub fn feed_in(&mut self, window: Window) -> Result<(), WindowError> {
        if self.window == Some(window) {
            self.feed();
            Ok(())
        } else {
            self.set_window(window)
        }
    }

    /// The window in effect: `None` until one is known to be (a start or a
    /// change whose update did not complete).
    pub fn window(&self) -> Option<Window> {
        self.window
    }

    /// Whether PR and RLR were in effect before the first reload.
    pub fn updated(&self) -> bool {
        self.updated
    }

    pub fn port(&self) -> &P {
        &self.port
    }

    pub fn port_mut(&mut self) -> &mut P {
        &mut self.port
    }

    /// PR and RLR read back as `window` (valid once PVU/RVU are clear).
    fn reads_back(&mut self, window: Window) -> bool {
        let pr = self.port.read(IwdgReg::Pr) & PR_MASK;
        let rlr = self.port.read(IwdgReg::Rlr) & RLR_MAX;
        (pr, rlr) == (window.pr, window.rlr)
    }

    /// A PR or RLR update is still crossing into the LSI domain.
    fn updating(&mut self) -> bool {
        self.port.read(IwdgReg::Sr) & (SR_PVU | SR_RVU) != 0
    }

    /// Poll SR until PVU and RVU are clear, at most `polls` times.
    fn wait_updates(&mut self, polls: u32) -> bool {
        for _ in 0..polls {
            if !self.updating() {
                return true;
            }
        }
        false
    }
}
