//! stepbridge firmware: the RTIC 2 application for the STM32F405.
//!
//! Thin glue only. Pins and peripherals come from [`board`], the chain SPI
//! from [`chain_spi`], the Modbus line from [`rs485`], time from [`clock`];
//! every decision about what goes on a bus belongs to the logic crate
//! (`bridge_logic`). This file wires them to interrupts:
//!
//! * `init`: clocks, SysTick monotonic, pins, chain reset pulse, settings
//!   from the flash store, the bridge (chain detection and axis setup), I2C
//!   slave, Modbus line, ADC, timer.
//! * `control_tick` (TIM2 update, 1 kHz, priority 3): `bridge.tick(now)`: one
//!   chain batch for every axis; STBY low for good once the bridge declares
//!   the chain dead; LED; feeds the independent watchdog; spawns the slow
//!   jobs.
//! * `modbus_uart` (USART2, priority 4): every received byte is stamped with
//!   the monotonic's µs and handed to the Modbus RTU server; the response
//!   goes out by TXE/TC interrupts with DE high (see `rs485`). Highest
//!   priority, so stamps are accurate and a response never stalls between
//!   characters (a pause > t1.5 would break the frame).
//! * `modbus_server` (async, priority 2): sleeps until the server's t3.5
//!   deadline, then locks the bridge only for `poll` (which executes the
//!   request) and starts the response at once; a changed address base goes
//!   on to the I2C slave's own addresses.
//! * `i2c_event` / `i2c_error` (I2C1, priority 2): bytes in and out of the
//!   PoStep60 I2C protocol; the bridge is locked only to execute a write or
//!   prepare a read.
//! * `housekeeping` (priority 1): ADC samples, pending settings save (flash),
//!   system reset — the last two only while no Modbus response is going out.
//! * `idle`: spins (no `wfi`, which stops the debug clock on some probes and
//!   gains nothing while a 1 kHz tick keeps waking the core).
//!
//! A panic, and a HardFault on the board, drive STBY low first of all
//! ([`failsafe`]); the independent watchdog (board only, started in `init`)
//! resets the MCU if the control tick stops.
//!
//! With the `qemu` feature the same app runs on QEMU's `netduinoplus2`;
//! [`qemu`] lists what is replaced (clocks, chain, ADC, flash, I2C, log
//! transport) and the control tick comes from the monotonic
//! (`control_loop`) because QEMU's TIM2 is unusable.
//!
//! The firmware is built only for `thumbv7em-none-eabihf` (`cargo fw`,
//! `cargo qemu`). On any other target this file compiles to an empty `main`,
//! so a host-side `cargo check --workspace` still works.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]
#![deny(unsafe_code)]

#[cfg(all(target_os = "none", not(feature = "qemu")))]
mod analog;
// Under QEMU the chain SPI, HSE and I2C assignments go unused (the board
// build checks them).
#[cfg(target_os = "none")]
#[cfg_attr(feature = "qemu", allow(dead_code))]
mod board;
#[cfg(all(target_os = "none", not(feature = "qemu")))]
mod chain_spi;
#[cfg(target_os = "none")]
mod clock;
#[cfg(target_os = "none")]
mod failsafe;
#[cfg(all(target_os = "none", not(feature = "qemu")))]
mod flash_store;
// Under QEMU not built: `qemu::NoI2c` stands in for the driver.
#[cfg(all(target_os = "none", not(feature = "qemu")))]
mod i2c_slave;
#[cfg(all(target_os = "none", feature = "qemu"))]
mod qemu;
#[cfg(target_os = "none")]
mod rs485;

#[cfg(all(target_os = "none", not(feature = "qemu")))]
use defmt_rtt as _;
#[cfg(all(target_os = "none", feature = "qemu"))]
use defmt_semihosting as _;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("stepbridge is firmware: build it with `cargo fw` (board) or `cargo qemu`");
}

