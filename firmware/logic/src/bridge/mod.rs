//! The bridge: the one object the firmware owns. It holds the chain, one
//! axis and one emulated PoStep60 per chip, the settings and the bus-facing
//! state, and offers `tick(now)` for the control loop and `on_*` / trait
//! entry points for bus events.
//!
//! # What it guarantees
//!
//! * **Addresses** (the product rules (`docs/PRODUCT.md`)): axis k answers `base + k`. On I2C the primary
//!   own address (OAR1) is axis 0's and the secondary (OAR2) axis 1's; the
//!   extension command 0x70 selects another axis for the following commands
//!   on that address. An address change (0x04) sent to axis k moves the base
//!   so that axis k gets the new address; it takes effect when the write has
//!   ended and survives a reset only after Write settings.
//! * **Bad input** on any bus changes nothing and is counted in
//!   [`Diagnostics`]; reads after an unknown I2C command return zeros.
//! * **Saving** never happens implicitly. Write settings is accepted on
//!   every bus at any time (except while a save is being written) and takes
//!   the settings as they are when it is accepted; it is written once every
//!   axis rests ([`Bridge::take_save`] hands the image out only then), and
//!   until then it is visible as pending (diagnostics 0x0346 = 3). From the
//!   hand-out until [`Bridge::saved`] every request is refused (Busy),
//!   because erasing flash stalls the CPU — and with it the control loop —
//!   for up to 4 s, and no motor may start moving just before that. A
//!   second Write settings before the first is written replaces it.
//! * **The MCU's watchdog window** ([`Bridge::watchdog_window`]): short
//!   (tens of ms) whenever any axis may move, so a stalled control loop
//!   leaves a chip running on its last Run for no longer than that; long
//!   (seconds) only from [`Bridge::take_save`] to [`Bridge::saved`], while
//!   every axis is at rest and every request is refused, so the flash erase
//!   that stalls the CPU does not reset the MCU.
//! * **System reset** stops every axis at once and is handed out by
//!   [`Bridge::take_reset`] only when they have stopped.
//! * **Time** is passed in: `tick(now_ms)` once per control period.

use heapless::Vec;

use crate::ioext::{Action as IoAction, Clocks as IoClocks, IoExtension};
use crate::motion::{Axis, AxisConfig, AxisGroup};
use crate::postep60::analog::{self, AnalogSample};
use crate::postep60::settings::{Serial, Watchdog, WatchdogAction, IMAGE_LEN, WATCHED_BUSES};
use crate::postep60::{
    CommandError, Device, Effect, Inputs, PowerStage, Query, Request, Settings, Value,
};
use crate::powerstep::chain::{Chain, ChainBus, ChainError, Frames, Plan, MAX_DEVICES};
use crate::transport::i2c::I2cCommand;
use crate::transport::modbus::Stats as ModbusStats;

/// Where the settings in use came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SettingsSource {
    /// Loaded from the settings store.
    Stored,
    /// The store was empty: factory settings.
    FactoryEmpty,
    /// The store could not be read (corrupt, other format): factory settings.
    FactoryUnreadable,
}

/// What the MCU restarts into after [`Bridge::take_reset`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetTarget {
    /// The application, as at power-up (I2C/Modbus 0x60; USB 0x02 in boot mode).
    Application,
    /// The firmware's own boot mode (USB 0x02 once: the PoStep60's
    /// "once starts the bootloader").
    BootMode,
    /// ST's ROM DFU bootloader (USB extension 0xDF), for `dfu-util`.
    RomDfu,
}

/// The window the MCU's independent watchdog (IWDG) must have now
/// ([`Bridge::watchdog_window`]) — not the PoStep60 communication watchdog.
/// The firmware applies it (`drivers_core::iwdg::Window::of` gives the
/// timeouts); which one is needed is decided here.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WatchdogWindow {
    /// Tens of milliseconds: an axis may move, and a control loop that
    /// stops feeding must reset the MCU (and with it STBY: bridges off)
    /// before a chip runs far on its last Run.
    Short,
    /// Seconds: a settings save was handed out and its flash erase is
    /// about to stall the CPU, feeds included, for up to 4 s; every axis is
    /// at rest and every request is refused until [`Bridge::saved`].
    Long,
}

/// The buses a request can come on (the communication watchdog's index).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Bus {
    Modbus = 0,
    I2c = 1,
    Usb = 2,
}

