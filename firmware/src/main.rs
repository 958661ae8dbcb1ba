//! stepbridge: the RTIC 2 application, written once for the board and QEMU.
//!
//! Thin glue: pins come from `firmware::pins`, peripherals from
//! `firmware::platform` (the board's, or QEMU's stand-ins under the same
//! names), every decision from the logic crate (`bridge_logic`).
//!
//! | task | runs on | priority | owns | shares |
//! |---|---|---|---|---|
//! | `init` | reset | – | reset handoff, RCC, SysTick, IWDG (long window, short as its last step), GPIO; starts everything below | – |
//! | `chain_window_end` | DMA2_STREAM0 | 5 | – | the chain driver (SPI1, DMA2 streams 0/3, TIM7, CS: one value in `platform`'s cell, `platform::with_chain`) |
//! | `chain_gap_end` | TIM7 | 5 | – | the chain driver |
//! | `modbus_uart` | USART2 | 4 | – | `rs485` (USART2, DE), `modbus` |
//! | `control_tick` | TIM2, 1 kHz | 3 | `tick` (TIM2), LED, STBY | `bridge` (its chain bus: a handle on the chain driver, for the blocking windows), the chain driver (poll, start), `watchdog` (IWDG) |
//! | `modbus_server` | async | 2 | – | `bridge`, `rs485`, `modbus`, `i2c` |
//! | `ioext_run` | async | 2 | – | `ioext` (SPI2, TIM1, DMA1/2, PB11/13–15), `bridge` |
//! | `ioext_spi_end`, `ioext_bit_end` | DMA1_STREAM3, DMA2_STREAM2 | 2 | – | `ioext`, `bridge` |
//! | `i2c_event`, `i2c_error` | I2C1_EV, I2C1_ER | 2 | – | `bridge`, `i2c` (I2C1), `i2c_proto` |
//! | `housekeeping` | async, 10 Hz | 1 | `analog` (ADC1), `store` (FLASH) | `bridge`, `rs485`, `watchdog` |
//! | `usb_hid` | OTG_FS, and pended by every control tick | 1 | `usb` (OTG FS) | `bridge` |
//!
//! * `chain_window_end` / `chain_gap_end` run the control tick's chain
//!   batch (`drivers::chain_spi`): per window TIM7 times the CS-high gap
//!   (≥ 800 ns) and the CS set-up (≥ 350 ns), DMA2 moves the N bytes, and
//!   stream 0's transfer-complete raises CS and arms the next window. Tens
//!   of instructions each (`docs/performance.md`).
//!   Highest priority: the windows are the motion's timing and must not
//!   wait behind the Modbus UART or a bridge lock; they can delay the UART
//!   task by one of these short handlers (< 1 µs), nothing at the Modbus
//!   line's scale (t1.5 ≥ 750 µs). The chain driver is one value, SPI1's
//!   only owner, in a critical-section cell (`platform::with_chain`):
//!   these handlers, the control tick's start and hand-over (~140 and ~70
//!   instructions) and the bridge's handle (a blocking window, ≤ 27 µs:
//!   chain detection in `init`, the recovery windows after a bus error)
//!   each mask every interrupt for that long.
//! * `modbus_uart` stamps each received byte with the monotonic's µs and
//!   hands it to the Modbus RTU server; the response leaves by TXE/TC
//!   interrupts with DE high. Above everything but the chain's interrupts:
//!   stamps stay accurate and a response never pauses between characters
//!   (> t1.5 would break it).
//! * `control_tick`: first the watchdog, fed in the window the bridge asks
//!   for (`Bridge::watchdog_window`: short, 16.9–47.1 ms over the LSI's
//!   spread, whenever an axis may move; long only while a save is handed
//!   out), so the window is in effect before the tick plans anything (a
//!   change waits up to 5 LSI cycles, 0.3 ms: at the first tick after a
//!   save only). Then `Bridge::tick_pipelined` — one chain batch for every
//!   axis, by DMA: the batch started by the previous tick is collected
//!   (`ChainSpi::poll`, its rows copied out) and ended (its replies
//!   absorbed), then this tick is planned and its batch started; the bytes
//!   shift while the CPU does other work. Batch k's replies are absorbed at
//!   tick k + 1's start, before batch k + 1 is planned: the blocking
//!   tick's order, one period later. A chain whose computation and batch
//!   in a row do not fit the period (`rate::fit`) ticks overlapped
//!   instead (`Bridge::tick_overlapped`, the same call): the batch the
//!   previous tick planned starts first, then the one before it is
//!   absorbed and the next planned while it shifts. A batch still on the bus when the
//!   tick comes skips the tick (an overrun in the diagnostics); one past
//!   its deadline (2 × nominal + 100 µs) is stopped and ends as a chain
//!   error. Then STBY low for good once the bridge declares the chain dead, LED,
//!   the 10 Hz spawn of `housekeeping`, a pend of `usb_hid`,
//!   its own duration (DWT; the monotonic under QEMU) into the bridge's
//!   diagnostics, and the I/O extension's next action
//!   (`Bridge::take_io_action`) into a channel to `ioext_run` — nothing of
//!   the transfer runs inside the tick.
//! * `ioext_run` starts each transfer (`platform::IoExtDriver`, under QEMU
//!   the simulated shift registers, which end at once) and waits for its
//!   end at most the plan's `timeout_us`, then stops it and reports a
//!   failure. `ioext_*_end` (the DMA transfer-complete / error interrupts)
//!   finish the transfer (BSY / CEN, half a period, CS) and hand the
//!   received bits to `Bridge::on_io_done` (`on_io_failed` on a DMA error).
//!   Priority 2, below the control tick and the Modbus UART: they can delay
//!   neither, except by the bridge lock around `on_io_done` (~1 250
//!   instructions, shorter than a Modbus request's); the driver resource is
//!   shared only at priority 2, so its locks mask nothing.
//! * `modbus_server` sleeps until the server's t3.5 deadline, executes the
//!   request with the bridge locked and starts the response; a changed
//!   address base goes on to the I2C slave. `i2c_*` move PoStep60 I2C bytes.
//! * `housekeeping`: ADC samples, a pending settings save, a requested
//!   system reset — the last two only while no Modbus response goes out.
//!   A save switches the watchdog to the long window (4.4–12.2 s) before
//!   the flash erase stalls the CPU, and does not erase if that fails; the
//!   control tick after `Bridge::saved` switches back to short.
//!   The reset's target (application, boot mode, ROM DFU) goes into the
//!   `.uninit` handoff word first; `init` reads it before anything else:
//!   boot mode starts the bridge in it, ROM DFU jumps to ST's bootloader
//!   before the clocks are touched.
//! * `usb_hid` polls usb-device, hands OUT reports to the bridge and puts
//!   its next IN report into the endpoint; a bus reset ends the stream.
//!   Lowest priority: USB has the loosest timing of the buses (the OTG core
//!   NAKs until the task has served it; the host polls every 10 ms). Its
//!   interrupts come from the OTG core; the 0xA0 stream is due by time, so
//!   every control tick also pends it (≤ 1 ms late on the 10 ms cadence).
//!
//! A panic or HardFault drives STBY low first (`firmware::failsafe`); the
//! watchdog resets the MCU if `control_tick` stops, within 47.1 ms while
//! an axis may move (`docs/pins.md`, *Wiring*). Under QEMU (feature
//! `qemu`) the same tasks run on `platform/qemu.rs`'s stand-ins, where the
//! I2C tasks never fire and USB is never started (`usb_hid` returns at
//! once). On any target but `thumbv7em-none-eabihf` this file is an empty
//! `main`.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]
#![deny(unsafe_code)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("stepbridge is firmware: build it with `cargo fw` (board) or `cargo qemu`");
}

