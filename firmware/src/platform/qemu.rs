//! The platform under QEMU 7.2's `netduinoplus2` (feature `qemu`): stand-ins
//! with the board's names for what QEMU does not model (see `platform/mod.rs`
//! for the table of both platforms). Everything else — the RTIC app, the
//! bridge, the Modbus server and its USART2/RS-485 driver, the SysTick
//! monotonic, the panic handler — is the board's code.
//!
//! * **Control tick**: QEMU's TIM2 counts at a fixed 1 GHz and ignores the
//!   prescaler (with PSC = 15 and ARR = 999, the HAL's 1 kHz at HSI, it
//!   fires every microsecond). With PSC = 0 it raises its update interrupt
//!   ARR ns after it was last armed, and QEMU re-arms it from the moment it
//!   serves it, so every late service would shift every later tick (1.01 ms
//!   per tick on an idle host; 1.15–1.8 ms mean measured on a busy 2-core
//!   one: a rate the image did not keep while the chips live on the host's
//!   time). [`TickTimer::acknowledge`] writes the gap to the next deadline
//!   into ARR: the ticks keep their phase on QEMU's virtual clock as the
//!   board's keep theirs on the crystal, and one served more than a period
//!   late loses the deadlines it missed, as on the board. The app's TIM2
//!   task runs unchanged. The idle loop waits with `wfi` ([`idle_wait`]),
//!   so QEMU does not spend a host core on an emulated spin loop, and the
//!   tick's cost under QEMU is [`tick_need`] (measured), which the rate
//!   is fitted to.
//! * **Chain**: [`ChainDriver`] holds [`AXES`] simulated powerSTEP01s and
//!   lets them live through the time of QEMU's virtual clock ([`HostClock`],
//!   TIM5's counter: the host's time) that passed since the last CS window,
//!   as real chips run on real time whatever the control loop does: a late
//!   or lost tick is one they run through at their last `Run` speed, as on a
//!   board. (They lived on the SysTick monotonic before, which loses time at
//!   every 100 µs wrap, 10–30 % behind the host: chips whose ramps, in the
//!   bridge's time, were 0.7–1.2 × the profile's instead of 1.5 ×, and could
//!   not follow its braking.) The bridge's clock counts ticks, so the two
//!   drift apart by what the ticks lose, as a board's MCU and chip
//!   oscillators do by theirs.
//!   It has the board's one chain driver's API — blocking windows, and
//!   batches that it clocks through those chips at once in `start` and
//!   hands over at the next `poll` — and lives in the same kind of cell,
//!   behind the same [`ChainLink`], so the app's pipelined control tick
//!   runs unchanged (QEMU 7.2 has no DMA controller and no TIM7: the
//!   board's DMA path is only built here).
//! * **Settings flash**: [`SettingsFlash`] (`qemu_flash.rs`) keeps the
//!   store's two erase units in RAM, loaded at boot from a host file and
//!   written through by semihosting, so settings saved under QEMU survive a
//!   restart.
//! * **I/O extension**: [`IoExtDriver`] runs every transfer through the
//!   simulated 74HC165/74HC595 chain of `stepbridge-sim` ([`IOEXT_165`] '165s,
//!   [`IOEXT_595`] '595) at once, instead of SPI2/TIM1/DMA (QEMU 7.2's
//!   STM32F405 has no DMA controller and no TIM1). Its inputs are buttons
//!   with pull-ups, all open at boot; `press N` / `release N` on the test
//!   console (below) close and open them (N = receive bit 0..15 in wire
//!   order: press closes the contact, the bit reads 0), logged as
//!   `ioext console: …`.
//! * **Test console and fault injection** (`qemu_console.rs`): USART1 (QEMU's first `-serial`,
//!   `QEMU_CONSOLE` in `cargo xtask qemu-run`) takes the lines of
//!   `stepbridge_sim::ConsoleLine`, read at every control tick ([`TickTimer::acknowledge`],
//!   the tick's first step) and logged (`sim console: …`): the buttons
//!   above, and faults of the simulated hardware for the bring-up checks
//!   (`stepctl doctor`): `chip K dead [HH]` / `revive` / `reset` / `uvlo` /
//!   `ocd` (handed to [`ChainDriver`], applied before its next window),
//!   `supply MV` / `supply off` (what [`Analog`] reports), `jumper on` /
//!   `off` (a MOSI → MISO jumper on the I/O extension's port). The same
//!   lines in the host file `<settings flash file>.boot`, if there is one,
//!   are applied at boot before the chain is detected ([`chain_driver`]):
//!   a chip dead at power-up (`chip 1 dead`) leaves a chain the detection
//!   cannot measure. (Not an MCU reset on the console: after QEMU 7.2's
//!   system reset its TIM2 model adds the time of the reset to every
//!   period, so the control tick would crawl.)
//! * **Faults**: a HardFault (also the end of the panic handler, after its
//!   message) exits QEMU with status 1, so a crash fails a run instead of
//!   hanging it.