/// Why the MCU last reset (from RCC_CSR, decoded by
/// [`ResetCause::from_rcc_csr`]; the one decoder of that register: the
/// firmware logs and reports this).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// No flag set, or the platform cannot tell (QEMU).
    Unknown = 0,
    /// Power-on or power-down reset.
    PowerOn = 1,
    /// The NRST pin (a debugger's reset, the reset button).
    Pin = 2,
    /// A watchdog expired (the firmware runs the independent one: the
    /// control tick stalled).
    Watchdog = 3,
    /// `SCB::sys_reset` (a "system reset" command, a restart into boot mode).
    Software = 4,
    Brownout = 5,
    /// Entering Standby/Stop when the option bytes forbid it.
    LowPower = 6,
}

impl ResetCause {
    /// RCC_CSR's reset flags (RM0090 7.3.21: LPWR 31, WWDG 30, IWDG 29,
    /// SFT 28, POR 27, PIN 26, BOR 25). A power-on sets POR, PIN and BOR
    /// together, so the more specific flags are looked at first.
    pub const fn from_rcc_csr(csr: u32) -> ResetCause {
        if csr & (1 << 30 | 1 << 29) != 0 {
            ResetCause::Watchdog
        } else if csr & 1 << 31 != 0 {
            ResetCause::LowPower
        } else if csr & 1 << 28 != 0 {
            ResetCause::Software
        } else if csr & 1 << 27 != 0 {
            ResetCause::PowerOn
        } else if csr & 1 << 25 != 0 {
            ResetCause::Brownout
        } else if csr & 1 << 26 != 0 {
            ResetCause::Pin
        } else {
            ResetCause::Unknown
        }
    }
}

/// The communication watchdog's state for one bus.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct BusWatch {
    /// When a valid request last arrived, ms.
    last_ms: u64,
    /// Tripped and not heard from since.
    tripped: bool,
    trips: u32,
}

/// Duration of the control tick as the firmware measured it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct TickTiming {
    last_us: u32,
    max_us: u32,
    overruns: u32,
    /// Ticks timed since the counters were cleared.
    ticks: u32,
    /// The period the last tick was timed against, µs.
    period_us: u32,
}

/// How the firmware runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RunMode {
    Application,
    /// After USB 0x02: USB answers (0x01 reports DEVICE_MODE 0xB0), every
    /// axis is asleep (bridges off) and every request is refused
    /// ([`CommandError::BootMode`]) until the next 0x02 restarts the application.
    Boot,
}

/// Counters of everything that went wrong or was refused.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Diagnostics {
    pub i2c_unknown: u32,
    pub i2c_short: u32,
    /// I2C writes with more bytes than their command takes (refused).
    pub i2c_long: u32,
    /// Requests a device refused (wrong mode, asleep, faulted, ignored values…).
    pub refused: u32,
    pub chain_errors: u32,
    /// Communication-watchdog trips, every bus together.
    pub watchdog_trips: u32,
    /// Chip resets / undervoltages detected, every axis together (each one
    /// latched UVLO in its axis's faults and re-ran the chip's setup).
    pub chip_resets: u32,
    /// Speed/acceleration settings clamped to what the chip can follow.
    pub limit_clamps: u32,
    pub saves: u32,
    pub save_errors: u32,
    /// USB OUT reports executed.
    pub usb_reports: u32,
    /// USB OUT reports ignored: wrong length, `OutDATA[63]` ≠ 0, 0xDF
    /// without its magic.
    pub usb_bad: u32,
    /// USB OUT reports with an unknown command.
    pub usb_unknown: u32,
    /// USB responses dropped because the host did not read them in time.
    pub usb_dropped: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq)]
    enum E {
        Empty,
        Corrupt,
    }

    #[test]
    fn a_readable_image_is_used() {
        let mut img = [0u8; IMAGE_LEN];
        let mut s = Settings::FACTORY;
        s.base_address = 9;
        s.to_image(&mut img);
        let got = boot_settings::<E>(Ok(&img[..]), |e| *e == E::Empty);
        assert_eq!(got, (s, SettingsSource::Stored));
    }

    #[test]
    fn an_empty_store_boots_factory_settings() {
        let got = boot_settings(Err(E::Empty), |e| *e == E::Empty);
        assert_eq!(got, (Settings::FACTORY, SettingsSource::FactoryEmpty));
    }

    #[test]
    fn an_unreadable_store_or_image_boots_factory_settings_and_says_so() {
        let got = boot_settings(Err(E::Corrupt), |e| *e == E::Empty);
        assert_eq!(got, (Settings::FACTORY, SettingsSource::FactoryUnreadable));
        let got = boot_settings::<E>(Ok(&[9, 9, 9][..]), |e| *e == E::Empty);
        assert_eq!(got, (Settings::FACTORY, SettingsSource::FactoryUnreadable));
    }
}

