//! Set-up shared by the on-target tests: the app's `init` up to the point
//! each test needs, through the same `platform` and `board` functions.
#![allow(dead_code)] // each test binary uses part of it

/// A marker function for the armcount plugin (`cargo chain-cpu`,
/// `cargo ioext-cpu`): the benches call it at the edges of a counted
/// region, the plugin finds it by its symbol.
#[allow(unused_macros)] // only the armcount benches use it
macro_rules! marker {
    ($name:ident, $v:expr) => {
        #[inline(never)]
        #[no_mangle]
        pub extern "C" fn $name() {
            core::hint::black_box($v as u32);
        }
    };
}

use bridge_logic::bridge::ResetCause;
use firmware::drivers::clock::{self, Mono};
use firmware::pins::{self, Pins};
use firmware::platform;
use stm32f4xx_hal::gpio::GpioExt;
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::Rcc;

/// The target after the app's clock and pin set-up.
pub struct Target {
    pub rcc: Rcc,
    pub pins: Pins,
    pub sysclk_hz: u32,
    pub systick_hz: u32,
    pub reset_cause: ResetCause,
    pub usart2: pac::USART2,
    pub spi1: pac::SPI1,
    pub tim7: pac::TIM7,
    pub flash: pac::FLASH,
    pub iwdg: pac::IWDG,
    pub dbgmcu: pac::DBGMCU,
    pub tim2: pac::TIM2,
    pub usb_otg: pins::UsbOtg,
    pub spi2: pac::SPI2,
    pub tim1: pac::TIM1,
    pub dma1: pac::DMA1,
    pub dma2: pac::DMA2,
}

/// Clocks (platform), DWT cycle counter, SysTick monotonic, pins (board).
pub fn setup() -> Target {
    let Some(dp) = pac::Peripherals::take() else {
        defmt::panic!("device peripherals taken twice");
    };
    let Some(mut cp) = cortex_m::Peripherals::take() else {
        defmt::panic!("core peripherals taken twice");
    };
    let reset_cause = ResetCause::from_rcc_csr(platform::take_reset_flags(&dp.RCC));
    let mut rcc = platform::freeze_clocks(dp.RCC);
    let sysclk_hz = rcc.clocks.sysclk().raw();
    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();
    let systick_hz = platform::systick_hz(&rcc);
    Mono::start(cp.SYST, systick_hz - systick_hz % clock::MONO_HZ);
    let pins = pins::configure(
        dp.GPIOA.split(&mut rcc),
        dp.GPIOB.split(&mut rcc),
        dp.GPIOC.split(&mut rcc),
    );
    defmt::info!(
        "{=str}: SYSCLK {=u32} Hz, SysTick {=u32} Hz, reset cause {}",
        platform::NAME,
        sysclk_hz,
        systick_hz,
        reset_cause
    );
    Target {
        rcc,
        pins,
        sysclk_hz,
        systick_hz,
        reset_cause,
        usart2: dp.USART2,
        spi1: dp.SPI1,
        tim7: dp.TIM7,
        flash: dp.FLASH,
        iwdg: dp.IWDG,
        dbgmcu: dp.DBGMCU,
        tim2: dp.TIM2,
        usb_otg: (dp.OTG_FS_GLOBAL, dp.OTG_FS_DEVICE, dp.OTG_FS_PWRCLK),
        spi2: dp.SPI2,
        tim1: dp.TIM1,
        dma1: dp.DMA1,
        dma2: dp.DMA2,
    }
}

/// CPU cycles since `start` (DWT), wrapping.
pub fn cycles_since(start: u32) -> u32 {
    cortex_m::peripheral::DWT::cycle_count().wrapping_sub(start)
}

pub fn cycles_now() -> u32 {
    cortex_m::peripheral::DWT::cycle_count()
}

/// Busy-wait until `clock::now_us` has advanced `us`.
pub fn spin_us(us: u64) {
    let start = clock::now_us();
    while clock::now_us().saturating_sub(start) < us {}
}

/// The chain batch of a streaming control tick on `n` chips: every chip
/// reads ABS_POS back and gets a Run (5 windows of `n` bytes).
pub fn streaming_plan(n: usize) -> bridge_logic::powerstep::Plan {
    use bridge_logic::powerstep::{Batch, Command, Direction, Plan, Register};
    let mut batch = Batch::new(n);
    for d in 0..n {
        let _ = batch.push(d, Command::GetParam(Register::AbsPos));
        let _ = batch.push(d, Command::Run(Direction::Forward, 1_000 + 37 * d as u32));
    }
    match Plan::new(&batch) {
        Ok(plan) => plan,
        Err(e) => defmt::panic!("streaming plan: {}", e),
    }
}

/// The longest batch of 4-byte commands on `n` chips: three per chip
/// (12 windows of `n` bytes), different bytes in every window.
pub fn long_plan(n: usize) -> bridge_logic::powerstep::Plan {
    use bridge_logic::powerstep::{Batch, Command, Direction, Plan};
    let mut batch = Batch::new(n);
    for d in 0..n {
        let k = d as u32;
        let _ = batch.push(d, Command::Move(Direction::Forward, 0x1_2345 + k * 0x111));
        let _ = batch.push(d, Command::GoTo(0x2_3456 + 0x222 * d as i32));
        let _ = batch.push(d, Command::Run(Direction::Reverse, 0x3_4567 + k * 0x333));
    }
    match Plan::new(&batch) {
        Ok(plan) => plan,
        Err(e) => defmt::panic!("long plan: {}", e),
    }
}

/// The chain's one driver on the target's SPI1, TIM7 and chain pins, with
/// its `'static` buffers, as the app takes it (the app then puts it in
/// `platform`'s cell; the tests use it directly).
pub fn chain(mut t: Target) -> firmware::drivers::chain_spi::ChainSpi {
    use firmware::drivers::chain_spi::{chain_spi, ChainBuffers, ChainPeripherals};
    let p = t.pins;
    let Some(bufs) = cortex_m::singleton!(: ChainBuffers = ChainBuffers::new()) else {
        defmt::panic!("buffers taken twice");
    };
    let peripherals = ChainPeripherals {
        spi: t.spi1,
        tim: t.tim7,
        lines: p.chain,
    };
    chain_spi(peripherals, bufs, &mut t.rcc)
}

/// The I/O extension's board driver on the target's SPI2, TIM1, DMA1, DMA2
/// and extension pins, with its `'static` buffers, as the app takes it.
pub fn ioext_port(mut t: Target) -> firmware::drivers::ioext_spi::IoExtPort {
    use firmware::drivers::ioext_spi::{ioext_port, IoExtBuffers, IoExtPeripherals};
    let p = t.pins;
    let Some(bufs) = cortex_m::singleton!(: IoExtBuffers = IoExtBuffers::new()) else {
        defmt::panic!("buffers taken twice");
    };
    let peripherals = IoExtPeripherals {
        spi: t.spi2,
        tim: t.tim1,
        dma1: t.dma1,
        dma2: t.dma2,
        lines: p.ioext,
    };
    ioext_port(peripherals, bufs, &mut t.rcc)
}
