//! The board: every pin and peripheral assignment, and nothing else.
//!
//! This is the one place in the firmware that names a pin or a peripheral
//! instance. Other modules use the type aliases below, so moving a signal to
//! another pin is a change to this file and to the table in `docs/pins.md`:
//! `host-tests/tests/pin_table.rs` reads both (and every pin row of the
//! README and `docs/`) and fails on any difference — a signal's pin, its
//! alternate function, the `*_PIN` numbers, a reserved pin in use.
//!
//! Active levels are those of the powerSTEP01 pins: STBY/RESET, FLAG and BUSY
//! are active low; FLAG and BUSY are open-drain outputs of every chip, wired
//! together (wired-OR of "some device has an alarm" / "some device is busy"),
//! so the MCU provides the pull-ups.

use stm32f4xx_hal::gpio::{
    self, Alternate, Analog, Input, OpenDrain, Output, PinState, PushPull, Speed,
};
use stm32f4xx_hal::pac;

/// HSE crystal on OSC_IN/OSC_OUT.
pub const HSE_HZ: u32 = 8_000_000;
/// SYSCLK from HSE through the main PLL (the F405's maximum).
pub const SYSCLK_HZ: u32 = 168_000_000;

// ---------------------------------------------------------------------------
// Peripherals
// ---------------------------------------------------------------------------

/// SPI master of the powerSTEP01 daisy chain (on APB2). Its bytes move by
/// DMA2 stream 3 channel 3 (SPI1_TX) and stream 0 channel 3 (SPI1_RX); a
/// window ends in the `DMA2_STREAM0` interrupt (the `binds =` of the chain
/// task in `main.rs` must follow). DMA2 itself is [`IoExtTimerDma`]'s
/// singleton; the chain driver uses only those two streams.
pub type ChainSpi = pac::SPI1;
/// Times the chain's CS-high gap (t_disCS) and CS set-up (t_setCS) between
/// DMA windows, one pulse each (on APB1, 84 MHz timer clock). Its interrupt
/// is `TIM7` (the `binds =` of the chain's timer task in `main.rs` must
/// follow this alias). A basic timer: no pins, no DMA request needed.
pub type ChainGapTimer = pac::TIM7;
/// Control-loop timer. Its update interrupt is bound to the `control_tick`
/// task in `main.rs` (`binds = TIM2`: RTIC needs the interrupt's literal name,
/// so that attribute must follow this alias).
///
/// `init` takes both instances out of `pac::Peripherals` by field name; the
/// aliases make a mismatch there a compile error.
pub type ControlTimer = pac::TIM2;
/// PoStep60 I2C slave (on APB1). Its event and error interrupts are
/// `I2C1_EV` / `I2C1_ER` (the `binds =` of the I2C tasks in `main.rs` must
/// follow this alias, as for [`ControlTimer`]).
pub type HostI2c = pac::I2C1;
/// ADC for the motor supply, the internal temperature sensor and VREFINT
/// (only ADC1 reaches the internal channels 16 and 17).
pub type SenseAdc = pac::ADC1;
/// Modbus RTU on RS-485 (on APB1). Its interrupt is `USART2` (the `binds =`
/// of the Modbus task in `main.rs` must follow this alias). Under QEMU's
/// `netduinoplus2` it is the second `-serial` backend.
pub type ModbusUsart = pac::USART2;
/// USB OTG FS (global, device and power/clock register blocks): the
/// PoStep60 USB HID device. Its interrupt is `OTG_FS` (the `binds =` of the
/// USB task in `main.rs` must follow this alias).
pub type UsbOtg = (pac::OTG_FS_GLOBAL, pac::OTG_FS_DEVICE, pac::OTG_FS_PWRCLK);
/// The I/O extension's SPI engine (on APB1, 42 MHz): SPI2 master, moved by
/// [`IoExtSpiDma`].
pub type IoExtSpi = pac::SPI2;
/// The I/O extension's bit engine for slow clocks (on APB2, 168 MHz timer
/// clock): TIM1, CH1N makes SCK, CC2/CC3 pace [`IoExtTimerDma`].
pub type IoExtTimer = pac::TIM1;
/// DMA1: stream 4 channel 0 = SPI2_TX, stream 3 channel 0 = SPI2_RX. The
/// SPI engine ends in the `DMA1_STREAM3` interrupt (the `binds =` of the
/// I/O-extension task in `main.rs` must follow this alias).
pub type IoExtSpiDma = pac::DMA1;
/// DMA2: stream 6 channel 6 = TIM1_CH3 (MOSI table → GPIOB BSRR), stream 2
/// channel 6 = TIM1_CH2 (GPIOB IDR → MISO samples). Only DMA2 reaches the
/// GPIO ports (AHB1). The bit engine ends in `DMA2_STREAM2`. Streams 0 and
/// 3 belong to the chain ([`ChainSpi`]).
pub type IoExtTimerDma = pac::DMA2;