mod coord;
pub mod ext_space;
pub mod handoff;
mod i2c;
mod io;
mod modbus;
mod pipeline;
mod usb;

pub use crate::ext_space::ExtError;
pub use crate::powerstep::chain::BatchState;
pub use pipeline::PipelinedTick;

pub use usb::STREAM_PERIOD_MS;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Port {
    /// Axis the commands on this address go to.
    axis: u8,
    /// What a read returns.
    last: Option<I2cCommand>,
}

/// Settings to boot with, from what the settings store returned: the
/// stored image if it is readable, else the factory settings, and where they
/// came from (so a bad store is reported, not silently replaced).
pub fn boot_settings<E>(
    loaded: Result<&[u8], E>,
    empty: impl Fn(&E) -> bool,
) -> (Settings, SettingsSource) {
    match loaded {
        Ok(image) => match Settings::from_image(image) {
            Ok(s) => (s, SettingsSource::Stored),
            Err(_) => (Settings::FACTORY, SettingsSource::FactoryUnreadable),
        },
        Err(e) if empty(&e) => (Settings::FACTORY, SettingsSource::FactoryEmpty),
        Err(_) => (Settings::FACTORY, SettingsSource::FactoryUnreadable),
    }
}

/// Failed control ticks in a row after which the chain counts as dead.
pub const CHAIN_DEAD_TICKS: u32 = 10;

/// Highest I2C address a PoStep60 accepts.
pub const I2C_ADDRESS_MAX: u8 = 127;

/// The bridge.
#[derive(Clone)]
pub struct Bridge<B: ChainBus> {
    chain: Chain<B>,
    group: AxisGroup,
    devices: Vec<Device, MAX_DEVICES>,
    stage: PowerStage,
    base_address: u8,
    serial: Serial,
    supply: u16,
    temperature: u16,
    ports: [Port; 2],
    /// A Write settings accepted and not yet handed out: the settings as
    /// they were when it was accepted.
    pending_save: Option<Settings>,
    /// An image was handed out and is being written: requests wait. The
    /// settings it holds (what the store holds once it is written).
    saving: bool,
    writing: Option<Settings>,
    reset_pending: Option<ResetTarget>,
    addresses_changed: bool,
    run_mode: RunMode,
    /// The MCU's 96-bit unique id (USB serial number and 0x01's IAP_UID).
    uid: [u32; 3],
    /// The settings the store holds (USB 0x84 reads them).
    stored: Settings,
    usb: usb::UsbState,
    /// Time of the last control tick, ms.
    now_ms: u64,
    /// The communication watchdog: settings and state per bus.
    watchdog: [Watchdog; WATCHED_BUSES],
    watch: [BusWatch; WATCHED_BUSES],
    /// Per axis: bit per bus that last started motion on it.
    moved_by: [u8; MAX_DEVICES],
    timing: TickTiming,
    /// The overlapped tick's state ([`Bridge::tick_overlapped`]).
    overlap: pipeline::Overlap,
    reset_cause: ResetCause,
    build_id: u32,
    /// The Modbus server's counters as last handed over, and their values
    /// when the diagnostics were last cleared.
    modbus: ModbusStats,
    modbus_base: ModbusStats,
    /// Chip resets per axis when the diagnostics were last cleared.
    resets_base: [u32; MAX_DEVICES],
    /// 0 no save yet, 1 the last save succeeded, 2 it failed.
    last_save: u16,
    /// The Copley-style SPI I/O extension.
    io: IoExtension,
    /// Input levels the board's own pins last reported, per axis.
    board_inputs: [Inputs; MAX_DEVICES],
    /// What the extension's driver must do next (taken by the firmware).
    io_action: Option<IoAction>,
    chain_error: Option<ChainError<B::Error>>,
    /// Control ticks in a row whose chain batch failed.
    failed_ticks: u32,
    source: SettingsSource,
    /// The last refused request: axis and reason (diagnostics 0x0349).
    last_refusal: Option<(u8, CommandError)>,
    /// The coordinated move as the extension space describes it (0x08nn).
    coord: coord::CoordRegs,
    pub diag: Diagnostics,
}

impl<B: ChainBus> core::fmt::Debug for Bridge<B> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Bridge")
            .field("axes", &self.devices.len())
            .field("base_address", &self.base_address)
            .field("diag", &self.diag)
            .finish_non_exhaustive()
    }
}