// Dispatchers: unused interrupts for the software tasks (one per priority).
#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4xx_hal::pac, dispatchers = [UART4, UART5, USART6])]
mod app {
    use bridge_logic::bridge::{boot_settings, Bridge};
    use bridge_logic::persist::{StoreError, MAX_IMAGE};
    use bridge_logic::postep::settings::IMAGE_LEN;
    use bridge_logic::postep::Board;
    use bridge_logic::transport::modbus::{RtuServer, Timing};
    use defmt::{debug, error, info, warn};
    use rtic::Mutex;
    use rtic_monotonics::Timebase;
    use rtic_sync::signal::{SignalReader, SignalWriter};
    use stm32f4xx_hal::gpio::GpioExt;
    use stm32f4xx_hal::rcc::{Config, RccExt};

    use crate::board;
    use crate::clock::{self, Mono};
    use crate::rs485::{Rs485, Rx};

    // The board's peripherals, or their QEMU stand-ins (crate::qemu).
    #[cfg(not(feature = "qemu"))]
    use crate::analog::Analog;
    #[cfg(not(feature = "qemu"))]
    use crate::chain_spi::ChainSpiBus as ChainBus;
    #[cfg(not(feature = "qemu"))]
    use crate::flash_store::{SettingsStore, StoreFlash};
    #[cfg(not(feature = "qemu"))]
    use crate::i2c_slave::{I2cSlaveDriver, LockedTarget};
    #[cfg(feature = "qemu")]
    use crate::qemu::NoI2c as I2cSlaveDriver;
    #[cfg(feature = "qemu")]
    use crate::qemu::{FixedAnalog as Analog, RamFlash, SettingsStore, SimChain as ChainBus};
    use bridge_logic::transport::i2c::I2cSlave;
    // (Named in both builds: RTIC's Send assertions name the types of every
    // resource, cfg'd out or not.)
    use stm32f4xx_hal::timer::CounterHz;
    use stm32f4xx_hal::watchdog::IndependentWatchdog;
    #[cfg(not(feature = "qemu"))]
    use stm32f4xx_hal::{
        prelude::_fugit_ExtU32 as _,
        time::Hertz,
        timer::{Event, Flag, TimerExt},
        ClearFlags, Listen,
    };

    /// Control-loop rate.
    const TICK_HZ: u32 = 1_000;
    const TICK_US: u32 = 1_000_000 / TICK_HZ;
    /// STBY/RESET low time at power-up (datasheet minimum is well below).
    const RESET_PULSE_MS: u32 = 1;
    /// Wait after releasing STBY/RESET before the first SPI byte.
    const WAKE_UP_MS: u32 = 20;
    /// Housekeeping (ADC, pending save, reset) every this many ticks (10 Hz).
    const HOUSEKEEPING_TICKS: u64 = TICK_HZ as u64 / 10;
    /// Worst-case erase of a 128 KiB flash sector at x8 parallelism
    /// (STM32F405 datasheet): a settings save that erases stalls the CPU,
    /// control tick and watchdog feed included, this long.
    #[cfg(not(feature = "qemu"))]
    const ERASE_MAX_MS: u32 = 4_000;
    /// Independent-watchdog timeout, nominal (the HAL assumes a 32 kHz LSI).
    /// The LSI of the STM32F405 runs anywhere from 17 to 47 kHz (datasheet),
    /// so the real timeout is 0.68 to 1.88 times this: 6.5 s nominal is at
    /// least 4.4 s, longer than the worst-case erase (a shorter one would
    /// reset the MCU in the middle of a save), and at most 12.2 s.
    #[cfg(not(feature = "qemu"))]
    const WATCHDOG_MS: u32 = 6_500;
    #[cfg(not(feature = "qemu"))]
    const _: () = assert!(
        WATCHDOG_MS as u64 * 32 / 47 > ERASE_MAX_MS as u64 + 2 * TICK_US as u64 / 1_000,
        "the watchdog must outlast a sector erase at the fastest LSI"
    );

