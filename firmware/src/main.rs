//! stepbridge firmware: the RTIC 2 application for the STM32F405.
//!
//! Thin glue only. Pins and peripherals come from [`board`], the chain SPI
//! from [`chain_spi`]; every decision about what goes on the chain belongs to
//! the logic crate (`bridge_logic`). This file wires them to interrupts:
//!
//! * `init`: clocks, pins, chain reset pulse, chain detection, first STATUS
//!   read, then the control timer.
//! * `control_tick` (TIM2 update, 1 kHz, highest logic priority): one chain
//!   batch per tick; for now a STATUS poll.
//! * `idle`: spins (no `wfi`, which stops the debug clock on some probes and
//!   gains nothing while a 1 kHz tick keeps waking the core).
//!
//! The firmware is built only for `thumbv7em-none-eabihf` (`cargo fw`). On
//! any other target this file compiles to an empty `main`, so a host-side
//! `cargo check --workspace` still works.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]
#![deny(unsafe_code)]

#[cfg(target_os = "none")]
mod board;
#[cfg(target_os = "none")]
mod chain_spi;

#[cfg(target_os = "none")]
use defmt_rtt as _;
#[cfg(target_os = "none")]
use panic_probe as _;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("stepbridge is firmware: build it with `cargo fw`");
}

// Dispatchers: two unused interrupts, for the lower-priority bus-handler
// tasks of later issues (none yet).
#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4xx_hal::pac, dispatchers = [UART4, UART5])]
mod app {
    use bridge_logic::powerstep::Chain;
    use defmt::{debug, error, info, warn};
    use stm32f4xx_hal::gpio::GpioExt;
    use stm32f4xx_hal::rcc::{Config, RccExt};
    use stm32f4xx_hal::time::Hertz;
    use stm32f4xx_hal::timer::{CounterHz, Event, Flag, TimerExt};
    use stm32f4xx_hal::{ClearFlags, Listen};

    use crate::board;
    use crate::chain_spi::ChainSpiBus;

    /// Control-loop rate.
    const TICK_HZ: u32 = 1_000;
    /// STBY/RESET low time at power-up (datasheet minimum is well below).
    const RESET_PULSE_MS: u32 = 1;
    /// Wait after releasing STBY/RESET before the first SPI byte.
    const WAKE_UP_MS: u32 = 20;
    /// The status LED toggles every this many ticks: a 1 Hz heartbeat shows
    /// the control loop is running.
    const HEARTBEAT_TICKS: u32 = TICK_HZ / 2;

    #[shared]
    struct Shared {}

    #[local]
    struct Local {
        /// The powerSTEP01 chain: the one owner of every chain SPI byte.
        chain: Chain<ChainSpiBus>,
        /// TIM2 as the 1 kHz control-loop timer (update interrupt).
        tick_timer: CounterHz<board::ControlTimer>,
        /// Wired-OR FLAG line of the chain (low = some chip has an alarm).
        chain_flag: board::ChainFlag,
        /// Wired-OR BUSY line of the chain (low = some chip is busy).
        chain_busy: board::ChainBusy,
        /// Heartbeat LED.
        led: board::StatusLed,
        /// Ticks since the last heartbeat toggle.
        heartbeat: u32,
        /// Failed chain transfers since boot.
        poll_errors: u32,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp = cx.device;
        let mut rcc = dp.RCC.freeze(
            Config::hse(Hertz::from_raw(board::HSE_HZ)).sysclk(Hertz::from_raw(board::SYSCLK_HZ)),
        );
        let sysclk = rcc.clocks.sysclk().raw();
        info!(
            "stepbridge: SYSCLK {=u32} Hz, APB2 {=u32} Hz",
            sysclk,
            rcc.clocks.pclk2().raw()
        );

