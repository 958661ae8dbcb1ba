//! Start-up steps of the RTIC app (`main.rs`'s `init`) that need no RTIC
//! resource: the settings to boot with, the boot log lines the end-to-end
//! tests wait for, the watchdog's first window, the reset pulse's delay.

use bridge_logic::bridge::{boot_settings, Bridge, SettingsSource};
use bridge_logic::persist::{Store, StoreError, MAX_IMAGE};
use bridge_logic::postep60::settings::Settings;
use bridge_logic::transport::modbus::Timing;
use defmt::{error, info};

use crate::drivers::rs485::Rs485;
use crate::platform::{ChainLink, SettingsFlash, Watchdog};

/// The settings to boot with: the store's, or factory settings (and why).
pub fn load_settings(store: &mut Store<SettingsFlash>) -> (Settings, SettingsSource) {
    let mut image = [0u8; MAX_IMAGE];
    let loaded = store
        .load(&mut image)
        .map(|n| image.get(..n).unwrap_or(&[]));
    let (settings, source) = boot_settings(loaded, |e| *e == StoreError::Empty);
    info!("settings: {}", source);
    (settings, source)
}

/// The boot log line of the Modbus line (the e2e test waits for it).
pub fn log_modbus(rs485: &Rs485, bridge: &Bridge<ChainLink>, timing: Timing) {
    let serial = bridge.serial();
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
}

/// Start-up's last step: the watchdog in the bridge's window.
pub fn arm_watchdog(watchdog: &mut Watchdog, bridge: &Bridge<ChainLink>) {
    let window = bridge.watchdog_window();
    match watchdog.feed_in(window) {
        Ok(()) => info!("watchdog: {} window", window),
        Err(e) => error!("watchdog: {} window not in effect ({})", window, e),
    }
}

/// Busy-wait `ms` milliseconds at `sysclk_hz` (init only).
pub fn delay_ms(ms: u32, sysclk_hz: u32) {
    cortex_m::asm::delay(ms.saturating_mul(sysclk_hz / 1_000));
}
