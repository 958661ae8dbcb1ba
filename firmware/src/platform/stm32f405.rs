//! The platform on the reference board (STM32F405RG, 8 MHz crystal): the
//! real peripherals behind the names the app uses (see `platform/mod.rs`
//! for the table of both platforms).

// cortex-m-rt's HardFault handler is an `unsafe fn` by contract.
#![allow(unsafe_code)]

use bridge_logic::bridge::WatchdogWindow;
use defmt_rtt as _;
use drivers_core::iwdg::{self, WindowError};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::{Config, Rcc, RccExt};
use stm32f4xx_hal::time::Hertz;
use stm32f4xx_hal::timer::{CounterHz, Event, Flag, TimerExt};
use stm32f4xx_hal::{ClearFlags, Listen};

use crate::drivers::chain_spi::{self, ChainBuffers, ChainCell, ChainPeripherals};
use crate::drivers::flash::StoreFlash;
use crate::drivers::ioext_spi::{self, IoExtBuffers, IoExtPeripherals, IoExtPort};
use crate::pins;

pub use crate::drivers::analog::Analog;
pub use crate::drivers::i2c_slave::I2cSlaveDriver;

/// Which platform this image runs on (logged at boot).
pub const NAME: &str = "board";

/// HSE crystal through the main PLL to 168 MHz (APB1 42 MHz, APB2 84 MHz)
/// and the 48 MHz PLL48CLK of USB OTG FS: M 4, N 168, P 2, Q 7 — the same
/// PLL the HAL picks for 168 MHz alone, so every other clock is unchanged
/// (`freeze` asserts the 48 MHz).
pub fn freeze_clocks(rcc: pac::RCC) -> Rcc {
    rcc.freeze(
        Config::hse(Hertz::from_raw(pins::HSE_HZ))
            .sysclk(Hertz::from_raw(pins::SYSCLK_HZ))
            .require_pll48clk(),
    )
}

/// The SysTick input clock: the processor clock (SYSCLK).
pub fn systick_hz(rcc: &Rcc) -> u32 {
    rcc.clocks.sysclk().raw()
}

/// RCC_CSR as the reset left it (its reset flags, for
/// `bridge_logic::bridge::ResetCause::from_rcc_csr`), then cleared (RMVF)
/// so the next reset reports only its own cause. Call it before
/// `freeze_clocks`.
pub fn take_reset_flags(rcc: &pac::RCC) -> u32 {
    let flags = rcc.csr().read().bits();
    rcc.csr().modify(|_, w| w.rmvf().set_bit());
    flags
}

/// The independent watchdog (`drivers_core::iwdg` on `pac::IWDG`) in the
/// window the bridge asks for (`Bridge::watchdog_window`): short (16.9 to
/// 47.1 ms over the LSI's spread) whenever an axis may move, long (4.4 to
/// 12.2 s) only around a settings save's flash erase.
pub struct Watchdog(drivers_core::iwdg::Watchdog<crate::drivers::iwdg::IwdgPeripheral>);

impl Watchdog {
    /// Start the IWDG in the long window (it cannot be stopped again),
    /// frozen while a debugger halts the core. Long because `init` has the
    /// chips' reset pulse and wake-up, chain detection and set-up, the
    /// settings load and the USB start ahead of it; `init` switches to the
    /// bridge's window (short) last, at most a tick period before the first
    /// control tick.
    pub fn start(iwdg: pac::IWDG, dbgmcu: &pac::DBGMCU) -> Watchdog {
        dbgmcu.apb1_fz().modify(|_, w| w.dbg_iwdg_stop().set_bit());
        let watchdog =
            iwdg::Watchdog::start(crate::drivers::iwdg::IwdgPeripheral(iwdg), iwdg::LONG);
        defmt::info!(
            "watchdog: long window {=u32} ms nominal ({=u64}..{=u64} ms), short {=u32} ms ({=u64}..{=u64} us) while anything may move",
            iwdg::LONG_MS,
            iwdg::LONG_MIN_US / 1000,
            iwdg::LONG_MAX_US.div_ceil(1000),
            iwdg::SHORT_MS,
            iwdg::SHORT_MIN_US,
            iwdg::SHORT_MAX_US
        );
        Watchdog(watchdog)
    }