// cortex-m-rt's HardFault handler is an `unsafe fn` by contract.
#![allow(unsafe_code)]

use bridge_logic::bridge::{BatchState, WatchdogWindow};
use bridge_logic::ioext::{wire, Action, TransferPlan, WireBits};
use bridge_logic::postep60::analog::AnalogSample;
use bridge_logic::powerstep::chain::{clock_windows, Frames, Plan};
use bridge_logic::powerstep::ChainBus;
use bridge_logic::transport::i2c::{I2cSlave, I2cTarget};
use core::sync::atomic::Ordering;
use defmt_semihosting as _;
use drivers_core::iwdg::WindowError;
use stepbridge_sim::{ConsoleLine, HomeCam, Lines, ShiftChain, SimChain};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::{Config, Enable, Rcc, RccExt, Reset};

use crate::drivers::chain_spi::{ChainBuffers, ChainCell, ChainPeripherals, ChainSpiError};
use crate::drivers::ioext_spi::{IoExtBuffers, IoExtError, IoExtPeripherals, Started};
use crate::drivers::usb::Link;
use crate::pins::{self, HostI2c, HostI2cScl, HostI2cSda, SenseAdc, SupplySense};
use bridge_logic::transport::usb::REPORT_LEN;
use usb_device::device::UsbDeviceState;

// The settings flash's host-file stand-in.
#[path = "qemu_flash.rs"]
mod flash;
pub use flash::{settings_flash, SettingsFlash, SettingsFlashError};

// The test console and the fault injection it drives.
#[path = "qemu_console.rs"]
mod console;
use console::{take_chip_faults, Console, INPUTS_CLOSED, JUMPER, SUPPLY_MV, SUPPLY_OWN};

/// Which platform this image runs on (logged at boot).
pub const NAME: &str = "QEMU netduinoplus2";

/// Simulated powerSTEP01s on the chain.
pub const AXES: usize = 4;
/// The rate QEMU's SysTick counts at, whatever the clock tree says.
pub const SYSTICK_HZ: u32 = 168_000_000;
/// The rate QEMU 7.2's STM32 timer model counts at (its prescaler is not
/// applied to the interrupt period).
pub const TIMER_HZ: u32 = 1_000_000_000;

/// HSI (16 MHz), no PLL: QEMU's RCC ready bits read 0, so waiting for the
/// HSE or the PLL hangs.
pub fn freeze_clocks(rcc: pac::RCC) -> Rcc {
    rcc.freeze(Config::hsi())
}

/// [`SYSTICK_HZ`], whatever `rcc` says.
pub fn systick_hz(_rcc: &Rcc) -> u32 {
    SYSTICK_HZ
}

/// QEMU models no RCC_CSR: no reset flag (unknown cause).
pub fn take_reset_flags(_rcc: &pac::RCC) -> u32 {
    0
}

/// Watchdog stand-in: QEMU does not model the IWDG, so nothing is started,
/// feeding does nothing and every window is "in effect" at once.
pub struct Watchdog;

impl Watchdog {
    pub fn start(_iwdg: pac::IWDG, _dbgmcu: &pac::DBGMCU) -> Watchdog {
        defmt::info!("watchdog: not modelled by QEMU, not started");
        Watchdog
    }

    pub fn feed(&mut self) {}

    pub fn feed_in(&mut self, _window: WatchdogWindow) -> Result<(), WindowError> {
        Ok(())
    }
}

/// Why the control timer did not start.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum TimerError {
    /// 0 Hz, or faster than the timer model counts.
    WrongRate,
}

