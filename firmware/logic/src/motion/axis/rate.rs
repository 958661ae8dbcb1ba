//! How fast the chip's oscillator runs against the control tick.

/// How fast the chip's time runs against the bridge's: the powerSTEP01's
/// internal oscillator is a few % off 16 MHz, so a `Run` at speed `s` moves
/// it `ratio · s`. Without this a proportional correction leaves a following
/// error of `ratio − 1` times the speed times the correction period (3.6 full
/// steps at ±5 % in the random scenario) and a move passes its target by
/// several microsteps before it lands.
///
/// Estimated while streaming at a steady profile speed (cruising: a ramp
/// makes the chip move less than commanded) from what was commanded and
/// what the chip moved between position reads: over windows of at least
/// [`RATE_WINDOW`] microsteps while the chip follows (following error ≤
/// [`RATE_MAX_ERROR`], speed below its MAX_SPEED), `ratio = moved /
/// commanded` (clamped to ±10 %; the first window's estimate is taken as
/// it is — the only division, once per axis —, later windows correct it by a
/// division-free step); every `Run` speed is then divided by it (a multiply
/// by the Q16 reciprocal, kept by Newton steps).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct ClockRate {
    /// chip time / bridge time, Q16 (65 536: equal).
    pub(super) ratio: u32,
    /// 2³² / ratio.
    pub(super) inv: u32,
    /// SPEED of the last `Run` (signed, as sent): what the chip runs at.
    pub(super) running: i64,
    /// Sum of `running` over the planned ticks that count (wrapping): a
    /// window's command is the difference of two reads' values (each
    /// read's batch records it at its plan).
    pub(super) commanded: i64,
    /// `commanded` at the read that began the window, and its epoch.
    pub(super) base: i64,
    pub(super) base_epoch: u32,
    /// Counts the plans that ended a window (a tick that did not count):
    /// two reads bound a window only if no such plan came between them.
    pub(super) epoch: u32,
    /// Window sums: commanded (SPEED · ticks) and moved (microsteps).
    pub(super) cmd: i64,
    pub(super) moved: i64,
    /// The last position read came while streaming: a window may go on.
    pub(super) armed: bool,
    /// The profile kept its speed at the last tick: the chip ran at
    /// `running` the whole tick (while the profile ramps, the chip ramps
    /// toward each new speed with its ACC and moves less than commanded).
    pub(super) steady: bool,
    /// Windows taken so far (the first one replaces the default).
    pub(super) estimates: u32,
    /// Position reads in the current window.
    pub(super) reads: u32,
}

/// The clock-rate estimate's bounds, Q16 (±10 %).
pub(super) const RATIO_MIN: i64 = 58_982;
pub(super) const RATIO_MAX: i64 = 72_090;

/// Microsteps a window of the clock-rate estimate must cover.
pub const RATE_WINDOW: i64 = 1024;
/// Position reads a window must span after the first estimate (64 ticks).
pub const RATE_READS: u32 = 32;
/// A window ends when the following error exceeds this (microsteps): the
/// chip is not following the `Run` speeds then (still stopping, landing).
pub const RATE_MAX_ERROR: i64 = 64;

impl ClockRate {
    pub(super) const NEW: ClockRate = ClockRate {
        ratio: 1 << 16,
        inv: 1 << 16,
        running: 0,
        commanded: 0,
        base: 0,
        base_epoch: 0,
        epoch: 0,
        cmd: 0,
        moved: 0,
        armed: false,
        steady: false,
        estimates: 0,
        reads: 0,
    };

    /// The window ends at a read (the chip did something else than follow
    /// `Run` before it).
    pub(super) fn disarm(&mut self) {
        self.armed = false;
        self.reads = 0;
        self.cmd = 0;
        self.moved = 0;
    }

    /// The window ends at a plan: the tick before it does not count (and
    /// no read before it bounds a window with a read after it).
    pub(super) fn disarm_tick(&mut self) {
        self.disarm();
        self.epoch = self.epoch.wrapping_add(1);
        self.running = 0;
    }

    /// A position read while streaming: the chip moved `moved` microsteps
    /// since the last one; `commanded` and `epoch` are what the read's plan
    /// recorded.
    pub(super) fn take(
        &mut self,
        moved: i64,
        (commanded, epoch): (i64, u32),
        tick_us: u32,
        step_shift: u32,
    ) {
        if self.armed && epoch == self.base_epoch {
            // Both sums stay far inside i64: a tick commands at most 2²⁰
            // (SPEED) and moves at most a few hundred microsteps, and a
            // window ends at RATE_WINDOW microsteps moved (2⁴³ ticks of
            // the fastest Run before the command sum could wrap).
            let since = commanded.wrapping_sub(self.base);
            self.cmd = self.cmd.wrapping_add(since);
            self.moved = self.moved.wrapping_add(moved);
        }
        self.base = commanded;
        self.base_epoch = epoch;
        self.armed = true;
        self.reads = self.reads.saturating_add(1);
        // A window covers RATE_WINDOW microsteps; after the first estimate
        // also RATE_READS reads (a fast axis would update every tick).
        let short = self.moved.unsigned_abs() < RATE_WINDOW.unsigned_abs();
        if short || (self.estimates > 0 && self.reads < RATE_READS) {
            return;
        }
        self.reads = 0;
        let (cmd, moved) = (self.cmd, self.moved);
        self.cmd = 0;
        self.moved = 0;
        if cmd == 0 || (cmd < 0) != (moved < 0) {
            return;
        }
        // Expected microsteps at ratio 1: cmd · tick_us · 2^(S+2) / 2²⁸.
        let Some(e) = cmd
            .checked_mul(i64::from(tick_us.max(1)))
            .and_then(|x| x.checked_mul(1 << (step_shift.min(8) + 2)))
            // Rounded (a floor would bias every window by up to a microstep).
            .map(|x| (x + (1 << 27)) >> 28)
            .filter(|x| *x != 0)
        else {
            return;
        };
        if self.estimates == 0 {
            // The first window sets the ratio outright: one division per
            // axis, ever (later windows correct it without dividing).
            let Some(num) = moved.checked_mul(1 << 16) else {
                return;
            };
            self.ratio = (num / e).clamp(RATIO_MIN, RATIO_MAX) as u32;
            self.inv = ((1u64 << 32) / u64::from(self.ratio)) as u32;
        } else {
            // Later windows: ratio += (moved − predicted) / expected, the
            // division by `expected` replaced by a shift by its bit length
            // (2^(len−1) ≤ |e| < 2^len), which takes a quarter to half of the
            // step: a few windows converge, no window overshoots.
            let predicted = (e * i64::from(self.ratio) + (1 << 15)) >> 16;
            let len = 64 - e.unsigned_abs().leading_zeros();
            let step = moved.saturating_sub(predicted).saturating_mul(1 << 16) >> len;
            let step = if e < 0 { -step } else { step };
            self.ratio = (i64::from(self.ratio) + step).clamp(RATIO_MIN, RATIO_MAX) as u32;
            // 1/ratio by two Newton steps from the last one (it moved little).
            for _ in 0..2 {
                let r = u64::from(self.ratio);
                let inv = u64::from(self.inv);
                let corr = (2u64 << 16).saturating_sub((r * inv) >> 16);
                self.inv = ((inv * corr) >> 16) as u32;
            }
        }
        self.estimates = self.estimates.saturating_add(1);
    }

    /// A SPEED the chip runs at the bridge's rate, in its own time.
    pub(super) fn scale(&self, speed: u64) -> u64 {
        (speed * u64::from(self.inv)) >> 16
    }
}