// Dispatchers: unused interrupts for the software tasks (one per priority).
#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4xx_hal::pac, dispatchers = [UART4, UART5, USART6])]
mod app {
    use bridge_logic::bridge::{BatchState, Bridge, ResetCause, ResetTarget};
    use bridge_logic::ioext::Action;
    use bridge_logic::persist::Store;
    use bridge_logic::postep60::settings::IMAGE_LEN;
    use bridge_logic::postep60::PowerStage;
    use bridge_logic::powerstep::chain::{Frames, MAX_DEVICES, MAX_WINDOWS};
    use bridge_logic::transport::i2c::I2cSlave;
    use bridge_logic::transport::modbus::{RtuServer, Timing};
    use bridge_logic::transport::usb::REPORT_LEN;
    use defmt::{debug, error, info, warn};
    use firmware::drivers::chain_spi::ChainSpiError;
    use firmware::drivers::chain_spi::{ChainBuffers, ChainPeripherals};
    use firmware::drivers::clock::{self, Mono};
    use firmware::drivers::i2c_slave::LockedTarget;
    use firmware::drivers::ioext_spi::{IoExtBuffers, IoExtPeripherals, Started};
    use firmware::drivers::mcu;
    use firmware::drivers::rs485::{Rs485, Rx};
    use firmware::drivers::usb::Link;
    use firmware::handoff::{apply_address_change, hand_over_io, report_io};
    use firmware::pins;
    use firmware::platform::{
        self, Analog, ChainLink, I2cSlaveDriver, IoExtDriver, SettingsFlash, Stopwatch, TickTimer,
        Usb, Watchdog,
    };
    use firmware::startup::{arm_watchdog, delay_ms, load_settings, log_modbus};
    use rtic_monotonics::Timebase;
    use rtic_sync::channel::{Receiver, Sender};
    use rtic_sync::signal::{SignalReader, SignalWriter};
    use stm32f4xx_hal::gpio::GpioExt;
    use stm32f4xx_hal::pac::Interrupt;

