//! The platform under QEMU 7.2's `netduinoplus2` (feature `qemu`): stand-ins
//! with the board's names for what QEMU does not model (see `platform/mod.rs`
//! for the table of both platforms). Everything else — the RTIC app, the
//! bridge, the Modbus server and its USART2/RS-485 driver, the SysTick
//! monotonic, the panic handler — is the board's code.
//!
//! * **Control tick**: QEMU's TIM2 counts at a fixed 1 GHz and ignores the
//!   prescaler (with PSC = 15 and ARR = 999, the HAL's 1 kHz at HSI, it
//!   fires every microsecond). With PSC = 0 and ARR = 10⁶ − 1 it raises its
//!   update interrupt every 1.01 ms (measured; QEMU re-arms it from the
//!   moment the tick is served), so the app's TIM2 task runs unchanged.
//! * **Chain**: [`ChainDriver`] holds [`AXES`] simulated powerSTEP01s and
//!   lets them live through the monotonic's time that passed since the last
//!   CS window, as real chips run on their own oscillator whatever the
//!   control loop does. The bridge's clock counts ticks, so the two drift
//!   apart by the timer's 1 %, as a board's MCU and chip oscillators do.
//! * **Settings flash**: [`SettingsFlash`] keeps the store's two erase units
//!   in RAM, loaded at boot from a host file and written through on every
//!   program and erase (semihosting), so settings saved under QEMU survive a
//!   restart. The file is the `flash=PATH` semihosting argument
//!   (`scripts/qemu-run` passes `target/qemu-flash.bin`); without one the
//!   flash lives in RAM only and every boot is factory-fresh.
//! * **Faults**: a HardFault (also the end of the panic handler, after its
//!   message) exits QEMU with status 1, so a crash fails a run instead of
//!   hanging it.

// cortex-m-rt's HardFault handler is an `unsafe fn` by contract.
#![allow(unsafe_code)]

use core::convert::Infallible;
use core::ffi::CStr;

use bridge_logic::persist::MAX_RECORD;
use bridge_logic::postep::analog::AnalogSample;
use bridge_logic::powerstep::ChainBus;
use bridge_logic::sim::{SimChain, SimFlash, SimFlashError};
use bridge_logic::transport::i2c::{I2cSlave, I2cTarget};
use defmt_semihosting as _;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use semihosting::fs::File;
use semihosting::io::{Read as _, Seek as _, SeekFrom, Write as _};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::{Config, Enable, Rcc, RccExt, Reset};

use super::ResetCause;
use crate::board::{
    self, ChainCs, ChainMiso, ChainMosi, ChainSck, ChainSpi, HostI2c, HostI2cScl, HostI2cSda,
    SenseAdc, SupplySense,
};
use crate::drivers::clock;

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

/// QEMU models no RCC_CSR: always [`ResetCause::Unknown`].
pub fn reset_cause(_rcc: &pac::RCC) -> ResetCause {
    ResetCause::Unknown
}

/// Watchdog stand-in: QEMU does not model the IWDG, so nothing is started
/// and feeding does nothing.
pub struct Watchdog;

impl Watchdog {
    /// The board's nominal timeout (not applied under QEMU).
    pub const TIMEOUT_MS: u32 = 6_500;

    pub fn start(_iwdg: pac::IWDG, _dbgmcu: &pac::DBGMCU) -> Watchdog {
        defmt::info!("watchdog: not modelled by QEMU, not started");
        Watchdog
    }

    pub fn feed(&mut self) {}
}

/// Why the control timer did not start.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum TimerError {
    /// 0 Hz, or faster than the timer model counts.
    WrongRate,
}

/// TIM2 as the control-loop timer, programmed for QEMU's timer model
/// (module docs): its update interrupt is the control tick, as on the board.
pub struct TickTimer(board::ControlTimer);

impl TickTimer {
    pub fn new(tim: board::ControlTimer, rcc: &mut Rcc) -> TickTimer {
        board::ControlTimer::enable(rcc);
        board::ControlTimer::reset(rcc);
        TickTimer(tim)
    }

    /// Interrupt every `1 / hz` s (plus QEMU's re-arm latency).
    pub fn start(&mut self, hz: u32) -> Result<(), TimerError> {
        let arr = TIMER_HZ
            .checked_div(hz)
            .and_then(|ticks| ticks.checked_sub(1))
            .filter(|&arr| arr > 0)
            .ok_or(TimerError::WrongRate)?;
        let tim = &self.0;
        tim.psc().write(|w| w.psc().set(0));
        tim.arr().write(|w| w.arr().set(arr));
        tim.dier().write(|w| w.uie().set_bit());
        tim.cr1().write(|w| w.cen().set_bit());
        Ok(())
    }