/// TIM2 as the control-loop timer, programmed for QEMU's timer model
/// (module docs): its update interrupt is the control tick, as on the
/// board, and on the board's phase: every deadline is a whole number of
/// periods after the start on QEMU's virtual clock.
pub struct TickTimer {
    tim: pins::ControlTimer,
    /// The period, ns of QEMU's virtual clock (TIM2's CNT at 1 GHz).
    period: u32,
    /// CNT at the next deadline.
    next: u32,
    /// The test console, read at every tick.
    console: Console,
}

/// A deadline closer than this (ns) when the tick is served is lost
/// instead of firing at once after it (its interrupt would have come
/// while the flag was still set).
const TICK_MIN_GAP_NS: u32 = 20_000;

impl TickTimer {
    pub fn new(tim: pins::ControlTimer, rcc: &mut Rcc) -> TickTimer {
        pins::ControlTimer::enable(rcc);
        pins::ControlTimer::reset(rcc);
        TickTimer {
            tim,
            period: 0,
            next: 0,
            console: Console::start(rcc),
        }
    }

    /// Interrupt every `1 / hz` s.
    pub fn start(&mut self, hz: u32) -> Result<(), TimerError> {
        let period = TIMER_HZ
            .checked_div(hz)
            .filter(|&p| p > TICK_MIN_GAP_NS)
            .ok_or(TimerError::WrongRate)?;
        let tim = &self.tim;
        tim.psc().write(|w| w.psc().set(0));
        self.next = tim.cnt().read().bits().wrapping_add(period);
        self.period = period;
        tim.arr().write(|w| w.arr().set(period.saturating_sub(1)));
        tim.dier().write(|w| w.uie().set_bit());
        tim.cr1().write(|w| w.cen().set_bit());
        Ok(())
    }

    /// Clear the update flag (first thing in the interrupt) and arm the
    /// next deadline. QEMU 7.2's model re-arms the timer a period after the
    /// moment it serves it, so every late service would shift every later
    /// tick (1 % on an idle host, up to 40 % measured on a busy 2-core one:
    /// a rate the image cannot keep, while the chips live on the host's
    /// time). Writing ARR arms it `ARR` ns after the write, so the gap to
    /// the next deadline goes there: ticks stay on their phase, and a
    /// tick served more than a period late loses the deadlines it missed,
    /// as a board's timer does (one pending update flag).
    ///
    /// Then the test console's new lines (module docs).
    pub fn acknowledge(&mut self) {
        self.arm_next();
        self.console.poll();
    }

    fn arm_next(&mut self) {
        let tim = &self.tim;
        tim.sr().write(|w| w.uif().clear_bit());
        if self.period == 0 {
            return;
        }
        let now = tim.cnt().read().bits();
        // How far past the deadline, in [0, 2³¹) (before it: an early
        // interrupt, the deadline stands).
        let late = now.wrapping_sub(self.next);
        if late < 1 << 31 {
            let missed = late.checked_div(self.period).unwrap_or(0);
            self.next = self
                .next
                .wrapping_add(missed.wrapping_add(1).wrapping_mul(self.period));
        }
        let now = tim.cnt().read().bits();
        let mut gap = self.next.wrapping_sub(now);
        if gap < TICK_MIN_GAP_NS || gap > self.period {
            // Too close to arm (or the clock jumped): the next one.
            self.next = now.wrapping_add(self.period);
            gap = self.period;
        }
        tim.arr().write(|w| w.arr().set(gap));
    }
}

/// QEMU's virtual clock, ns, 32 bits (wraps every 4.29 s): TIM5's counter.
/// QEMU 7.2's STM32 timer model computes CNT from its virtual clock at
/// 1 GHz on every read (PSC = 0): without `-icount` that is the host's
/// time. TIM5 is not used on the board; [`HostClock::start`] starts it.
fn virtual_ns32() -> u32 {
    // SAFETY: a read of TIM5's counter, which has no side effect; TIM5 is
    // otherwise only written once, by `HostClock::start`.
    unsafe { pac::TIM5::steal() }.cnt().read().bits()
}

/// QEMU's virtual clock (the host's time) in ns, unwrapped from
/// [`virtual_ns32`] against the previous read: read at least every 4.29 s
/// (every control tick reads it). The simulated chips live on it, as a
/// board's chips live on real time.
pub struct HostClock {
    raw: u32,
    ns: u64,
}