    /// Control-loop rate: the build setting `STEPBRIDGE_TICK_HZ` (default
    /// 1 kHz; `bridge_logic::rate`).
    use bridge_logic::rate::{Rate, TickClock, TICK_HZ};
    /// STBY/RESET low time at power-up (datasheet minimum is well below).
    const RESET_PULSE_MS: u32 = 1;
    /// Wait after releasing STBY/RESET before the first SPI byte.
    const WAKE_UP_MS: u32 = 20;
    /// I/O extension actions in flight from the control tick to `ioext_run`
    /// (the bridge hands out at most one per tick, and none while its
    /// transfer runs).
    const IO_ACTIONS: usize = 2;

    #[shared]
    struct Shared {
        /// The bridge: chain (a handle on the one chain driver, for its
        /// blocking windows), axes, PoStep60 models; bus tasks hand it
        /// bytes. The chain driver itself (the control tick's batches, run
        /// by the DMA and TIM7 tasks) is in `platform`'s cell. In `init`'s
        /// static slot (`bridge_slot`), not moved through `init`'s return
        /// value: it is ~18 KB, and every copy on the way costs stack
        /// (docs/performance.md, "SRAM is shared").
        bridge: &'static mut Bridge<ChainLink>,
        /// USART2 + DE: the RS-485 line (Modbus UART task and server task).
        rs485: Rs485,
        /// Modbus RTU framing and function codes (same two tasks).
        modbus: RtuServer,
        /// I2C1 as the PoStep60 I2C slave (both I2C tasks, and the Modbus
        /// server task for address changes; all at one priority, so the
        /// locks cost nothing, but an async task may not share a
        /// `#[lock_free]` resource).
        i2c: I2cSlaveDriver,
        /// PoStep60 I2C transaction framing (both I2C tasks, one priority).
        #[lock_free]
        i2c_proto: I2cSlave,
        /// The I/O extension's port (`ioext_run` and the two DMA tasks, all
        /// at priority 2).
        ioext: IoExtDriver,
        /// The independent watchdog: fed by every control tick in the
        /// bridge's window, switched to the long one by `housekeeping`
        /// before a save's erase (ceiling 3: that switch holds the tick off
        /// for its ≤ 0.3 ms).
        watchdog: Watchdog,
    }

    #[local]
    struct Local {
        /// TIM2 as the control-loop timer (update interrupt).
        tick: TickTimer,
        /// The bridge's ms clock and the 10 Hz cadence, counted in ticks.
        clock: TickClock,
        /// The tick rate in use (`rate::fit_need` with the platform's cost
        /// of a tick: the build setting, or slower for a chain that does
        /// not fit it).
        rate: Rate,
        /// Status LED (pattern decided by the bridge).
        led: pins::StatusLed,
        /// Chain STBY/RESET, released (high) by `init`: driven low and given
        /// up (`None`) once the bridge declares the chain dead.
        stby: Option<pins::ChainStby>,
        /// ADC1: motor supply, die temperature, VREFINT.
        analog: Analog,
        /// Settings store: flash sectors 10 and 11 (a host file under QEMU).
        store: Store<SettingsFlash>,
        /// Wakes the Modbus server task when bytes arrive (UART task's end).
        bytes_in: SignalWriter<'static, ()>,
        /// The Modbus server task's end of that signal.
        bytes_seen: SignalReader<'static, ()>,
        /// OTG FS as the PoStep60 HID device (None: not started, QEMU).
        usb: Option<Usb>,
        /// The control tick's end of the I/O extension's action channel.
        io_actions: Sender<'static, Action, IO_ACTIONS>,
        /// An action the channel had no room for, handed over next tick.
        io_pending: Option<Action>,
        /// `ioext_run`'s end of the action channel.
        io_next: Receiver<'static, Action, IO_ACTIONS>,
        /// "The transfer ended" from the DMA tasks to `ioext_run`.
        io_ended: Receiver<'static, (), 2>,
        /// The DMA tasks' ends of that channel.
        io_ended_spi: Sender<'static, (), 2>,
        io_ended_bit: Sender<'static, (), 2>,
    }