    /// Clear the update flag (first thing in the interrupt).
    pub fn acknowledge(&mut self) {
        self.0.sr().write(|w| w.uif().clear_bit());
    }
}

/// The chain stand-in: [`AXES`] simulated chips that live on the
/// monotonic's time (module docs).
pub struct ChainDriver {
    chain: SimChain,
    /// `clock::now_us` at the last window.
    last_us: u64,
}

impl ChainDriver {
    /// The simulated chips.
    pub fn chain(&self) -> &SimChain {
        &self.chain
    }
}

impl ChainBus for ChainDriver {
    type Error = Infallible;

    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), Infallible> {
        let now = clock::now_us();
        let elapsed_ns = now.saturating_sub(self.last_us).saturating_mul(1_000);
        self.last_us = now;
        self.chain.advance(elapsed_ns);
        self.chain.transfer(tx, rx);
        Ok(())
    }
}

/// The simulated chain instead of SPI1 (which, and whose pins, stay as
/// `board::configure` left them). Start the monotonic first.
pub fn chain_driver(
    _spi: ChainSpi,
    _pins: (ChainSck, ChainMiso, ChainMosi),
    _cs: ChainCs,
    _rcc: &mut Rcc,
) -> ChainDriver {
    ChainDriver {
        chain: SimChain::new(AXES),
        last_us: clock::now_us(),
    }
}

/// ADC1 stand-in: constant samples of a 24 V supply and a 25 °C die (at
/// VDDA = 3.3 V, with the reference board's ÷20 divider). The ADC and its
/// pin stay untouched.
pub struct Analog;

impl Analog {
    /// 24 V / 20 = 1.2 V at the pin = 1490 counts at VDDA 3.2988 V.
    const SAMPLE: AnalogSample = AnalogSample {
        supply: 1490,
        temperature: 943,
        vrefint: 1502,
    };

    pub fn new(_adc: SenseAdc, _pin: SupplySense, _rcc: &mut Rcc) -> Analog {
        Analog
    }

    pub fn sample(&mut self) -> AnalogSample {
        Self::SAMPLE
    }
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

/// Erase unit of the QEMU settings flash: the smallest power of two that
/// holds the store's largest record (the store needs one record per erase
/// unit; the board's are 128 KiB).
pub const FLASH_SECTOR: usize = MAX_RECORD.next_power_of_two();
/// Erase units (the store uses two).
pub const FLASH_SECTORS: usize = 2;
/// Bytes of the host file.
pub const FLASH_SIZE: usize = FLASH_SECTOR * FLASH_SECTORS;
/// Longest host path taken from the `flash=PATH` argument.
const PATH_MAX: usize = 255;

/// Why a settings-flash operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SettingsFlashError {
    /// Alignment, bounds (as on the board).
    Flash(SimFlashError),
    /// The host file could not be written: the RAM copy has the new content,
    /// the file may not.
    HostFile,
}

impl NorFlashError for SettingsFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SettingsFlashError::Flash(e) => e.kind(),
            SettingsFlashError::HostFile => NorFlashErrorKind::Other,
        }
    }
}

/// The settings store's flash under QEMU: NOR semantics in RAM
/// ([`SimFlash`]), every program and erase written through to the host
/// file (module docs).
pub struct SettingsFlash {
    ram: SimFlash<FLASH_SECTOR, FLASH_SECTORS>,
    /// `None`: RAM only.
    file: Option<File>,
    /// Kept untouched, for [`SettingsFlash::free`].
    flash: pac::FLASH,
}

impl SettingsFlash {
    /// The FLASH peripheral back (the host file is closed).
    pub fn free(self) -> pac::FLASH {
        self.flash
    }

    /// Copy `ram[offset..offset + len]` into the host file.
    fn write_through(&mut self, offset: u32, len: usize) -> Result<(), SettingsFlashError> {
        let Some(file) = self.file.as_mut() else {
            return Ok(());
        };
        let start = offset as usize;
        let mut chunk = [0u8; FLASH_SECTOR];
        let mut done = 0;
        while done < len {
            let n = (len - done).min(FLASH_SECTOR);
            let at = start + done;
            let buf = chunk.get_mut(..n).ok_or(SettingsFlashError::HostFile)?;
            self.ram
                .read(at as u32, buf)
                .map_err(SettingsFlashError::Flash)?;
            file.seek(SeekFrom::Start(at as u64))
                .and_then(|_| file.write_all(buf))
                .map_err(|_| SettingsFlashError::HostFile)?;
            done += n;
        }
        Ok(())
    }
}