impl HostClock {
    fn start(rcc: &mut Rcc) -> HostClock {
        pac::TIM5::enable(rcc);
        // SAFETY: nothing else in the firmware uses TIM5 (the app never
        // takes it out of `pac::Peripherals`): this is its only set-up.
        let tim = unsafe { pac::TIM5::steal() };
        tim.psc().write(|w| w.psc().set(0));
        tim.cr1().write(|w| w.cen().set_bit());
        HostClock {
            raw: virtual_ns32(),
            ns: 0,
        }
    }

    /// ns since [`HostClock::start`].
    pub fn now_ns(&mut self) -> u64 {
        let raw = virtual_ns32();
        self.ns = self
            .ns
            .saturating_add(u64::from(raw.wrapping_sub(self.raw)));
        self.raw = raw;
        self.ns
    }
}

/// [`AXES`] simulated chips that live on QEMU's virtual clock, the host's
/// time (module docs).
struct Chips {
    chain: SimChain,
    clock: HostClock,
    /// `clock` at the last window, ns.
    last_ns: u64,
}

impl ChainBus for Chips {
    type Error = ChainSpiError;

    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ChainSpiError> {
        take_chip_faults(&mut self.chain);
        let now = self.clock.now_ns();
        let elapsed_ns = now.saturating_sub(self.last_ns);
        self.last_ns = now;
        self.chain.advance(elapsed_ns);
        self.chain.transfer(tx, rx);
        Ok(())
    }
}

/// The chain's one driver under QEMU: the board driver's API
/// (`drivers::chain_spi::ChainSpi`: blocking windows, batches), every
/// window clocked through the simulated chips, a batch's at `start`
/// (module docs).
pub struct ChainDriver {
    chips: Chips,
    bufs: &'static mut ChainBuffers,
    /// A batch clocked and not yet handed over: its windows and chips.
    done: Option<(usize, usize)>,
}

impl ChainBus for ChainDriver {
    /// The board's error type; the simulated chips never fail.
    type Error = ChainSpiError;

    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ChainSpiError> {
        self.chips.window(tx, rx)
    }
}

impl ChainDriver {
    /// The simulated chips.
    pub fn chain(&self) -> &SimChain {
        &self.chips.chain
    }

    /// Clock the plan's windows through the simulated chips now; the next
    /// `poll` hands them over.
    pub fn start(&mut self, plan: &Plan, _now_us: u64) -> Result<(), ChainSpiError> {
        if self.done.is_some() {
            return Err(ChainSpiError::Busy);
        }
        let (windows, n) = (plan.windows(), plan.devices());
        clock_windows(&mut self.chips, plan, n, self.bufs.rx_mut())?;
        self.done = Some((windows, n));
        Ok(())
    }

    /// The batch clocked at `start` (never running: it ended there).
    pub fn poll<'a>(&mut self, _now_us: u64, rx: &'a mut Frames) -> BatchState<'a, ChainSpiError> {
        let Some((windows, n)) = self.done.take() else {
            return BatchState::Idle;
        };
        for (dst, src) in rx.iter_mut().zip(self.bufs.rx_mut().iter()).take(windows) {
            if let (Some(d), Some(s)) = (dst.get_mut(..n), src.get(..n)) {
                d.copy_from_slice(s);
            }
        }
        BatchState::Done(Ok(rx))
    }

    /// No DMA interrupt ever fires under QEMU.
    pub fn on_dma(&mut self) {}

    /// No TIM7 interrupt ever fires under QEMU.
    pub fn on_timer(&mut self) {}

    /// Never: a batch ends in `start`.
    pub fn is_running(&self) -> bool {
        false
    }
}

/// The bridge's chain bus: a handle on [`ChainDriver`] (as on the board).
pub type ChainLink = crate::drivers::chain_spi::ChainLink<ChainDriver>;

/// Where the one driver lives (`drivers::chain_spi::ChainCell`).
static CHAIN: ChainCell<ChainDriver> = ChainCell::new();

/// Run `f` on the chain's one driver, interrupts masked (`None` before
/// [`chain_driver`]).
#[inline]
pub fn with_chain<R>(f: impl FnOnce(&mut ChainDriver) -> R) -> Option<R> {
    CHAIN.with(f)
}