// ---------------------------------------------------------------------------
// Pins in use (configured by [`configure`])
// ---------------------------------------------------------------------------

/// SPI1 SCK, AF5 → CK of every chip.
pub type ChainSck = gpio::PA5<Alternate<5>>;
/// SPI1 MISO, AF5, internal pull-up ← SDO of the last chip in the chain.
pub type ChainMiso = gpio::PA6<Alternate<5>>;
/// SPI1 MOSI, AF5 → SDI of chip 0.
pub type ChainMosi = gpio::PA7<Alternate<5>>;
/// Chain chip select (software NSS), push-pull, idle high, common to all chips.
pub type ChainCs = gpio::PA4<Output<PushPull>>;
/// GPIOA pin number of [`ChainCs`] (the chain driver drives it through
/// GPIOA_BSRR from its interrupts; it must stay on port A).
pub const CHAIN_CS_PIN: u8 = 4;
/// Chain STBY/RESET, push-pull, active low: low holds every chip in reset
/// (power bridges off). Driven low from `configure` on; until then (reset,
/// boot) the pin floats, so the board needs a pull-down on STBY to keep the
/// chips in reset — through a watchdog reset too. `failsafe` drives it
/// directly (GPIOC's BSRR), so it must stay on port C.
pub type ChainStby = gpio::PC4<Output<PushPull>>;
/// Chain FLAG, input with pull-up; open-drain wired-OR, low = some alarm.
pub type ChainFlag = gpio::PC5<Input>;
/// Chain BUSY, input with pull-up; open-drain wired-OR, low = some chip busy.
pub type ChainBusy = gpio::PB0<Input>;
/// Status LED, push-pull, high = on.
pub type StatusLed = gpio::PB12<Output<PushPull>>;
/// I2C1 SCL, AF4, open drain (the bus has its pull-ups): PoStep60 I2C slave.
pub type HostI2cScl = gpio::PB6<Alternate<4, OpenDrain>>;
/// I2C1 SDA, AF4, open drain: PoStep60 I2C slave.
pub type HostI2cSda = gpio::PB7<Alternate<4, OpenDrain>>;
/// ADC1_IN0, analog: the motor supply through the board divider (÷20).
pub type SupplySense = gpio::PA0<Analog>;
/// USART2 TX (AF7) → DI of the RS-485 transceiver.
pub type ModbusTx = gpio::PA2<Alternate<7>>;
/// USART2 RX (AF7), internal pull-up ← RO of the RS-485 transceiver (RO is
/// high-Z while the driver is enabled when RE̅ is tied to DE: the pull-up
/// keeps the line idle-high then).
pub type ModbusRx = gpio::PA3<Alternate<7>>;
/// RS-485 driver enable (DE, and RE̅ tied to it), push-pull: low = receive,
/// high = transmit. Driven low from `configure` on; until then (reset, boot)
/// the pin floats, so the board needs a pull-down on DE to keep the
/// transceiver off the bus.
pub type ModbusDe = gpio::PA1<Output<PushPull>>;
/// USB OTG FS D− (AF10); the core's PHY drives it once USB starts.
pub type UsbDm = gpio::PA11<Alternate<10>>;
/// USB OTG FS D+ (AF10); the core pulls it up (1.5 kΩ) to connect.
pub type UsbDp = gpio::PA12<Alternate<10>>;
/// I/O extension SCK: a floating input until the first transfer; the
/// driver (`drivers::ioext_spi`) then switches it between AF5 (SPI2_SCK)
/// and AF1 (TIM1_CH1N) and pulls it towards the plan's CPOL.
pub type IoExtSck = gpio::PB13<Input>;
/// I/O extension MISO, input with a pull-up; from the first transfer on
/// AF5 (SPI2_MISO), which the bit engine reads through GPIOB_IDR (the
/// input stage works in AF mode too). ← QH of the first 74HC165.
pub type IoExtMiso = gpio::PB14<Input>;
/// I/O extension MOSI: a floating input until the first transfer; then AF5
/// (SPI2_MOSI) for the SPI engine, a push-pull output written through
/// GPIOB_BSRR for the bit engine. → SER of the first 74HC595.
pub type IoExtMosi = gpio::PB15<Input>;
/// I/O extension CS, push-pull, idle high; **needs an external pull-up**
/// (it floats from reset until `configure`). → RCLK of the '595s, and
/// through an inverter → SH/LD of the '165s (`docs/ioext.md`).
pub type IoExtCs = gpio::PB11<Output<PushPull>>;
/// GPIOB pin numbers of the bit engine's DMA table and samples (they must
/// match [`IoExtMosi`] / [`IoExtMiso`], and both must be on port B).
pub const IOEXT_MOSI_PIN: u8 = 15;
pub const IOEXT_MISO_PIN: u8 = 14;
/// GPIOB pin number of [`IoExtSck`] (its alternate function is switched).
pub const IOEXT_SCK_PIN: u8 = 13;
/// GPIOB pin number of [`IoExtCs`] (the driver writes it through
/// GPIOB_BSRR).
pub const IOEXT_CS_PIN: u8 = 11;