    #[init(local = [
        io_buffers: IoExtBuffers = IoExtBuffers::new(),
        chain_buffers: ChainBuffers = ChainBuffers::new(),
        bridge_slot: Option<Bridge<ChainLink>> = None,
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp = cx.device;
        let mut core = cx.core;
        let (mut rcc, boot) =
            start_clocks(dp.RCC, &dp.SYSCFG, core.SYST, &mut core.DCB, &mut core.DWT);
        // From here on a stalled control tick resets the MCU: in the long
        // window until the end of init (chain detection and set-up, the
        // settings load, the USB start), then in the bridge's.
        let mut watchdog = Watchdog::start(dp.IWDG, &dp.DBGMCU);
        let pins = pins::configure(
            dp.GPIOA.split(&mut rcc),
            dp.GPIOB.split(&mut rcc),
            dp.GPIOC.split(&mut rcc),
        );
        let chain = ChainPeripherals {
            spi: dp.SPI1,
            tim: dp.TIM7,
            lines: pins.chain,
        };
        let (bus, stby) = start_chain(chain, pins.chain_stby, cx.local.chain_buffers, &mut rcc);

        let mut store = Store::new(platform::settings_flash(dp.FLASH));
        let uid = platform::unique_id();
        let (bridge, rate) = start_bridge(cx.local.bridge_slot, bus, &mut store, &boot, uid);
        // Connects at once; the host's traffic waits for the end of `init`.
        let otg = (dp.OTG_FS_GLOBAL, dp.OTG_FS_DEVICE, dp.OTG_FS_PWRCLK);
        let usb = platform::start_usb(otg, (pins.usb_dm, pins.usb_dp), &rcc, uid);
        let i2c_pins = (pins.host_i2c_scl, pins.host_i2c_sda);
        let i2c = start_i2c(dp.I2C1, i2c_pins, bridge, &mut rcc);
        let modbus_pins = (pins.modbus_tx, pins.modbus_rx, pins.modbus_de);
        let (rs485, timing) = start_modbus(dp.USART2, modbus_pins, bridge, &mut rcc);
        let io = IoExtPeripherals {
            spi: dp.SPI2,
            tim: dp.TIM1,
            dma1: dp.DMA1,
            dma2: dp.DMA2,
            lines: pins.ioext,
        };
        let ioext = platform::ioext_driver(io, cx.local.io_buffers, &mut rcc);
        let mut analog = Analog::new(dp.ADC1, pins.supply_sense, &mut rcc);
        bridge.on_analog(analog.sample());
        let tick = start_tasks(dp.TIM2, rate, &mut rcc);