        let pins = board::configure(
            dp.GPIOA.split(&mut rcc),
            dp.GPIOB.split(&mut rcc),
            dp.GPIOC.split(&mut rcc),
        );
        let bus = ChainSpiBus::new(
            dp.SPI1,
            (pins.chain_sck, pins.chain_miso, pins.chain_mosi),
            pins.chain_cs,
            &mut rcc,
        );
        info!("chain SPI: mode 3, SCK {=u32} Hz", bus.sck_hz());

        // Reset pulse: STBY/RESET is already low (board::configure).
        let mut stby = pins.chain_stby;
        delay_ms(RESET_PULSE_MS, sysclk);
        stby.set_high();
        delay_ms(WAKE_UP_MS, sysclk);

        let mut chain = Chain::new(bus);
        detect_and_report(&mut chain);
        info!(
            "chain lines: FLAG {=bool} BUSY {=bool} (true = asserted)",
            pins.chain_flag.is_low(),
            pins.chain_busy.is_low()
        );

        let mut tick_timer = dp.TIM2.counter_hz(&mut rcc);
        match tick_timer.start(Hertz::from_raw(TICK_HZ)) {
            Ok(()) => tick_timer.listen(Event::Update),
            Err(e) => error!("control timer: start failed ({}), no control loop", e),
        }

        (
            Shared {},
            Local {
                chain,
                tick_timer,
                chain_flag: pins.chain_flag,
                chain_busy: pins.chain_busy,
                led: pins.led,
                heartbeat: 0,
                poll_errors: 0,
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::nop();
        }
    }

    /// The control loop: one chain batch per tick (today: a STATUS poll).
    #[task(
        binds = TIM2,
        priority = 3,
        local = [tick_timer, chain, chain_flag, chain_busy, led, heartbeat, poll_errors]
    )]
    fn control_tick(cx: control_tick::Context) {
        let l = cx.local;
        l.tick_timer.clear_flags(Flag::Update);

        *l.heartbeat += 1;
        if *l.heartbeat >= HEARTBEAT_TICKS {
            *l.heartbeat = 0;
            l.led.toggle();
        }

        if l.chain.is_empty() {
            return;
        }
        match l.chain.poll_status() {
            Ok(replies) => {
                for d in 0..l.chain.len() {
                    if let Some(s) = replies.status(d) {
                        debug!("tick: #{=usize} STATUS {=u16:#06x}", d, s.raw());
                    }
                }
                debug!(
                    "tick: FLAG {=bool} BUSY {=bool}",
                    l.chain_flag.is_low(),
                    l.chain_busy.is_low()
                );
            }
            Err(e) => {
                *l.poll_errors = l.poll_errors.wrapping_add(1);
                // First failure and then one report per second of failures.
                if *l.poll_errors % TICK_HZ == 1 {
                    warn!(
                        "tick: chain poll failed ({}), {=u32} failures",
                        e, *l.poll_errors
                    );
                } else {
                    debug!("tick: chain poll failed ({})", e);
                }
            }
        }
    }

    /// Measure the chain and log every device's STATUS. On failure the chain
    /// stays empty (zero axes) and the control tick leaves it alone.
    fn detect_and_report(chain: &mut Chain<ChainSpiBus>) {
        match chain.detect() {
            Ok(n) => info!("chain: {=usize} powerSTEP01 detected", n),
            Err(e) => {
                error!("chain: detection failed ({}), running with 0 axes", e);
                return;
            }
        }
        match chain.poll_status() {
            Ok(replies) => {
                for d in 0..chain.len() {
                    match replies.status(d) {
                        Some(s) => info!("powerSTEP01 #{=usize}: STATUS {=u16:#06x}", d, s.raw()),
                        None => warn!("powerSTEP01 #{=usize}: no STATUS", d),
                    }
                }
            }
            Err(e) => error!("chain: first STATUS read failed ({})", e),
        }
    }

    /// Busy-wait `ms` milliseconds at `sysclk_hz` (init only).
    fn delay_ms(ms: u32, sysclk_hz: u32) {
        cortex_m::asm::delay(ms.saturating_mul(sysclk_hz / 1_000));
    }
}
