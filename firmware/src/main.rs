//! stepbridge firmware: the RTIC 2 application for the STM32F405.
//!
//! Thin glue only. Pins and peripherals come from [`board`], the chain SPI
//! from [`chain_spi`]; every decision about what goes on the chain belongs to
//! the logic crate (`bridge_logic`). This file wires them to interrupts:
//!
//! * `init`: clocks, pins, chain reset pulse, settings from the flash store,
//!   the bridge (chain detection and axis setup), I2C slave, ADC, timer.
//! * `control_tick` (TIM2 update, 1 kHz, priority 3): `bridge.tick(now)`: one
//!   chain batch for every axis; LED; spawns the slow jobs.
//! * `i2c_event` / `i2c_error` (I2C1, priority 2): bytes in and out of the
//!   PoStep60 I2C protocol; the bridge is locked only to execute a write or
//!   prepare a read.
//! * `housekeeping` (priority 1): ADC samples, pending settings save (flash),
//!   system reset.
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
mod analog;
#[cfg(target_os = "none")]
mod board;
#[cfg(target_os = "none")]
mod chain_spi;
#[cfg(target_os = "none")]
mod flash_store;
#[cfg(target_os = "none")]
mod i2c_slave;

#[cfg(target_os = "none")]
use defmt_rtt as _;
#[cfg(target_os = "none")]
use panic_probe as _;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("stepbridge is firmware: build it with `cargo fw`");
}

// Dispatchers: two unused interrupts for the software tasks.
#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4xx_hal::pac, dispatchers = [UART4, UART5])]
mod app {
    use bridge_logic::bridge::{boot_settings, Bridge};
    use bridge_logic::persist::{StoreError, MAX_IMAGE};
    use bridge_logic::postep::settings::IMAGE_LEN;
    use bridge_logic::postep::Board;
    use bridge_logic::transport::i2c::I2cSlave;
    use defmt::{error, info, warn};
    use stm32f4xx_hal::gpio::GpioExt;
    use stm32f4xx_hal::rcc::{Config, RccExt};
    use stm32f4xx_hal::time::Hertz;
    use stm32f4xx_hal::timer::{CounterHz, Event, Flag, TimerExt};
    use stm32f4xx_hal::{ClearFlags, Listen};

    use crate::analog::Analog;
    use crate::board;
    use crate::chain_spi::ChainSpiBus;
    use crate::flash_store::{SettingsStore, StoreFlash};
    use crate::i2c_slave::{I2cSlaveDriver, LockedTarget};

    /// Control-loop rate.
    const TICK_HZ: u32 = 1_000;
    const TICK_US: u32 = 1_000_000 / TICK_HZ;
    /// STBY/RESET low time at power-up (datasheet minimum is well below).
    const RESET_PULSE_MS: u32 = 1;
    /// Wait after releasing STBY/RESET before the first SPI byte.
    const WAKE_UP_MS: u32 = 20;
    /// Housekeeping (ADC, pending save, reset) every this many ticks (10 Hz).
    const HOUSEKEEPING_TICKS: u64 = TICK_HZ as u64 / 10;

    #[shared]
    struct Shared {
        /// The bridge: chain, axes, PoStep60 models; bus tasks hand it bytes.
        bridge: Bridge<ChainSpiBus>,
        /// I2C1 as the PoStep60 I2C slave (both I2C tasks, one priority).
        #[lock_free]
        i2c: I2cSlaveDriver,
        /// PoStep60 I2C transaction framing (both I2C tasks, one priority).
        #[lock_free]
        i2c_proto: I2cSlave,
    }

    #[local]
    struct Local {
        /// TIM2 as the 1 kHz control-loop timer (update interrupt).
        tick_timer: CounterHz<board::ControlTimer>,
        /// Milliseconds since boot (the bridge's clock).
        now_ms: u64,
        /// Status LED (pattern decided by the bridge).
        led: board::StatusLed,
        /// ADC1: motor supply, die temperature, VREFINT.
        analog: Analog,
        /// Settings store in flash sectors 10 and 11.
        store: SettingsStore,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp = cx.device;
        let mut rcc = dp.RCC.freeze(
            Config::hse(Hertz::from_raw(board::HSE_HZ)).sysclk(Hertz::from_raw(board::SYSCLK_HZ)),
        );
        let sysclk = rcc.clocks.sysclk().raw();
        info!("stepbridge: SYSCLK {=u32} Hz", sysclk);

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

        // Reset pulse: STBY/RESET is already low (board::configure).
        let mut stby = pins.chain_stby;
        delay_ms(RESET_PULSE_MS, sysclk);
        stby.set_high();
        delay_ms(WAKE_UP_MS, sysclk);