    #[shared]
    struct Shared {
        /// The bridge: chain, axes, PoStep60 models; bus tasks hand it bytes.
        bridge: Bridge<ChainBus>,
        /// USART2 + DE: the RS-485 line (Modbus UART task and server task).
        rs485: Rs485,
        /// Modbus RTU framing and function codes (same two tasks).
        modbus: RtuServer,
        /// I2C1 as the PoStep60 I2C slave (both I2C tasks, and the Modbus
        /// server task for address changes; all at one priority, so the
        /// locks cost nothing, but an async task may not share a
        /// `#[lock_free]` resource). A stand-in under QEMU: RTIC 2.4 cannot
        /// `cfg` out a resource that is locked.
        i2c: I2cSlaveDriver,
        /// PoStep60 I2C transaction framing (both I2C tasks, one priority).
        #[cfg(not(feature = "qemu"))]
        #[lock_free]
        i2c_proto: I2cSlave,
    }

    #[local]
    struct Local {
        /// TIM2 as the 1 kHz control-loop timer (update interrupt).
        #[cfg(not(feature = "qemu"))]
        tick_timer: CounterHz<board::ControlTimer>,
        /// Milliseconds since boot (the bridge's clock).
        #[cfg(not(feature = "qemu"))]
        now_ms: u64,
        /// Status LED (pattern decided by the bridge). Under QEMU it goes to
        /// `control_loop` as its spawn argument instead.
        #[cfg(not(feature = "qemu"))]
        led: board::StatusLed,
        /// Chain STBY/RESET, released (high) by `init`: driven low and given
        /// up (`None`) once the bridge declares the chain dead. Under QEMU
        /// (nothing attached) a spawn argument of `control_loop`, like the
        /// LED.
        #[cfg(not(feature = "qemu"))]
        stby: Option<board::ChainStby>,
        /// The independent watchdog, fed by every control tick.
        #[cfg(not(feature = "qemu"))]
        watchdog: IndependentWatchdog,
        /// ADC1: motor supply, die temperature, VREFINT.
        analog: Analog,
        /// Settings store: flash sectors 10 and 11 (RAM under QEMU).
        store: SettingsStore,
        /// Wakes the Modbus server task when bytes arrive (UART task's end).
        bytes_in: SignalWriter<'static, ()>,
        /// The Modbus server task's end of that signal.
        bytes_seen: SignalReader<'static, ()>,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp = cx.device;
        #[cfg(not(feature = "qemu"))]
        let (clocks, systick_hz) = (
            Config::hse(Hertz::from_raw(board::HSE_HZ)).sysclk(Hertz::from_raw(board::SYSCLK_HZ)),
            None,
        );
        // QEMU models no PLL (its ready bits read 0): HSI only; its SysTick
        // counts at 168 MHz anyway.
        #[cfg(feature = "qemu")]
        let (clocks, systick_hz) = (Config::hsi(), Some(crate::qemu::SYSTICK_HZ));
        let mut rcc = dp.RCC.freeze(clocks);
        let sysclk = rcc.clocks.sysclk().raw();
        info!("stepbridge: SYSCLK {=u32} Hz", sysclk);
        // `start` asserts a whole number of cycles per tick: 168 MHz is.
        let systick_hz = systick_hz.unwrap_or(sysclk);
        Mono::start(cx.core.SYST, systick_hz - systick_hz % clock::TICK_HZ);

        // From here on a stalled control tick resets the MCU (QEMU does not
        // model the IWDG). Frozen while a debugger halts the core.
        #[cfg(not(feature = "qemu"))]
        let watchdog = {
            let mut watchdog = IndependentWatchdog::new(dp.IWDG);
            watchdog.stop_on_debug(&dp.DBGMCU, true);
            watchdog.start(WATCHDOG_MS.millis());
            info!("watchdog: {=u32} ms nominal", WATCHDOG_MS);
            watchdog
        };

        let pins = board::configure(
            dp.GPIOA.split(&mut rcc),
            dp.GPIOB.split(&mut rcc),
            dp.GPIOC.split(&mut rcc),
        );
        #[cfg(not(feature = "qemu"))]
        let bus = ChainBus::new(
            dp.SPI1,
            (pins.chain_sck, pins.chain_miso, pins.chain_mosi),
            pins.chain_cs,
            &mut rcc,
        );
        // The simulated chain instead of SPI1; its pins stay configured.
        #[cfg(feature = "qemu")]
        let bus = crate::qemu::chain();