/// The configured pins of everything in use.
pub struct Pins {
    /// SPI1's lines and CS, for the chain's driver.
    pub chain: ChainLines,
    pub chain_stby: ChainStby,
    // FLAG/BUSY are configured (inputs with pull-ups, so the open-drain lines
    // are defined) but not read: the bridge reads STATUS every 2 ms instead.
    #[allow(dead_code)]
    pub chain_flag: ChainFlag,
    #[allow(dead_code)]
    pub chain_busy: ChainBusy,
    pub led: StatusLed,
    pub host_i2c_scl: HostI2cScl,
    pub host_i2c_sda: HostI2cSda,
    pub supply_sense: SupplySense,
    pub modbus_tx: ModbusTx,
    pub modbus_rx: ModbusRx,
    pub modbus_de: ModbusDe,
    pub usb_dm: UsbDm,
    pub usb_dp: UsbDp,
    /// SPI2's lines and CS, for the I/O extension's driver.
    pub ioext: IoExtLines,
}

/// The chain's SPI1 lines and chip select, as the chain's driver takes them.
#[derive(Debug)]
pub struct ChainLines {
    pub sck: ChainSck,
    pub miso: ChainMiso,
    pub mosi: ChainMosi,
    pub cs: ChainCs,
}

/// The I/O extension's SPI2 lines and chip select, as its driver takes them.
#[derive(Debug)]
pub struct IoExtLines {
    pub sck: IoExtSck,
    pub miso: IoExtMiso,
    pub mosi: IoExtMosi,
    pub cs: IoExtCs,
}