impl ErrorType for SettingsFlash {
    type Error = SettingsFlashError;
}

impl ReadNorFlash for SettingsFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.ram
            .read(offset, bytes)
            .map_err(SettingsFlashError::Flash)
    }

    fn capacity(&self) -> usize {
        FLASH_SIZE
    }
}

impl NorFlash for SettingsFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = FLASH_SECTOR;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.ram
            .erase(from, to)
            .map_err(SettingsFlashError::Flash)?;
        self.write_through(from, to.saturating_sub(from) as usize)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.ram
            .write(offset, bytes)
            .map_err(SettingsFlashError::Flash)?;
        self.write_through(offset, bytes.len())
    }
}

/// The settings flash, loaded from the host file named by the `flash=PATH`
/// semihosting argument (created erased if missing). The FLASH peripheral
/// stays untouched (QEMU does not model its controller).
pub fn settings_flash(flash: pac::FLASH) -> SettingsFlash {
    let mut flash = SettingsFlash {
        ram: SimFlash::new(),
        file: None,
        flash,
    };
    let mut path = [0u8; PATH_MAX + 1];
    let Some(path) = flash_path(&mut path) else {
        defmt::warn!(
            "settings flash: RAM only (no flash=PATH argument): factory-fresh at every boot"
        );
        return flash;
    };
    let name = path.to_str().unwrap_or("?");
    match File::options().read(true).write(true).open(path) {
        Ok(mut file) => {
            let mut got = 0;
            for sector in flash.ram.sectors_mut() {
                got += read_up_to(&mut file, sector);
            }
            defmt::info!(
                "settings flash: host file {=str} ({=usize} of {=usize} bytes read)",
                name,
                got,
                FLASH_SIZE
            );
            flash.file = Some(file);
        }
        Err(_) => match File::options()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)
        {
            Ok(file) => {
                flash.file = Some(file);
                // Size the new file: all of it erased.
                if flash.write_through(0, FLASH_SIZE).is_err() {
                    defmt::warn!("settings flash: cannot write {=str}", name);
                }
                defmt::info!("settings flash: new host file {=str} (factory-fresh)", name);
            }
            Err(_) => {
                defmt::warn!(
                    "settings flash: cannot open or create {=str}: RAM only",
                    name
                )
            }
        },
    }
    flash
}

/// Read as much of `file` as fits in `buf` (short at the end of the file:
/// the rest keeps its erased state). Returns the bytes read.
fn read_up_to(file: &mut File, buf: &mut [u8]) -> usize {
    let mut got = 0;
    while let Some(rest) = buf.get_mut(got..).filter(|r| !r.is_empty()) {
        match file.read(rest) {
            Ok(0) | Err(_) => break,
            Ok(n) => got += n,
        }
    }
    got
}

/// The `flash=PATH` semihosting argument, NUL-terminated in `buf`.
fn flash_path(buf: &mut [u8; PATH_MAX + 1]) -> Option<&CStr> {
    let args = semihosting::experimental::env::args::<{ PATH_MAX + 64 }>().ok()?;
    let path = (&args)
        .filter_map(Result::ok)
        .find_map(|arg| arg.strip_prefix("flash="))?
        .as_bytes();
    let slot = buf.get_mut(..path.len())?;
    if path.is_empty() || path.contains(&0) || path.len() > PATH_MAX {
        return None;
    }
    slot.copy_from_slice(path);
    *buf.get_mut(path.len())? = 0;
    CStr::from_bytes_until_nul(buf).ok()
}

/// How far SysTick time may fall behind real time, in percent. QEMU counts
/// 168 MHz of its own time, but re-arms the SysTick at each wrap (every
/// 100 µs here) from the moment it serves it, so every period is late by
/// the host's latency: measured 10-30 % behind the host clock on a 2-core
/// machine, varying with its load (its TIM2 model, re-armed every 1 ms,
/// lags ~1 %). The monotonic, Modbus timing included, runs that much slow
/// under QEMU; a wrong SysTick rate would be off by 10x.
pub const SYSTICK_LAG_MAX_PERCENT: u64 = 50;

/// Run `f` and return how long it took in µs on a clock that is not
/// SysTick, for the on-target tests that check the monotonic's rate: the
/// host's, through semihosting (SYS_CLOCK, 10 ms resolution; QEMU's DWT
/// cycle counter reads 0). 0 if the host does not answer.
pub fn measure_us(_sysclk_hz: u32, f: impl FnOnce()) -> u64 {
    let centiseconds = || semihosting::sys::arm_compat::sys_clock().unwrap_or(0) as u64;
    let start = centiseconds();
    f();
    centiseconds().saturating_sub(start) * 10_000
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