        let (bytes_in, bytes_seen) = rtic_sync::make_signal!(());
        let (io_actions, io_next) = rtic_sync::make_channel!(Action, IO_ACTIONS);
        let (io_ended_spi, io_ended) = rtic_sync::make_channel!((), 2);
        let io_ended_bit = io_ended_spi.clone();
        // Last: the bridge's window (short), with the first control tick at
        // most one period away.
        arm_watchdog(&mut watchdog, bridge);
        (
            Shared {
                bridge,
                rs485,
                modbus: RtuServer::new(timing),
                i2c,
                i2c_proto: I2cSlave::new(),
                ioext,
                watchdog,
            },
            Local {
                tick,
                clock: TickClock::new(rate),
                rate,
                led: pins.led,
                stby: Some(stby),
                analog,
                store,
                bytes_in,
                bytes_seen,
                usb,
                io_actions,
                io_pending: None,
                io_next,
                io_ended,
                io_ended_spi,
                io_ended_bit,
            },
        )
    }

    /// What the last run left behind, read before anything else.
    struct Boot {
        /// The restart target the last run asked for (`.uninit` word).
        handoff: Option<ResetTarget>,
        /// RCC_CSR's reset flags, decoded (and cleared).
        reset_cause: ResetCause,
    }

    /// Start-up step 1: the handoff word first (ST's ROM bootloader wants
    /// the MCU as a reset leaves it: clocks, IWDG), the reset cause, then
    /// the clock tree, the monotonic and the cycle counter.
    fn start_clocks(
        rcc: stm32f4xx_hal::pac::RCC,
        syscfg: &stm32f4xx_hal::pac::SYSCFG,
        syst: cortex_m::peripheral::SYST,
        dcb: &mut cortex_m::peripheral::DCB,
        dwt: &mut cortex_m::peripheral::DWT,
    ) -> (stm32f4xx_hal::rcc::Rcc, Boot) {
        let handoff = mcu::take_handoff();
        if handoff == Some(ResetTarget::RomDfu) {
            platform::rom_bootloader(&rcc, syscfg);
        }
        let reset_cause = ResetCause::from_rcc_csr(platform::take_reset_flags(&rcc));
        let rcc = platform::freeze_clocks(rcc);
        let sysclk = rcc.clocks.sysclk().raw();
        info!(
            "stepbridge on {=str}: build {=u32:08x}, SYSCLK {=u32} Hz, reset cause {}, handoff {}",
            platform::NAME,
            firmware::BUILD_ID,
            sysclk,
            reset_cause,
            handoff
        );
        // `start` asserts a whole number of cycles per tick: 168 MHz is.
        let systick_hz = platform::systick_hz(&rcc);
        Mono::start(syst, systick_hz.saturating_sub(systick_hz % clock::MONO_HZ));
        platform::enable_stopwatch(dcb, dwt);
        let boot = Boot {
            handoff,
            reset_cause,
        };
        (rcc, boot)
    }

    /// The chips' reset pulse (STBY/RESET is already low,
    /// `pins::configure`), then their wake-up time before the first byte.
    fn release_chain(stby: &mut pins::ChainStby, sysclk: u32) {
        delay_ms(RESET_PULSE_MS, sysclk);
        stby.set_high();
        delay_ms(WAKE_UP_MS, sysclk);
    }

    /// Start-up step 2: the chain's driver (SPI1, TIM7, DMA2), then the
    /// chips out of reset.
    fn start_chain(
        chain: ChainPeripherals,
        mut stby: pins::ChainStby,
        buffers: &'static mut ChainBuffers,
        rcc: &mut stm32f4xx_hal::rcc::Rcc,
    ) -> (ChainLink, pins::ChainStby) {
        let bus = platform::chain_driver(chain, buffers, rcc);
        release_chain(&mut stby, rcc.clocks.sysclk().raw());
        (bus, stby)
    }

    /// Start-up step 3: the settings, chain detection and set-up, the tick
    /// rate, and what the bridge reports about this start.
    fn start_bridge(
        slot: &'static mut Option<Bridge<ChainLink>>,
        bus: ChainLink,
        store: &mut Store<SettingsFlash>,
        boot: &Boot,
        uid: [u32; 3],
    ) -> (&'static mut Bridge<ChainLink>, Rate) {
        let (settings, source) = load_settings(store);
        // A chain whose batch and computation do not fit the build's tick
        // runs at a slower one (a skipped tick would run the motors slow).
        let (built, rate) = Bridge::new_fitted_with(
            bus,
            PowerStage::REFERENCE,
            settings,
            source,
            TICK_HZ,
            platform::tick_need,
        );
        let bridge = slot.insert(built);
        match bridge.chain_error() {
            None => info!("chain: {=usize} powerSTEP01", bridge.axes()),
            Some(e) => error!("chain: detection failed ({}), running with 0 axes", e),
        }
        let need = platform::tick_need(bridge.axes());
        if rate.derated {
            warn!(
                "control tick: {=u32} Hz instead of {=u32} Hz: {=usize} chips need {=u64} us per tick ({=u64} us overlapped)",
                rate.hz,
                TICK_HZ,
                bridge.axes(),
                need.serial_ns / 1000,
                need.overlapped_ns / 1000
            );
        }
        if rate.overlapped {
            info!(
                "control tick: overlapped at {=u32} Hz: {=usize} chips need {=u64} us in a row, {=u64} us overlapped",
                rate.hz,
                bridge.axes(),
                need.serial_ns / 1000,
                need.overlapped_ns / 1000
            );
        }
        bridge.set_reset_cause(boot.reset_cause);
        bridge.set_build_id(firmware::BUILD_ID);
        bridge.set_unique_id(uid);
        if boot.handoff == Some(ResetTarget::BootMode) {
            bridge.enter_boot_mode();
            warn!("boot mode (USB 0x02): every axis asleep, USB answers; 0x02 restarts the application");
        }
        (bridge, rate)
    }

    /// Start-up step 4a: the PoStep60 I2C slave at the bridge's addresses.
    fn start_i2c(
        i2c1: pins::HostI2c,
        lines: (pins::HostI2cScl, pins::HostI2cSda),
        bridge: &Bridge<ChainLink>,
        rcc: &mut stm32f4xx_hal::rcc::Rcc,
    ) -> I2cSlaveDriver {
        let (primary, secondary) = bridge.i2c_addresses();
        I2cSlaveDriver::new(i2c1, lines, primary, secondary, rcc)
    }

    /// Start-up step 4b: the RS-485 line at the settings' serial format,
    /// and the Modbus timing that goes with it.
    fn start_modbus(
        usart: pins::ModbusUsart,
        (tx, rx, de): (pins::ModbusTx, pins::ModbusRx, pins::ModbusDe),
        bridge: &Bridge<ChainLink>,
        rcc: &mut stm32f4xx_hal::rcc::Rcc,
    ) -> (Rs485, Timing) {
        let serial = bridge.serial();
        let timing = Timing::for_serial(serial);
        let rs485 = Rs485::new(usart, (tx, rx), de, serial, rcc);
        log_modbus(&rs485, bridge, timing);
        (rs485, timing)
    }

    /// Start-up step 5: the control timer at the fitted rate and the two
    /// async tasks.
    fn start_tasks(
        tim: pins::ControlTimer,
        rate: Rate,
        rcc: &mut stm32f4xx_hal::rcc::Rcc,
    ) -> TickTimer {
        let mut tick = TickTimer::new(tim, rcc);
        if let Err(e) = tick.start(rate.hz) {
            error!("control timer: start failed ({}), no control loop", e);
        }
        if modbus_server::spawn().is_err() {
            error!("modbus: server task spawn failed");
        }
        if ioext_run::spawn().is_err() {
            error!("ioext: task spawn failed");
        }
        tick
    }

    /// Waits for the next interrupt the platform's way (`platform::idle_wait`:
    /// a spin on the board, `wfi` under QEMU).
    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            platform::idle_wait();
        }
    }

    /// The control loop: the watchdog fed in the bridge's window, one
    /// bridge tick (one chain batch for every axis, pipelined: the previous
    /// batch's replies in, this tick's batch out by DMA), then STBY, LED,
    /// the slow jobs at 10 Hz and a USB poll; the tick's duration goes to
    /// the bridge's diagnostics.
    #[task(
        binds = TIM2,
        priority = 3,
        shared = [bridge, watchdog],
        local = [
            tick, clock, rate, led, stby, io_actions, io_pending,
            rx: Frames = [[0; MAX_DEVICES]; MAX_WINDOWS],
            chain_failing: bool = false,
            watchdog_failing: bool = false,
        ]
    )]
    fn control_tick(mut cx: control_tick::Context) {
        let stopwatch = Stopwatch::start();
        cx.local.tick.acknowledge();
        // The window before anything is planned: short whenever an axis may
        // move. A change (after a save) waits up to 5 LSI cycles; one that
        // fails is tried again next tick.
        let window = cx.shared.bridge.lock(|b| b.watchdog_window());
        let fed = cx.shared.watchdog.lock(|w| w.feed_in(window));
        match (fed, *cx.local.watchdog_failing) {
            (Err(e), false) => error!("watchdog: {} window not in effect ({})", window, e),
            (Ok(()), true) => info!("watchdog: {} window in effect", window),
            _ => {}
        }
        *cx.local.watchdog_failing = fed.is_err();
        // The bridge's clock is milliseconds: above 1 kHz several ticks
        // share one.
        let (now, housekeeping_due) = cx.local.clock.tick();
        let rate = *cx.local.rate;
        // The batch started by the previous tick (its replies copied out of
        // the DMA buffer; past its deadline it is stopped as a timeout).
        let now_us = clock::now_us();
        let rx = cx.local.rx;
        let previous = platform::with_chain(|c| c.poll(now_us, rx)).unwrap_or(BatchState::Idle);
        if let BatchState::Done(result) = &previous {
            if let (Err(e), false) = (result, *cx.local.chain_failing) {
                warn!("chain: batch failed ({})", e);
            }
            *cx.local.chain_failing = result.is_err();
        }
        // End it, plan this tick, start its batch (Bridge::tick_pipelined;
        // overlapped: start the planned batch, end the previous one, plan
        // the next); a batch still on the bus skips the tick as an overrun.
        let (on, dead, io) = cx.shared.bridge.lock(|b| {
            // The bridge's handle asks the one driver to start the batch.
            b.tick_pipelined(now, previous, |plan, link| {
                link.with(|c| c.start(plan, now_us))
                    .unwrap_or(Err(ChainSpiError::Busy))
            });
            (b.led_on(now), b.chain_dead(), b.take_io_action())
        });
        hand_over_io(cx.local.io_actions, cx.local.io_pending, io);
        // The bridge can no longer stop the motors over SPI: hold every chip
        // in reset, bridges off. The pin is given up with it (a dropped HAL
        // pin keeps its mode and level), so nothing can drive STBY high
        // again until the MCU resets.
        if dead {
            if let Some(mut pin) = cx.local.stby.take() {
                pin.set_low();
                error!("chain: dead, STBY low: every chip held in reset until the MCU resets");
            }
        }
        cx.local.led.set_state(on.into());
        if housekeeping_due {
            // Still busy with the previous round: skip this one.
            let _ = housekeeping::spawn();
        }
        // The USB task, at the lowest priority: the 0xA0 stream's reports
        // are due by time, not by an OTG interrupt.
        rtic::pend(Interrupt::OTG_FS);
        let duration_us = stopwatch.elapsed_us();
        // Free: this task's priority is the bridge's ceiling.
        cx.shared
            .bridge
            .lock(|b| b.tick_timing(duration_us, rate.us));
    }

    /// A chain window's bytes are in (DMA2 stream 0, SPI1_RX, transfer
    /// complete) or a stream failed: CS up, next window armed and its gap
    /// started, or the batch over (`drivers::chain_spi`).
    #[task(binds = DMA2_STREAM0, priority = 5)]
    fn chain_window_end(_: chain_window_end::Context) {
        platform::with_chain(|c| c.on_dma());
    }

    /// TIM7's one pulse: a chain window's CS-high gap is over (CS down,
    /// set-up time started) or its set-up time is (bytes out).
    #[task(binds = TIM7, priority = 5)]
    fn chain_gap_end(_: chain_gap_end::Context) {
        platform::with_chain(|c| c.on_timer());
    }

    /// The I/O extension's driver side: start each action the control tick
    /// hands over, then wait for the DMA task to end the transfer, at most
    /// the plan's timeout; past it, stop the transfer and report a failure.
    #[task(priority = 2, shared = [ioext, bridge], local = [io_next, io_ended])]
    async fn ioext_run(mut cx: ioext_run::Context) {
        loop {
            let Ok(action) = cx.local.io_next.recv().await else {
                error!("ioext: action channel closed");
                return;
            };
            // An end reported after the last wait gave up.
            while cx.local.io_ended.try_recv().is_ok() {}
            let started = cx.shared.ioext.lock(|d| d.run(&action));
            let ended = match (started, action) {
                (Started::Running, Action::Transfer(plan)) => {
                    let deadline = clock::now_us().saturating_add(plan.timeout_us());
                    let wait = cx.local.io_ended.recv();
                    match Mono::timeout_at(clock::instant_at_us(deadline), wait).await {
                        Ok(_) => None,
                        Err(_) => cx.shared.ioext.lock(|d| d.abort()),
                    }
                }
                (Started::Ended(result), _) => Some(result),
                (Started::Running, Action::Disable) | (Started::Released, _) => None,
            };
            if let Some(result) = ended {
                report_io(&mut cx.shared.bridge, result);
            }
        }
    }

    /// SPI engine: DMA1 stream 3 (SPI2_RX) complete or in error.
    #[task(binds = DMA1_STREAM3, priority = 2, shared = [ioext, bridge], local = [io_ended_spi])]
    fn ioext_spi_end(mut cx: ioext_spi_end::Context) {
        if let Some(result) = cx.shared.ioext.lock(|d| d.on_interrupt()) {
            report_io(&mut cx.shared.bridge, result);
            let _ = cx.local.io_ended_spi.try_send(());
        }
    }

    /// Bit engine: DMA2 stream 2 (TIM1_CH2 samples) complete or in error.
    #[task(binds = DMA2_STREAM2, priority = 2, shared = [ioext, bridge], local = [io_ended_bit])]
    fn ioext_bit_end(mut cx: ioext_bit_end::Context) {
        if let Some(result) = cx.shared.ioext.lock(|d| d.on_interrupt()) {
            report_io(&mut cx.shared.bridge, result);
            let _ = cx.local.io_ended_bit.try_send(());
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
                // The diagnostics' Modbus counters (0x0300..).
                let stats = server.stats();
                bridge.lock(|b| b.set_modbus_stats(stats));
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
    #[task(binds = I2C1_EV, priority = 2, shared = [bridge, i2c, i2c_proto])]
    fn i2c_event(mut cx: i2c_event::Context) {
        let (bridge, proto) = (&mut cx.shared.bridge, cx.shared.i2c_proto);
        cx.shared.i2c.lock(|i2c| {
            i2c.on_event(proto, &mut LockedTarget(&mut *bridge));
            apply_address_change(bridge, i2c);
        });
    }

    /// I2C1 errors: the master's NACK ending a read, bus errors.
    #[task(binds = I2C1_ER, priority = 2, shared = [bridge, i2c, i2c_proto])]
    fn i2c_error(mut cx: i2c_error::Context) {
        let (bridge, proto) = (&mut cx.shared.bridge, cx.shared.i2c_proto);
        cx.shared
            .i2c
            .lock(|i2c| i2c.on_error(proto, &mut LockedTarget(bridge)));
    }

    /// Slow jobs at the lowest priority: ADC samples (~71 µs of blocking
    /// conversions), a pending settings save (flash programming stalls the
    /// CPU; the bridge hands out the image only when every axis is at rest),
    /// and a requested system reset. Save and reset wait until no Modbus
    /// response is going out (both would cut it short); the check and the
    /// take are one lock, so a response started in between cannot slip by.
    /// A handed-out save first puts the watchdog in the window the bridge
    /// now asks for (long): the erase starts only once it is in effect.
    #[task(priority = 1, shared = [bridge, rs485, watchdog], local = [analog, store, image: [u8; IMAGE_LEN] = [0; IMAGE_LEN]])]
    async fn housekeeping(mut cx: housekeeping::Context) {
        let sample = cx.local.analog.sample();
        let image = cx.local.image;
        let (save, reset, window) =
            (&mut cx.shared.bridge, &mut cx.shared.rs485).lock(|b, line| {
                b.on_analog(sample);
                let (save, reset) = if line.is_sending() {
                    (false, None)
                } else {
                    (b.take_save(image), b.take_reset())
                };
                (save, reset, b.watchdog_window())
            });
        if save {
            let ok = match cx.shared.watchdog.lock(|w| w.feed_in(window)) {
                Ok(()) => cx.local.store.save(image).is_ok(),
                Err(e) => {
                    error!(
                        "watchdog: {} window not in effect ({}), no erase",
                        window, e
                    );
                    false
                }
            };
            if ok {
                info!("settings: saved");
            } else {
                warn!("settings: save failed");
            }
            // From here on the bridge asks for the short window again; the
            // next control tick puts it in effect before it plans.
            cx.shared.bridge.lock(|b| b.saved(ok));
        }
        if let Some(target) = reset {
            info!("system reset requested ({})", target);
            // `init` of the next run reads it (ROM DFU, boot mode).
            mcu::store_handoff(target);
            cortex_m::peripheral::SCB::sys_reset();
        }
    }

    /// USB OTG FS (its interrupt, and pended by every control tick): poll
    /// the stack, OUT reports into the bridge, the bridge's next IN report
    /// into the endpoint. The bridge's USB entry points get the monotonic's
    /// ms (they only compare their own times: the stream's due time, an
    /// extension read's timeout). Each lock covers one report.
    #[task(binds = OTG_FS, priority = 1, shared = [bridge], local = [usb])]
    fn usb_hid(mut cx: usb_hid::Context) {
        let Some(usb) = cx.local.usb.as_mut() else {
            return;
        };
        let now_ms = clock::now_us() / 1_000;
        let bridge = &mut cx.shared.bridge;
        if usb.poll() == Link::Lost {
            // Bus reset, suspend, deconfigured: the stream and unread
            // responses go.
            bridge.lock(|b| b.on_usb_reset());
        }
        let mut report = [0u8; REPORT_LEN];
        while let Some(n) = usb.read_report(&mut report) {
            let bytes = report.get(..n).unwrap_or(&[]);
            bridge.lock(|b| b.on_usb_report(bytes, now_ms));
        }
        bridge.lock(|b| {
            if let Some(r) = b.usb_next(now_ms).copied() {
                if usb.write_report(&r.0) {
                    b.usb_sent();
                }
            }
        });
    }
}