    /// Reload the counter in the window in effect.
    pub fn feed(&mut self) {
        self.0.feed();
    }

    /// Feed in `window`: a plain feed while it is in effect, else a window
    /// change (up to 5 LSI cycles, 0.3 ms at 17 kHz), in effect once this
    /// returns `Ok`.
    pub fn feed_in(&mut self, window: WatchdogWindow) -> Result<(), WindowError> {
        self.0.feed_in(iwdg::Window::of(window))
    }
}

/// Why the control timer did not start.
pub type TimerError = stm32f4xx_hal::timer::Error;

/// TIM2 as the control-loop timer: its update interrupt is the control
/// tick (the app binds `TIM2`).
pub struct TickTimer(CounterHz<pins::ControlTimer>);

impl TickTimer {
    pub fn new(tim: pins::ControlTimer, rcc: &mut Rcc) -> TickTimer {
        TickTimer(tim.counter_hz(rcc))
    }

    /// Run at `hz` with the update interrupt on.
    pub fn start(&mut self, hz: u32) -> Result<(), TimerError> {
        self.0.start(Hertz::from_raw(hz))?;
        self.0.listen(Event::Update);
        Ok(())
    }

    /// Clear the update flag (first thing in the interrupt).
    pub fn acknowledge(&mut self) {
        self.0.clear_flags(Flag::Update);
    }
}

/// The chain's one driver: SPI1, DMA2 streams 0/3, TIM7 and CS — blocking
/// windows and the control tick's batches by DMA, CS gaps by TIM7
/// (`drivers::chain_spi`).
pub type ChainDriver = chain_spi::ChainSpi;

/// The bridge's chain bus: a handle on [`ChainDriver`] that asks it for
/// each blocking window (chain detection, recovery after a bus error).
pub type ChainLink = chain_spi::ChainLink<ChainDriver>;

/// Where the one driver lives (`drivers::chain_spi::ChainCell`).
static CHAIN: ChainCell<ChainDriver> = ChainCell::new();

/// Start SPI1 for the chain (mode 3, ≤ 4 MHz), TIM7 and DMA2 streams 0/3,
/// put their one driver where the control tick and the chain's interrupts
/// reach it ([`with_chain`]) and return the bridge's handle on it.
pub fn chain_driver(
    peripherals: ChainPeripherals,
    bufs: &'static mut ChainBuffers,
    rcc: &mut Rcc,
) -> ChainLink {
    CHAIN.install(chain_spi::chain_spi(peripherals, bufs, rcc))
}

/// Run `f` on the chain's one driver, interrupts masked (`None` before
/// [`chain_driver`]).
#[inline]
pub fn with_chain<R>(f: impl FnOnce(&mut ChainDriver) -> R) -> Option<R> {
    CHAIN.with(f)
}

/// The I/O extension's port: SPI2 / TIM1 with DMA1 / DMA2
/// (`drivers::ioext_spi`).
pub type IoExtDriver = IoExtPort;

/// Take the extension's peripherals (nothing is driven until the first
/// transfer; CS stays high).
pub fn ioext_driver(
    peripherals: IoExtPeripherals,
    bufs: &'static mut IoExtBuffers,
    rcc: &mut Rcc,
) -> IoExtDriver {
    ioext_spi::ioext_port(peripherals, bufs, rcc)
}

/// The settings store's flash: sectors 10 and 11.
pub type SettingsFlash = StoreFlash;

pub fn settings_flash(flash: pac::FLASH) -> SettingsFlash {
    StoreFlash::new(flash)
}

/// How far SysTick time may fall behind real time, in percent: not at all,
/// it counts SYSCLK cycles.
pub const SYSTICK_LAG_MAX_PERCENT: u64 = 0;