        let mut store = SettingsStore::new(StoreFlash::new(dp.FLASH));
        let mut image = [0u8; MAX_IMAGE];
        let loaded = store
            .load(&mut image)
            .map(|n| image.get(..n).unwrap_or(&[]));
        let (settings, source) = boot_settings(loaded, |e| *e == StoreError::Empty);
        info!("settings: {}", source);

        let bridge = Bridge::new(bus, Board::REFERENCE, settings, source, TICK_US);
        match bridge.chain_error() {
            None => info!("chain: {=usize} powerSTEP01", bridge.axes()),
            Some(e) => error!("chain: detection failed ({}), running with 0 axes", e),
        }

        let (primary, secondary) = bridge.i2c_addresses();
        let i2c = I2cSlaveDriver::new(
            dp.I2C1,
            (pins.host_i2c_scl, pins.host_i2c_sda),
            primary,
            secondary,
            &mut rcc,
        );
        let analog = Analog::new(dp.ADC1, pins.supply_sense, &mut rcc);

        let mut tick_timer = dp.TIM2.counter_hz(&mut rcc);
        match tick_timer.start(Hertz::from_raw(TICK_HZ)) {
            Ok(()) => tick_timer.listen(Event::Update),
            Err(e) => error!("control timer: start failed ({}), no control loop", e),
        }

        (
            Shared {
                bridge,
                i2c,
                i2c_proto: I2cSlave::new(),
            },
            Local {
                tick_timer,
                now_ms: 0,
                led: pins.led,
                analog,
                store,
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::nop();
        }
    }

    /// The control loop: one bridge tick (one chain batch for every axis).
    #[task(binds = TIM2, priority = 3, shared = [bridge], local = [tick_timer, now_ms, led])]
    fn control_tick(mut cx: control_tick::Context) {
        let l = cx.local;
        l.tick_timer.clear_flags(Flag::Update);
        *l.now_ms += 1;
        let now = *l.now_ms;
        let led = cx.shared.bridge.lock(|b| {
            b.tick(now);
            b.led_on(now)
        });
        l.led.set_state(led.into());
        if now % HOUSEKEEPING_TICKS == 0 {
            // Still busy with the previous round: skip this one.
            let _ = housekeeping::spawn();
        }
    }

    /// I2C1 events: address match, data bytes, STOP (see `i2c_slave`).
    #[task(binds = I2C1_EV, priority = 2, shared = [bridge, i2c, i2c_proto])]
    fn i2c_event(mut cx: i2c_event::Context) {
        let i2c = cx.shared.i2c;
        i2c.on_event(
            cx.shared.i2c_proto,
            &mut LockedTarget(&mut cx.shared.bridge),
        );
        if let Some((p, s)) = cx
            .shared
            .bridge
            .lock(|b| b.take_address_change().then(|| b.i2c_addresses()))
        {
            i2c.set_addresses(p, s);
        }
    }

    /// I2C1 errors: the master's NACK ending a read, bus errors.
    #[task(binds = I2C1_ER, priority = 2, shared = [bridge, i2c, i2c_proto])]
    fn i2c_error(mut cx: i2c_error::Context) {
        cx.shared.i2c.on_error(
            cx.shared.i2c_proto,
            &mut LockedTarget(&mut cx.shared.bridge),
        );
    }

    /// Slow jobs at the lowest priority: ADC samples (~71 µs of blocking
    /// conversions), a pending settings save (flash programming stalls the
    /// CPU; the bridge hands out the image only when every axis is at rest),
    /// and a requested system reset.
    #[task(priority = 1, shared = [bridge], local = [analog, store, image: [u8; IMAGE_LEN] = [0; IMAGE_LEN]])]
    async fn housekeeping(mut cx: housekeeping::Context) {
        let sample = cx.local.analog.sample();
        let image = cx.local.image;
        let (save, reset) = cx.shared.bridge.lock(|b| {
            b.on_analog(sample);
            (b.take_save(image), b.take_reset())
        });
        if save {
            let ok = cx.local.store.save(image).is_ok();
            if !ok {
                warn!("settings: save failed");
            }
            cx.shared.bridge.lock(|b| b.saved(ok));
        }
        if reset {
            info!("system reset requested");
            cortex_m::peripheral::SCB::sys_reset();
        }
    }

    /// Busy-wait `ms` milliseconds at `sysclk_hz` (init only).
    fn delay_ms(ms: u32, sysclk_hz: u32) {
        cortex_m::asm::delay(ms.saturating_mul(sysclk_hz / 1_000));
    }
}