impl<B: ChainBus> Bridge<B> {
    /// Detect the chain on `bus` and set up one axis per chip with
    /// `settings`. If the chain cannot be detected the bridge runs with no
    /// axes and [`Bridge::chain_error`] says why.
    pub fn new(
        bus: B,
        stage: PowerStage,
        settings: Settings,
        source: SettingsSource,
        tick_us: u32,
    ) -> Bridge<B> {
        let (chain, n, chain_error) = Self::detect(bus);
        Self::build(chain, n, chain_error, stage, settings, source, tick_us)
    }

    /// [`Bridge::new`] at the fastest tick rate up to `build_hz` that the
    /// detected chain fits ([`crate::rate::fit`]): the chain is detected once,
    /// and the axes are set up for the rate returned with the bridge.
    pub fn new_fitted(
        bus: B,
        stage: PowerStage,
        settings: Settings,
        source: SettingsSource,
        build_hz: u32,
    ) -> (Bridge<B>, crate::rate::Rate) {
        Self::new_fitted_with(bus, stage, settings, source, build_hz, crate::rate::need)
    }

    /// [`Bridge::new_fitted`] with the platform's cost of a streaming tick
    /// of `n` chips ([`crate::rate::fit_need`]): the QEMU image's
    /// simulated chips cost more than the board's bytes on SPI. The bridge
    /// ticks overlapped if the rate says so ([`Bridge::set_overlapped`]),
    /// and its batches take at most the rate's windows.
    pub fn new_fitted_with(
        bus: B,
        stage: PowerStage,
        settings: Settings,
        source: SettingsSource,
        build_hz: u32,
        need: fn(usize) -> crate::rate::Need,
    ) -> (Bridge<B>, crate::rate::Rate) {
        let (chain, n, chain_error) = Self::detect(bus);
        let rate = crate::rate::fit_need(build_hz, need(n));
        let mut bridge = Self::build(chain, n, chain_error, stage, settings, source, rate.us);
        bridge.set_overlapped(rate.overlapped);
        bridge.set_window_budget(usize::from(rate.windows));
        (bridge, rate)
    }

    /// The chain on `bus` and its length (0 and why, if detection failed).
    fn detect(bus: B) -> (Chain<B>, usize, Option<ChainError<B::Error>>) {
        let mut chain = Chain::new(bus);
        match chain.detect() {
            Ok(n) => (chain, n, None),
            Err(e) => (chain, 0, Some(e)),
        }
    }

    fn build(
        chain: Chain<B>,
        n: usize,
        chain_error: Option<ChainError<B::Error>>,
        stage: PowerStage,
        settings: Settings,
        source: SettingsSource,
        tick_us: u32,
    ) -> Bridge<B> {
        let mut group = AxisGroup::new();
        let mut devices = Vec::new();
        for s in settings.axes.iter().take(n) {
            let cfg = AxisConfig {
                tick_us,
                logical_shift: s.step_mode,
                step: stage.step,
                drive: stage.drive,
            };
            let mut device = Device::new(*s);
            let mut axis =
                Axis::new(cfg, device.limits()).with_chip_config(stage.config_register());
            device.clamp_limits(&mut axis);
            device.apply_tuning(&mut axis);
            axis.energize();
            let _ = group.push(axis);
            let _ = devices.push(device);
        }
        Bridge {
            chain,
            group,
            devices,
            stage,
            base_address: settings.base_address,
            serial: settings.serial,
            supply: 0,
            temperature: 0,
            ports: [
                Port {
                    axis: 0,
                    last: None,
                },
                Port {
                    axis: if n > 1 { 1 } else { 0 },
                    last: None,
                },
            ],
            pending_save: None,
            saving: false,
            writing: None,
            reset_pending: None,
            addresses_changed: false,
            run_mode: RunMode::Application,
            uid: [0; 3],
            stored: settings,
            usb: usb::UsbState::default(),
            now_ms: 0,
            watchdog: settings.watchdog,
            watch: [BusWatch::default(); WATCHED_BUSES],
            moved_by: [0; MAX_DEVICES],
            timing: TickTiming::default(),
            overlap: pipeline::Overlap::new(),
            reset_cause: ResetCause::Unknown,
            build_id: 0,
            modbus: ModbusStats::default(),
            modbus_base: ModbusStats::default(),
            resets_base: [0; MAX_DEVICES],
            last_save: 0,
            io: IoExtension::new(settings.io, IoClocks::BOARD),
            io_action: None,
            board_inputs: [Inputs::default(); MAX_DEVICES],
            chain_error,
            failed_ticks: 0,
            source,
            last_refusal: None,
            coord: coord::CoordRegs::default(),
            diag: Diagnostics::default(),
        }
    }