/// The simulated chain instead of SPI1, TIM7 and DMA2 (which, and whose
/// pins, stay as `pins::configure` left them), put where the control tick
/// reaches it ([`with_chain`]); returns the bridge's handle. Start the
/// monotonic first.
pub fn chain_driver(
    _peripherals: ChainPeripherals,
    bufs: &'static mut ChainBuffers,
    rcc: &mut Rcc,
) -> ChainLink {
    let mut chain = SimChain::new(AXES);
    // Faults present at power-up: the boot file's console lines.
    flash::boot_lines(|line| {
        console::apply(ConsoleLine::parse(line, IOEXT_165 * 8, AXES), line.len())
    });
    take_chip_faults(&mut chain);
    // The last axis has a home switch: a cam on its shaft presses SW below
    // HOME_CAM_EDGE microsteps (the end-to-end test homes it over Modbus).
    if let Some(chip) = chain.device_mut(AXES - 1) {
        chip.set_home_cam(Some(HomeCam {
            edge: HOME_CAM_EDGE,
            nc: false,
        }));
    }
    let mut clock = HostClock::start(rcc);
    let last_ns = clock.now_ns();
    CHAIN.install(ChainDriver {
        chips: Chips {
            chain,
            clock,
            last_ns,
        },
        bufs,
        done: None,
    })
}

/// Where the last simulated axis's home switch closes, microsteps (1/128:
/// 25 full steps below the power-up position).
pub const HOME_CAM_EDGE: i64 = -3_200;

/// 74HC165s (16 inputs) on the simulated I/O extension port.
pub const IOEXT_165: usize = 2;
/// 74HC595s (8 lamps) on the simulated I/O extension port.
pub const IOEXT_595: usize = 1;
/// The I/O extension's port under QEMU: the simulated shift registers,
/// whose buttons the test console presses (module docs).
pub struct IoExtDriver {
    chain: ShiftChain,
    /// The console's closed inputs as last applied.
    closed: u32,
}

/// The simulated port instead of SPI2/TIM1/DMA (which, and whose pins,
/// stay as `pins::configure` left them).
pub fn ioext_driver(
    _peripherals: IoExtPeripherals,
    _bufs: &'static mut IoExtBuffers,
    _rcc: &mut Rcc,
) -> IoExtDriver {
    let mut chain = ShiftChain::new(IOEXT_165, IOEXT_595);
    // Pull-ups, every contact open.
    for i in 0..IOEXT_165 * 8 {
        chain.set_rx_bit(i, true);
    }
    IoExtDriver { chain, closed: 0 }
}

impl IoExtDriver {
    /// Run the action on the simulated chain: a transfer ends at once.
    pub fn run(&mut self, action: &Action) -> Started {
        let closed = INPUTS_CLOSED.load(Ordering::Relaxed);
        if closed != self.closed {
            for i in 0..IOEXT_165 * 8 {
                if (closed ^ self.closed) & 1 << i != 0 {
                    self.chain.set_rx_bit(i, closed & 1 << i == 0);
                }
            }
            self.closed = closed;
        }
        match action {
            // MISO jumpered to MOSI: what goes out comes back.
            Action::Transfer(plan) if JUMPER.load(Ordering::Relaxed) => {
                self.transfer(plan);
                Started::Ended(Ok(plan.tx))
            }
            Action::Transfer(plan) => Started::Ended(Ok(self.transfer(plan))),
            Action::Disable => Started::Released,
        }
    }

    /// Clock `plan`'s wire through the simulated chips, half period by half
    /// period (they take line levels): the bits the master samples.
    fn transfer(&mut self, plan: &TransferPlan) -> WireBits {
        let halves = wire(plan).map(|h| (Lines::new(h.cs, h.sck, h.mosi), h.sample));
        WireBits::from_words(self.chain.clock_transfer(halves))
    }

    /// No DMA interrupt ever fires under QEMU.
    pub fn on_interrupt(&mut self) -> Option<Result<WireBits, IoExtError>> {
        None
    }

    /// Nothing is ever left running.
    pub fn abort(&mut self) -> Option<Result<WireBits, IoExtError>> {
        None
    }