/// Run `f` and return how long it took in µs on a clock that is not
/// SysTick, for the on-target tests that check the monotonic's rate: the
/// DWT cycle counter at `sysclk_hz` (the caller has enabled it; `f` must
/// take less than one wrap, 25 s at 168 MHz).
pub fn measure_us(sysclk_hz: u32, f: impl FnOnce()) -> u64 {
    let start = cortex_m::peripheral::DWT::cycle_count();
    f();
    let cycles = cortex_m::peripheral::DWT::cycle_count().wrapping_sub(start);
    u64::from(cycles)
        .saturating_mul(1_000_000)
        .checked_div(u64::from(sysclk_hz))
        .unwrap_or(0)
}

/// HardFault: chips off, then wait for the watchdog's reset (within the
/// window in effect: ≤ 47.1 ms; seconds only in `init` and during a save).
/// Until then, and through the reset (the pin floats from reset until
/// `init` configures it), the board's pull-down on STBY keeps the chips in
/// reset.
#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    crate::failsafe::chips_off();
    loop {
        core::sync::atomic::compiler_fence(core::sync::atomic::Ordering::SeqCst);
    }
}

/// The PoStep60 USB HID device on OTG FS (`drivers::usb`).
pub type Usb = crate::drivers::usb::UsbPort;

/// Start USB (serial number from `uid`); None, and logged, if it was
/// refused. Needs the PLL48CLK of [`freeze_clocks`].
pub fn start_usb(
    otg: pins::UsbOtg,
    pins: (pins::UsbDm, pins::UsbDp),
    rcc: &Rcc,
    uid: [u32; 3],
) -> Option<Usb> {
    let usb = stm32f4xx_hal::otg_fs::USB::new(otg, pins, &rcc.clocks);
    match Usb::start(usb, uid) {
        Ok(port) => {
            defmt::info!("USB: OTG FS, PoStep60 HID, waiting for a host");
            Some(port)
        }
        Err(e) => {
            defmt::error!("USB: not started ({})", e);
            None
        }
    }
}

/// The MCU's 96-bit unique id (0x1FFF_7A10).
pub fn unique_id() -> [u32; 3] {
    crate::drivers::mcu::unique_id()
}

/// Jump into ST's ROM DFU bootloader (`drivers::mcu`): never returns. Call
/// it first thing in `init`, before clocks and peripherals are set up.
pub fn rom_bootloader(rcc: &pac::RCC, syscfg: &pac::SYSCFG) -> ! {
    crate::drivers::mcu::jump_to_rom_bootloader(rcc, syscfg)
}

/// What a streaming control tick of `chips` needs on the board, in a row
/// and overlapped: the computation as measured (`rate::compute_ns`) and
/// the batch as the installed chain driver times it (its SCK, TIM7 gap and
/// set-up; the board's nominal timing, `rate::BOARD_BUS`, before it is
/// installed).
pub fn tick_need(chips: usize) -> bridge_logic::rate::Need {
    let bus = CHAIN
        .with(|d| d.timing())
        .unwrap_or(bridge_logic::rate::BOARD_BUS);
    bridge_logic::rate::need_on(chips, bus)
}

/// The idle loop's wait: a `nop` (no `wfi`, which stops the debug clock on
/// some probes and gains nothing while a 1 kHz tick keeps waking the core).
pub fn idle_wait() {
    cortex_m::asm::nop();
}

/// Start the DWT cycle counter that [`Stopwatch`] reads.
pub fn enable_stopwatch(dcb: &mut cortex_m::peripheral::DCB, dwt: &mut cortex_m::peripheral::DWT) {
    dcb.enable_trace();
    dwt.enable_cycle_counter();
}

/// Times a stretch of code (the control tick) on the DWT cycle counter at
/// SYSCLK: 6 ns resolution, spans below 25 s.
pub struct Stopwatch(u32);

impl Stopwatch {
    pub fn start() -> Stopwatch {
        Stopwatch(cortex_m::peripheral::DWT::cycle_count())
    }

    /// µs since [`Stopwatch::start`].
    pub fn elapsed_us(&self) -> u32 {
        cortex_m::peripheral::DWT::cycle_count().wrapping_sub(self.0)
            / (pins::SYSCLK_HZ / 1_000_000)
    }
}