    /// Number of axes (= detected chips).
    pub fn axes(&self) -> usize {
        self.devices.len()
    }

    pub fn chain_error(&self) -> Option<&ChainError<B::Error>> {
        self.chain_error.as_ref()
    }

    pub fn settings_source(&self) -> SettingsSource {
        self.source
    }

    pub fn chain(&self) -> &Chain<B> {
        &self.chain
    }

    pub fn chain_mut(&mut self) -> &mut Chain<B> {
        &mut self.chain
    }

    pub fn axis(&self, k: usize) -> Option<&Axis> {
        self.group.axis(k)
    }

    pub fn device(&self, k: usize) -> Option<&Device> {
        self.devices.get(k)
    }

    pub fn power_stage(&self) -> &PowerStage {
        &self.stage
    }

    /// Address base: axis k answers `base + k`.
    pub fn base_address(&self) -> u8 {
        self.base_address
    }

    pub fn serial(&self) -> Serial {
        self.serial
    }

    /// I2C own addresses: (OAR1 for axis 0, OAR2 for axis 1 if there is one
    /// and it is a valid 7-bit address).
    pub fn i2c_addresses(&self) -> (u8, Option<u8>) {
        let second = self
            .base_address
            .checked_add(1)
            .filter(|a| *a <= I2C_ADDRESS_MAX && self.axes() > 1);
        (self.base_address, second)
    }

    /// True once after the addresses changed (reprogram the I2C own addresses).
    pub fn take_address_change(&mut self) -> bool {
        core::mem::take(&mut self.addresses_changed)
    }

    /// Once a reset was requested and every axis has stopped (the request
    /// stops them all first): what to restart into. The firmware keeps the
    /// target across the reset and starts in boot mode or jumps to the ROM
    /// bootloader accordingly.
    pub fn take_reset(&mut self) -> Option<ResetTarget> {
        if !self.group.is_settled() {
            return None;
        }
        self.reset_pending.take()
    }

    /// Stop every axis at once and restart into `target` once they rest.
    fn request_reset(&mut self, target: ResetTarget) {
        // A reset must not leave a chip running on its last Run while the
        // MCU restarts.
        self.reset_pending = Some(target);
        for i in 0..self.group.len() {
            if let Some(a) = self.group.axis_mut(i) {
                a.stop_now();
            }
        }
    }

    /// Run as the firmware's boot mode (after USB 0x02): every axis asleep,
    /// every request refused; USB keeps answering.
    pub fn enter_boot_mode(&mut self) {
        self.run_mode = RunMode::Boot;
        for (k, d) in self.devices.iter_mut().enumerate() {
            if let Some(a) = self.group.axis_mut(k) {
                let _ = d.apply(Request::RunSleep(0x0F), a, &self.stage);
            }
        }
    }

    pub fn run_mode(&self) -> RunMode {
        self.run_mode
    }

    /// The MCU's unique id (the firmware reads it at boot; QEMU has none).
    pub fn set_unique_id(&mut self, uid: [u32; 3]) {
        self.uid = uid;
    }

    pub fn unique_id(&self) -> [u32; 3] {
        self.uid
    }

    /// The settings image to store, once a save is pending and every axis is
    /// at rest. Report the outcome with [`Bridge::saved`].
    pub fn take_save(&mut self, out: &mut [u8; IMAGE_LEN]) -> bool {
        if self.pending_save.is_none() || !self.group.is_settled() {
            return false;
        }
        let Some(settings) = self.pending_save.take() else {
            return false;
        };
        // Until `saved`, every request is refused (Busy): nothing may start a
        // move while flash programming is about to stall the CPU.
        self.saving = true;
        settings.to_image(out);
        self.writing = Some(settings);
        true
    }

    /// Accept a save of the settings as they are now (module doc, "Saving").
    fn queue_save(&mut self) {
        self.pending_save = Some(self.settings());
    }

    /// A save was accepted and is not written yet (waiting for every axis
    /// to rest, or being written).
    pub fn save_pending(&self) -> bool {
        self.pending_save.is_some() || self.saving
    }