    /// The simulated chips (for tests).
    pub fn chain(&self) -> &ShiftChain {
        &self.chain
    }
}

/// ADC1 stand-in: constant samples of a 24 V supply and a 25 °C die (at
/// VDDA = 3.3 V, with the reference board's ÷20 divider), or the supply the
/// test console set (`supply MV`). The ADC and its pin stay untouched.
pub struct Analog;

impl Analog {
    pub fn new(_adc: SenseAdc, _pin: SupplySense, _rcc: &mut Rcc) -> Analog {
        Analog
    }

    pub fn sample(&mut self) -> AnalogSample {
        let mut s = AnalogSample::NOMINAL_24V_25C;
        let mv = SUPPLY_MV.load(Ordering::Relaxed);
        if mv != SUPPLY_OWN {
            s.supply = supply_counts(mv, s.vrefint);
        }
        s
    }
}

/// The ADC counts of a motor supply of `mv` behind the ÷20 divider, at the
/// VDDA that `vrefint` counts of VREFINT (1.21 V) mean: pin µV · vrefint /
/// 1.21 V, rounded, at most full scale.
// u32 and u16 inputs widened to u64: no overflow.
#[allow(clippy::arithmetic_side_effects)]
fn supply_counts(mv: u32, vrefint: u16) -> u16 {
    let pin_uv = u64::from(mv) * 1000 / 20;
    let counts = (pin_uv * u64::from(vrefint) + 605_000) / 1_210_000;
    counts.min(4095) as u16
}

/// I2C1 stand-in: I2C1 is never started (QEMU's I2C transfers hang), so its
/// interrupts never fire; it takes the address changes the Modbus server
/// hands on.
pub struct I2cSlaveDriver;

impl I2cSlaveDriver {
    pub fn new(
        _i2c: HostI2c,
        _pins: (HostI2cScl, HostI2cSda),
        _primary: u8,
        _secondary: Option<u8>,
        _rcc: &mut Rcc,
    ) -> I2cSlaveDriver {
        I2cSlaveDriver
    }

    pub fn set_addresses(&mut self, _primary: u8, _secondary: Option<u8>) {}

    pub fn on_event(&mut self, _slave: &mut I2cSlave, _target: &mut impl I2cTarget) {}

    pub fn on_error(&mut self, _slave: &mut I2cSlave, _target: &mut impl I2cTarget) {}
}

/// How far SysTick time may fall behind real time, in percent. QEMU counts
/// 168 MHz of its own time, but re-arms the SysTick at each wrap (every
/// 100 µs here) from the moment it serves it, so every period is late by
/// the host's latency: measured 10-30 % behind the host clock on a 2-core
/// machine, and 54 % with two other builds running on it (its TIM2 model,
/// re-armed every 1 ms, lags ~1 %). The monotonic, Modbus timing included,
/// runs that much slow under QEMU. The bound is loose on purpose: what the
/// test must catch is a wrong SysTick rate, which is off by 10x (a
/// prescaler) or more, never by 3x.
pub const SYSTICK_LAG_MAX_PERCENT: u64 = 200;

/// Run `f` and return how long it took in µs on a clock that is not
/// SysTick, for the on-target tests that check the monotonic's rate: the
/// host's, through semihosting (SYS_CLOCK, 10 ms resolution; QEMU's DWT
/// cycle counter reads 0). 0 if the host does not answer.
pub fn measure_us(_sysclk_hz: u32, f: impl FnOnce()) -> u64 {
    let centiseconds = || semihosting::sys::arm_compat::sys_clock().unwrap_or(0) as u64;
    let start = centiseconds();
    f();
    centiseconds().saturating_sub(start).saturating_mul(10_000)
}

/// Any HardFault (including the panic handler's `udf` after its message)
/// ends QEMU with exit status 1, so a crash fails a run instead of hanging.
#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    // Through semihosting's stderr, not defmt: the fault may have hit inside
    // a defmt frame on stdout.
    semihosting::eprintln!("stepbridge: HardFault, exiting QEMU");
    semihosting::process::exit(1)
}

/// USB stand-in: QEMU 7.2 maps OTG FS as an unimplemented device and the
/// allocator's core reset would wait for ever, so USB is never started and
/// no `Usb` exists (the app's USB task returns at once when pended).
pub enum Usb {}