        // Reset pulse: STBY/RESET is already low (board::configure).
        let mut stby = pins.chain_stby;
        delay_ms(RESET_PULSE_MS, sysclk);
        stby.set_high();
        delay_ms(WAKE_UP_MS, sysclk);

        #[cfg(not(feature = "qemu"))]
        let flash = StoreFlash::new(dp.FLASH);
        #[cfg(feature = "qemu")]
        let flash = RamFlash::new();
        let mut store = SettingsStore::new(flash);
        let mut image = [0u8; MAX_IMAGE];
        let loaded = store
            .load(&mut image)
            .map(|n| image.get(..n).unwrap_or(&[]));
        let (settings, source) = boot_settings(loaded, |e| *e == StoreError::Empty);
        info!("settings: {}", source);

        let mut bridge = Bridge::new(bus, Board::REFERENCE, settings, source, TICK_US);
        match bridge.chain_error() {
            None => info!("chain: {=usize} powerSTEP01", bridge.axes()),
            Some(e) => error!("chain: detection failed ({}), running with 0 axes", e),
        }

        #[cfg(feature = "qemu")]
        let i2c = crate::qemu::NoI2c;
        #[cfg(not(feature = "qemu"))]
        let i2c = {
            let (primary, secondary) = bridge.i2c_addresses();
            I2cSlaveDriver::new(
                dp.I2C1,
                (pins.host_i2c_scl, pins.host_i2c_sda),
                primary,
                secondary,
                &mut rcc,
            )
        };

        let serial = bridge.serial();
        let timing = Timing::for_serial(serial);
        let rs485 = Rs485::new(
            dp.USART2,
            (pins.modbus_tx, pins.modbus_rx),
            pins.modbus_de,
            serial,
            &mut rcc,
        );
        if rs485.is_configured() {
            info!(
                "modbus: RTU on USART2, {=u32} baud, parity {}, t1.5 {=u32} us, t3.5 {=u32} us, server ids from {=u8}, {=usize} axes",
                serial.baud,
                serial.parity,
                timing.t15_us,
                timing.t35_us,
                bridge.base_address(),
                bridge.axes()
            );
        } else {
            error!("modbus: USART2 configuration refused, no Modbus");
        }

        let mut analog = Analog::new(dp.ADC1, pins.supply_sense, &mut rcc);
        bridge.on_analog(analog.sample());

        #[cfg(not(feature = "qemu"))]
        let tick_timer = {
            let mut timer = dp.TIM2.counter_hz(&mut rcc);
            match timer.start(Hertz::from_raw(TICK_HZ)) {
                Ok(()) => timer.listen(Event::Update),
                Err(e) => error!("control timer: start failed ({}), no control loop", e),
            }
            timer
        };
        #[cfg(feature = "qemu")]
        if control_loop::spawn(pins.led, stby).is_err() {
            error!("control loop: spawn failed");
        }
        if modbus_server::spawn().is_err() {
            error!("modbus: server task spawn failed");
        }