    /// The MCU watchdog's window the firmware must have in effect now
    /// ([`WatchdogWindow`]): [`WatchdogWindow::Long`] exactly from a
    /// [`Bridge::take_save`] that handed out an image (every axis at rest,
    /// every request refused from then on) until [`Bridge::saved`];
    /// [`WatchdogWindow::Short`] at every other moment, so whenever an axis
    /// may move. The firmware applies it before each control tick plans
    /// (nothing moves but through a tick's batch), and between `take_save`
    /// and the erase (which must not start before the long window is in
    /// effect).
    pub fn watchdog_window(&self) -> WatchdogWindow {
        if self.saving {
            WatchdogWindow::Long
        } else {
            WatchdogWindow::Short
        }
    }

    /// Outcome of a save handed out by [`Bridge::take_save`].
    pub fn saved(&mut self, ok: bool) {
        self.saving = false;
        let written = self.writing.take();
        self.last_save = if ok { 1 } else { 2 };
        if ok {
            self.stored = written.unwrap_or_else(|| self.settings());
            self.diag.saves = self.diag.saves.saturating_add(1);
        } else {
            self.diag.save_errors = self.diag.save_errors.saturating_add(1);
        }
    }

    /// Current settings of every axis (what Write settings stores).
    pub fn settings(&self) -> Settings {
        let mut s = Settings {
            base_address: self.base_address,
            serial: self.serial,
            watchdog: self.watchdog,
            io: self.io.settings(),
            ..Settings::FACTORY
        };
        for (slot, d) in s.axes.iter_mut().zip(self.devices.iter()) {
            *slot = d.settings;
        }
        s
    }

    /// Status LED at `now_ms`: a 1 Hz heartbeat when all is well; a fast
    /// 5 Hz blink when the chain was not detected or the stored settings could
    /// not be read (the bridge runs on factory settings then).
    pub fn led_on(&self, now_ms: u64) -> bool {
        let trouble = self.chain_error.is_some()
            || self.source == SettingsSource::FactoryUnreadable
            || self.diag.save_errors > 0;
        let period: u64 = if trouble { 200 } else { 1000 };
        now_ms.checked_rem(period).unwrap_or(0) < period / 2
    }

    /// New ADC samples (supply, temperature).
    pub fn on_analog(&mut self, sample: AnalogSample) {
        self.supply = analog::supply_units(sample, self.stage.analog);
        self.temperature = analog::temperature_units(sample, self.stage.analog);
    }

    /// New input levels of one axis from the board's own pins (inputs the
    /// I/O extension's mapping wires come from the extension instead).
    /// Applied at once, or at the first tick after a save.
    pub fn on_inputs(&mut self, k: usize, inputs: Inputs) {
        if let Some(slot) = self.board_inputs.get_mut(k) {
            *slot = inputs;
        }
        self.apply_inputs();
    }

    /// One control tick at `now_ms`, on a chain bus that clocks each window
    /// when asked ([`ChainBus::window`], blocking).
    ///
    /// The same as [`Bridge::tick_begin`], the plan's windows through the
    /// bus, [`Bridge::tick_end`] — which a driver that clocks the windows by
    /// DMA calls itself, one tick's end right before the next one's begin
    /// ([`Bridge::tick_pipelined`] does that).
    pub fn tick(&mut self, now_ms: u64) {
        if self.overlap.on {
            self.tick_overlapped_blocking(now_ms);
            return;
        }
        if !self.models_tick(now_ms) {
            return;
        }
        let ok = self.group.tick(&mut self.chain).is_ok();
        self.after_batch(ok);
    }

    /// First half of a control tick at `now_ms`: the watchdog, inputs and
    /// device models, then every axis plans its commands. True if the plan
    /// ([`Bridge::plan`]) has windows to clock; then the tick must be ended
    /// with [`Bridge::tick_end`] before the next one begins. False: nothing
    /// goes out and the tick is complete.
    pub fn tick_begin(&mut self, now_ms: u64) -> bool {
        if !self.models_tick(now_ms) {
            return false;
        }
        if self.group.tick_begin(&mut self.chain).is_err() {
            self.after_batch(false);
            return false;
        }
        true
    }

    /// The watchdog, inputs and device models; false (and the tick is
    /// complete) without axes.
    fn models_tick(&mut self, now_ms: u64) -> bool {
        self.now_ms = now_ms;
        self.watch_buses();
        self.apply_inputs();
        for (k, d) in self.devices.iter_mut().enumerate() {
            if let Some(a) = self.group.axis_mut(k) {
                d.tick(now_ms, a, &self.stage, self.temperature);
            }
        }
        if self.devices.is_empty() {
            self.io_outputs();
            return false;
        }
        true
    }

    /// The windows of the tick begun last: [`Plan::window`]`(w)` for `w` in
    /// `0..windows()`, each one CS-low window of N bytes.
    pub fn plan(&self) -> &Plan {
        self.group.plan()
    }