impl Usb {
    pub fn poll(&mut self) -> Link {
        match *self {}
    }

    pub fn read_report(&mut self, _buf: &mut [u8; REPORT_LEN]) -> Option<usize> {
        match *self {}
    }

    pub fn write_report(&mut self, _report: &[u8; REPORT_LEN]) -> bool {
        match *self {}
    }

    pub fn state(&self) -> UsbDeviceState {
        match *self {}
    }
}

/// Never starts USB (see [`Usb`]); says so in the boot log.
pub fn start_usb(
    _otg: pins::UsbOtg,
    _pins: (pins::UsbDm, pins::UsbDp),
    _rcc: &Rcc,
    _uid: [u32; 3],
) -> Option<Usb> {
    defmt::info!("USB: not modelled by QEMU, not started");
    None
}

/// The unique id QEMU's image uses: reading 0x1FFF_7A10 HardFaults there.
pub const UNIQUE_ID: [u32; 3] = [0x554D_4551, 0x0000_0000, 0x0000_0001];

/// [`UNIQUE_ID`], a fixed stand-in (logged).
pub fn unique_id() -> [u32; 3] {
    let [a, b, c] = UNIQUE_ID;
    defmt::info!(
        "unique id: QEMU has none, using {=u32:08x}-{=u32:08x}-{=u32:08x}",
        a,
        b,
        c
    );
    UNIQUE_ID
}

/// QEMU has no system memory and no ROM bootloader: logs and returns, and
/// the image starts normally.
pub fn rom_bootloader(_rcc: &pac::RCC, _syscfg: &pac::SYSCFG) {
    defmt::warn!("reset handoff: ROM DFU bootloader requested, QEMU has none: starting normally");
}

/// What a streaming control tick costs under QEMU, ns: fixed, and per
/// simulated chip (clocking its windows through the powerSTEP01 model is
/// most of it). Measured with [`Stopwatch`] on a shared 2-core host, 4
/// axes streaming: median 60–70 µs, 90th percentile 150–180 µs, 99th
/// 530–630 µs (the host preempting QEMU); the 90th is taken. So 1 kHz keeps
/// 80 % of the period free and a 5 kHz build runs at 2.5 kHz.
pub const TICK_NS_FIXED: u64 = 20_000;
pub const TICK_NS_PER_CHIP: u64 = 45_000;

/// [`TICK_NS_FIXED`] + [`TICK_NS_PER_CHIP`] per chip (the board's is
/// `rate::need`, SPI bytes); overlapped no shorter: the simulated chips
/// are clocked on the CPU as the batch starts.
pub fn tick_need(chips: usize) -> bridge_logic::rate::Need {
    bridge_logic::rate::Need::serial(
        TICK_NS_PER_CHIP
            .saturating_mul(chips as u64)
            .saturating_add(TICK_NS_FIXED),
    )
}

/// The idle loop's wait: `wfi`. QEMU's CPU then sleeps until the next
/// interrupt instead of emulating a spin loop at 100 % of a host core,
/// which on a busy host delays QEMU's own timer thread and with it every
/// tick (measured on a shared 2-core host, the same hour, each tick re-armed
/// from its service: mean period 1.15–1.8 ms spinning, 1.03–1.45 ms with
/// `wfi`).
pub fn idle_wait() {
    cortex_m::asm::wfi();
}

/// Nothing to start: [`Stopwatch`] uses QEMU's virtual clock (QEMU's DWT
/// cycle counter reads 0).
pub fn enable_stopwatch(
    _dcb: &mut cortex_m::peripheral::DCB,
    _dwt: &mut cortex_m::peripheral::DWT,
) {
}

/// Times a stretch of code (the control tick) on QEMU's virtual clock
/// ([`virtual_ns32`], the host's time the simulated chips live on; QEMU's
/// DWT cycle counter reads 0, and the monotonic loses time at every
/// SysTick wrap): spans below 4.29 s.
pub struct Stopwatch(u32);

impl Stopwatch {
    pub fn start() -> Stopwatch {
        Stopwatch(virtual_ns32())
    }

    /// µs since [`Stopwatch::start`].
    pub fn elapsed_us(&self) -> u32 {
        virtual_ns32().wrapping_sub(self.0) / 1000
    }
}