/// Configure every pin in use from the split GPIO ports. Safe states first:
/// CS high (deselected), STBY low (chips held in reset until the caller
/// releases them), LED off, RS-485 DE low (receive), I/O extension CS
/// high with SCK/MOSI undriven (the driver takes them at its first
/// transfer); the I2C pins are
/// released (open drain, and the I2C peripheral stays off until its driver
/// starts it); the USB pins go to OTG FS's AF10, where the core's PHY keeps
/// them released until USB starts. Pins not named here (PB1, reserved for a
/// STEP pass-through, among them) stay in their reset mode.
pub fn configure(
    gpioa: gpio::gpioa::Parts,
    gpiob: gpio::gpiob::Parts,
    gpioc: gpio::gpioc::Parts,
) -> Pins {
    let (host_i2c_scl, host_i2c_sda) = host_i2c_pins(gpiob.pb6, gpiob.pb7);
    let (modbus_tx, modbus_rx, modbus_de) = modbus_pins(gpioa.pa2, gpioa.pa3, gpioa.pa1);
    Pins {
        chain: ChainLines {
            // SCK ≤ 4 MHz: medium slew is ample and keeps edges on the chain cable soft.
            sck: gpioa.pa5.into_alternate().speed(Speed::Medium),
            // SDO is high-Z while CS is high: the pull-up keeps MISO defined
            // (reads 0xFF with no chain attached).
            miso: gpioa.pa6.into_alternate().internal_pull_up(true),
            mosi: gpioa.pa7.into_alternate().speed(Speed::Medium),
            cs: gpioa.pa4.into_push_pull_output_in_state(PinState::High),
        },
        chain_stby: gpioc.pc4.into_push_pull_output_in_state(PinState::Low),
        chain_flag: gpioc.pc5.into_pull_up_input(),
        chain_busy: gpiob.pb0.into_pull_up_input(),
        led: gpiob.pb12.into_push_pull_output_in_state(PinState::Low),
        host_i2c_scl,
        host_i2c_sda,
        supply_sense: gpioa.pa0.into_analog(),
        modbus_tx,
        modbus_rx,
        modbus_de,
        // Full speed, 12 Mbit/s: the fastest slew.
        usb_dm: gpioa.pa11.into_alternate().speed(Speed::VeryHigh),
        usb_dp: gpioa.pa12.into_alternate().speed(Speed::VeryHigh),
        ioext: IoExtLines {
            cs: gpiob.pb11.into_push_pull_output_in_state(PinState::High),
            sck: gpiob.pb13.into_floating_input(),
            // QH of a '165 is always driven; the pull-up keeps MISO defined
            // with nothing attached.
            miso: gpiob.pb14.into_pull_up_input(),
            mosi: gpiob.pb15.into_floating_input(),
        },
    }
}

/// The RS-485 lines: TX and RX on USART2's AF7 (RX with its pull-up), DE
/// low (receive). ≤ 19200 baud: low slew is ample and keeps the cable quiet.
pub fn modbus_pins(tx: gpio::PA2, rx: gpio::PA3, de: gpio::PA1) -> (ModbusTx, ModbusRx, ModbusDe) {
    (
        tx.into_alternate().speed(Speed::Low),
        rx.into_alternate().internal_pull_up(true),
        de.into_push_pull_output_in_state(PinState::Low)
            .speed(Speed::Low),
    )
}

/// The host I2C lines: AF4, open drain, no internal pull-up (the ~40 kΩ
/// internal pull-ups are far too weak for 400 kHz; the bus brings its own).
/// Low slew rate: ample for 400 kHz, and the falling edges stay well within
/// the Fm fall-time window (20 + 0.1·Cb … 300 ns).
pub fn host_i2c_pins(scl: gpio::PB6, sda: gpio::PB7) -> (HostI2cScl, HostI2cSda) {
    (
        scl.into_alternate_open_drain()
            .internal_pull_up(false)
            .speed(Speed::Low),
        sda.into_alternate_open_drain()
            .internal_pull_up(false)
            .speed(Speed::Low),
    )
}