    /// Second half of a control tick: what came back (row `w` holds window
    /// `w`'s N bytes), or the bus error that cut the windows short.
    pub fn tick_end(&mut self, rx: Result<&Frames, B::Error>) {
        let ok = self.group.tick_end(&mut self.chain, rx).is_ok();
        self.after_batch(ok);
    }

    fn after_batch(&mut self, ok: bool) {
        if ok {
            self.failed_ticks = 0;
        } else {
            self.diag.chain_errors = self.diag.chain_errors.saturating_add(1);
            self.failed_ticks = self.failed_ticks.saturating_add(1);
        }
        self.diag.chip_resets = self
            .group
            .iter()
            .zip(self.resets_base.iter())
            .fold(0u32, |n, (a, b)| {
                n.saturating_add(a.chip_resets().wrapping_sub(*b))
            });
        self.io_outputs();
    }

    /// The communication watchdog: a bus silent for longer than its
    /// timeout (off when 0) applies its action to every axis it moved last,
    /// once until it is heard from again.
    fn watch_buses(&mut self) {
        for (bus, (w, s)) in self.watchdog.iter().zip(self.watch.iter_mut()).enumerate() {
            if w.timeout_ms == 0 || s.tripped {
                continue;
            }
            if self.now_ms.saturating_sub(s.last_ms) <= u64::from(w.timeout_ms) {
                continue;
            }
            s.tripped = true;
            let bit = 1u8 << bus;
            let mut acted = false;
            for (k, moved) in self.moved_by.iter_mut().enumerate() {
                if *moved & bit == 0 {
                    continue;
                }
                *moved &= !bit;
                acted = true;
                let (Some(d), Some(a)) = (self.devices.get_mut(k), self.group.axis_mut(k)) else {
                    continue;
                };
                let req = match w.action {
                    WatchdogAction::Hold => Request::Stop,
                    WatchdogAction::SoftStop => Request::SoftStop,
                    WatchdogAction::HiZ => Request::RunSleep(0x0F),
                };
                let _ = d.apply(req, a, &self.stage);
            }
            if acted {
                s.trips = s.trips.saturating_add(1);
                self.diag.watchdog_trips = self.diag.watchdog_trips.saturating_add(1);
            }
        }
    }

    /// Execute a request on axis `k` that came on `bus`: the watchdog hears
    /// the bus, and notes the bus as the one that moved the axis.
    pub fn request_from(
        &mut self,
        bus: Bus,
        k: usize,
        req: Request,
    ) -> Result<Effect, CommandError> {
        self.heard(bus);
        let r = self.request(k, req);
        if req.commands_motion() && r.is_ok() {
            if let Some(m) = self.moved_by.get_mut(k) {
                *m = 1 << bus as u8;
            }
        }
        r
    }

    /// The control tick took `duration_us` (measured by the firmware) of a
    /// `period_us` period: kept for the diagnostics, an overrun counted.
    pub fn tick_timing(&mut self, duration_us: u32, period_us: u32) {
        self.timing.last_us = duration_us;
        self.timing.max_us = self.timing.max_us.max(duration_us);
        self.timing.ticks = self.timing.ticks.wrapping_add(1);
        self.timing.period_us = period_us;
        if duration_us > period_us {
            self.timing.overruns = self.timing.overruns.saturating_add(1);
        }
    }

    pub fn set_reset_cause(&mut self, cause: ResetCause) {
        self.reset_cause = cause;
    }

    /// The firmware's build id (diagnostics).
    pub fn set_build_id(&mut self, id: u32) {
        self.build_id = id;
    }

    /// The Modbus server's counters (the firmware hands them over after
    /// every poll; they feed the diagnostics).
    pub fn set_modbus_stats(&mut self, stats: ModbusStats) {
        self.modbus = stats;
    }

    /// The Modbus counters since the diagnostics were last cleared.
    pub fn modbus_stats(&self) -> ModbusStats {
        self.modbus.since(&self.modbus_base)
    }

    /// Clear every diagnostics counter (a write to 0x0300).
    pub fn clear_diagnostics(&mut self) {
        self.diag = Diagnostics::default();
        self.last_refusal = None;
        self.modbus_base = self.modbus;
        for (b, a) in self.resets_base.iter_mut().zip(self.group.iter()) {
            *b = a.chip_resets();
        }
        for w in self.watch.iter_mut() {
            w.trips = 0;
        }
        self.timing = TickTiming {
            period_us: self.timing.period_us,
            ..TickTiming::default()
        };
    }