        let (bytes_in, bytes_seen) = rtic_sync::make_signal!(());
        (
            Shared {
                bridge,
                rs485,
                modbus: RtuServer::new(timing),
                i2c,
                #[cfg(not(feature = "qemu"))]
                i2c_proto: I2cSlave::new(),
            },
            Local {
                #[cfg(not(feature = "qemu"))]
                tick_timer,
                #[cfg(not(feature = "qemu"))]
                now_ms: 0,
                #[cfg(not(feature = "qemu"))]
                led: pins.led,
                #[cfg(not(feature = "qemu"))]
                stby: Some(stby),
                #[cfg(not(feature = "qemu"))]
                watchdog,
                analog,
                store,
                bytes_in,
                bytes_seen,
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
    #[cfg(not(feature = "qemu"))]
    #[task(binds = TIM2, priority = 3, shared = [bridge], local = [tick_timer, now_ms, led, stby, watchdog])]
    fn control_tick(mut cx: control_tick::Context) {
        cx.local.tick_timer.clear_flags(Flag::Update);
        cx.local.watchdog.feed();
        *cx.local.now_ms += 1;
        control_step(
            &mut cx.shared.bridge,
            *cx.local.now_ms,
            cx.local.led,
            cx.local.stby,
        );
    }

    /// The control loop under QEMU, whose TIM2 is unusable: the same step
    /// every 1 ms of the monotonic (late ticks catch up, so the bridge's
    /// clock keeps pace with real time).
    #[cfg(feature = "qemu")]
    #[task(priority = 3, shared = [bridge])]
    async fn control_loop(
        mut cx: control_loop::Context,
        mut led: board::StatusLed,
        stby: board::ChainStby,
    ) {
        let period = <Mono as Timebase>::Duration::from_ticks(u64::from(clock::TICK_HZ / TICK_HZ));
        let mut next = Mono::now();
        let mut now_ms = 0;
        let mut stby = Some(stby);
        loop {
            next += period;
            Mono::delay_until(next).await;
            now_ms += 1;
            control_step(&mut cx.shared.bridge, now_ms, &mut led, &mut stby);
        }
    }

    /// One control tick at `now` ms: bridge tick, STBY, LED, slow jobs at
    /// 10 Hz.
    fn control_step(
        bridge: &mut impl Mutex<T = Bridge<ChainBus>>,
        now: u64,
        led: &mut board::StatusLed,
        stby: &mut Option<board::ChainStby>,
    ) {
        let (on, dead) = bridge.lock(|b| {
            b.tick(now);
            // The simulated chips live through exactly one tick period.
            #[cfg(feature = "qemu")]
            b.chain_mut().bus_mut().advance(u64::from(TICK_US) * 1_000);
            (b.led_on(now), b.chain_dead())
        });
        // The bridge can no longer stop the motors over SPI: hold every chip
        // in reset, bridges off. The pin is given up with it (a dropped HAL
        // pin keeps its mode and level), so nothing can drive STBY high
        // again until the MCU resets.
        if dead {
            if let Some(mut pin) = stby.take() {
                pin.set_low();
                error!("chain: dead, STBY low: every chip held in reset until the MCU resets");
            }
        }
        led.set_state(on.into());
        if now % HOUSEKEEPING_TICKS == 0 {
            // Still busy with the previous round: skip this one.
            let _ = housekeeping::spawn();
        }
    }

    /// USART2: received bytes, stamped, into the Modbus server; the
    /// response's bytes out and DE released after the last stop bit.
    #[task(binds = USART2, priority = 4, shared = [rs485, modbus], local = [bytes_in])]
    fn modbus_uart(cx: modbus_uart::Context) {
        let mut received = false;
        (cx.shared.rs485, cx.shared.modbus).lock(|rs485, server| {
            rs485.on_interrupt(|rx| {
                let now = clock::now_us();
                match rx {
                    Rx::Byte(byte) => server.on_byte(byte, now),
                    Rx::Bad => server.on_bad_byte(now),
                }
                received = true;
            });
        });
        if received {
            cx.local.bytes_in.write(());
        }
    }

    /// Modbus frame ends: wait for the server's deadline (t3.5 after the
    /// last byte), execute the request with the bridge locked, start the
    /// response at once. A request that changed the address base moves the
    /// I2C slave's own addresses too (the I2C tasks only look after their
    /// own requests). Same priority as the I2C tasks: it never preempts
    /// them, so the addresses never change in the middle of their handling.
    #[task(priority = 2, shared = [bridge, rs485, modbus, i2c], local = [bytes_seen, errors_seen: u32 = 0])]
    async fn modbus_server(mut cx: modbus_server::Context) {
        loop {
            let Some(deadline) = cx.shared.modbus.lock(|s| s.deadline()) else {
                cx.local.bytes_seen.wait().await;
                continue;
            };
            Mono::delay_until(clock::instant_at_us(deadline)).await;
            let now = clock::now_us();
            let bridge = &mut cx.shared.bridge;
            let errors = (&mut cx.shared.modbus, &mut cx.shared.rs485).lock(|server, rs485| {
                if let Some(adu) = bridge.lock(|b| server.poll(now, b)) {
                    rs485.send(adu);
                    debug!(
                        "modbus: response {=[u8]:02x}, started {=u64} us after t3.5",
                        adu,
                        now.saturating_sub(deadline)
                    );
                }
                rs485.errors()
            });
            cx.shared.i2c.lock(|i2c| apply_address_change(bridge, i2c));
            if errors.total() != *cx.local.errors_seen {
                *cx.local.errors_seen = errors.total();
                warn!("modbus: line errors {}", errors);
            }
        }
    }

    /// I2C1 events: address match, data bytes, STOP (see `i2c_slave`).
    #[cfg(not(feature = "qemu"))]
    #[task(binds = I2C1_EV, priority = 2, shared = [bridge, i2c, i2c_proto])]
    fn i2c_event(mut cx: i2c_event::Context) {
        let (bridge, proto) = (&mut cx.shared.bridge, cx.shared.i2c_proto);
        cx.shared.i2c.lock(|i2c| {
            i2c.on_event(proto, &mut LockedTarget(&mut *bridge));
            apply_address_change(bridge, i2c);
        });
    }

    /// I2C1 errors: the master's NACK ending a read, bus errors.
    #[cfg(not(feature = "qemu"))]
    #[task(binds = I2C1_ER, priority = 2, shared = [bridge, i2c, i2c_proto])]
    fn i2c_error(mut cx: i2c_error::Context) {
        let (bridge, proto) = (&mut cx.shared.bridge, cx.shared.i2c_proto);
        cx.shared
            .i2c
            .lock(|i2c| i2c.on_error(proto, &mut LockedTarget(bridge)));
    }

    /// Reprogram the I2C own addresses if the bridge's address base changed
    /// since the last call (through either bus).
    fn apply_address_change(
        bridge: &mut impl Mutex<T = Bridge<ChainBus>>,
        i2c: &mut I2cSlaveDriver,
    ) {
        if let Some((p, s)) = bridge.lock(|b| b.take_address_change().then(|| b.i2c_addresses())) {
            i2c.set_addresses(p, s);
        }
    }

    /// Slow jobs at the lowest priority: ADC samples (~71 µs of blocking
    /// conversions), a pending settings save (flash programming stalls the
    /// CPU; the bridge hands out the image only when every axis is at rest),
    /// and a requested system reset. Save and reset wait until no Modbus
    /// response is going out (both would cut it short); the check and the
    /// take are one lock, so a response started in between cannot slip by.
    #[task(priority = 1, shared = [bridge, rs485], local = [analog, store, image: [u8; IMAGE_LEN] = [0; IMAGE_LEN]])]
    async fn housekeeping(mut cx: housekeeping::Context) {
        let sample = cx.local.analog.sample();
        let image = cx.local.image;
        let (save, reset) = (&mut cx.shared.bridge, &mut cx.shared.rs485).lock(|b, line| {
            b.on_analog(sample);
            if line.is_sending() {
                (false, None)
            } else {
                (b.take_save(image), b.take_reset())
            }
        });
        if save {
            let ok = cx.local.store.save(image).is_ok();
            if !ok {
                warn!("settings: save failed");
            }
            cx.shared.bridge.lock(|b| b.saved(ok));
        }
        if let Some(target) = reset {
            info!("system reset requested ({})", target);
            cortex_m::peripheral::SCB::sys_reset();
        }
    }

    /// Busy-wait `ms` milliseconds at `sysclk_hz` (init only).
    fn delay_ms(ms: u32, sysclk_hz: u32) {
        cortex_m::asm::delay(ms.saturating_mul(sysclk_hz / 1_000));
    }
}