    /// The chain has failed for [`CHAIN_DEAD_TICKS`] ticks in a row: the
    /// bridge can no longer stop the motors over SPI, so the firmware must
    /// hold the chips in reset (STBY low), which switches their bridges off.
    pub fn chain_dead(&self) -> bool {
        self.failed_ticks >= CHAIN_DEAD_TICKS
    }

    /// The chain's state for the diagnostics (0x034A): 0 working, 1 the
    /// last batch failed, 2 dead, 3 not detected at boot.
    pub fn chain_state(&self) -> u16 {
        if self.axes() == 0 {
            3
        } else if self.chain_dead() {
            2
        } else if self.failed_ticks > 0 {
            1
        } else {
            0
        }
    }

    /// Execute a request on axis `k` (any bus). A refusal is counted and
    /// kept as the last one (diagnostics 0x0349: axis and reason), which is
    /// how an I2C master — it gets no error reply — learns why.
    pub fn request(&mut self, k: usize, req: Request) -> Result<Effect, CommandError> {
        let result = self.perform(k, req);
        if let Err(e) = result {
            self.diag.refused = self.diag.refused.saturating_add(1);
            self.last_refusal = Some((u8::try_from(k).unwrap_or(u8::MAX), e));
        }
        result
    }

    fn perform(&mut self, k: usize, req: Request) -> Result<Effect, CommandError> {
        if self.run_mode == RunMode::Boot {
            return Err(CommandError::BootMode);
        }
        if self.saving {
            return Err(CommandError::Busy);
        }
        if req.leaves_a_group() && self.group.coord().is_member(k) {
            return Err(CommandError::Grouped);
        }
        let (Some(d), Some(a)) = (self.devices.get_mut(k), self.group.axis_mut(k)) else {
            return Err(CommandError::Unsupported);
        };
        let clamps = d.clamps;
        let result = d.apply(req, a, &self.stage);
        let clamped = d.clamps.wrapping_sub(clamps);
        self.diag.limit_clamps = self.diag.limit_clamps.saturating_add(clamped);
        match result {
            Ok(Effect::SaveSettings) => self.queue_save(),
            Ok(Effect::SystemReset) => self.request_reset(ResetTarget::Application),
            Ok(Effect::SetAddress { current, new }) => self.change_address(k, current, new)?,
            Ok(Effect::None) | Err(_) => {}
        }
        result
    }

    /// The last refused request: its axis and why.
    pub fn last_refusal(&self) -> Option<(u8, CommandError)> {
        self.last_refusal
    }

    /// Answer a query for axis `k` (any bus); `None` for a missing axis.
    pub fn query(&self, k: usize, q: Query) -> Option<Value> {
        let d = self.devices.get(k)?;
        let a = self.group.axis(k)?;
        Some(d.query(q, a, &self.stage, self.supply, self.temperature))
    }

    /// The address axis `k` answers.
    pub fn address_of(&self, k: usize) -> Option<u8> {
        u8::try_from(k)
            .ok()
            .and_then(|k| self.base_address.checked_add(k))
    }

    /// The axis answering `address`, if any.
    pub fn axis_at(&self, address: u8) -> Option<usize> {
        let k = usize::from(address.checked_sub(self.base_address)?);
        (k < self.axes()).then_some(k)
    }

    /// Address change (0x04) sent to axis `k`: the base moves so that axis
    /// `k` answers `new`. Refused unless every axis then has an address on
    /// every bus — one base serves I2C (7-bit, 1..=127) and Modbus
    /// (1..=247), so the narrower I2C range binds: with N axes the base is
    /// at most 128 − N.
    fn change_address(&mut self, k: usize, current: u8, new: u8) -> Result<(), CommandError> {
        let n = self.axes();
        if self.address_of(k) != Some(current) || !(1..=I2C_ADDRESS_MAX).contains(&new) {
            return Err(CommandError::BadAddress);
        }
        let k = u8::try_from(k).map_err(|_| CommandError::BadAddress)?;
        let base = new
            .checked_sub(k)
            .filter(|b| *b >= 1)
            .ok_or(CommandError::BadAddress)?;
        let last = usize::from(base).saturating_add(n.saturating_sub(1));
        let on_every_bus = [
            usize::from(I2C_ADDRESS_MAX),
            usize::from(crate::transport::modbus::ID_MAX),
        ];
        if on_every_bus.iter().any(|max| last > *max) {
            return Err(CommandError::BadAddress);
        }
        if base != self.base_address {
            self.base_address = base;
            self.addresses_changed = true;
        }
        Ok(())
    }
}
