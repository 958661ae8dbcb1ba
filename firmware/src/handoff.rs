//! Hand-offs between the RTIC app's tasks and the bridge (`main.rs`): the
//! I/O extension's actions to its task, a transfer's end back to the
//! bridge, the I2C addresses after an address change. Each applies what the
//! bridge decided; none decides anything.

use bridge_logic::bridge::Bridge;
use bridge_logic::ioext::{Action, WireBits};
use defmt::{error, warn};
use rtic::Mutex;
use rtic_sync::channel::{Sender, TrySendError};

use crate::drivers::ioext_spi::IoExtError;
use crate::platform::{ChainLink, I2cSlaveDriver};

/// The I/O extension's actions to `ioext_run`, oldest first; one that
/// finds the channel full waits for the next tick.
pub fn hand_over_io<const N: usize>(
    tx: &mut Sender<'static, Action, N>,
    pending: &mut Option<Action>,
    new: Option<Action>,
) {
    for action in [pending.take(), new].into_iter().flatten() {
        match tx.try_send(action) {
            Ok(()) => {}
            Err(TrySendError::Full(a)) => {
                if pending.replace(a).is_some() {
                    error!("ioext: action dropped (channel full twice)");
                }
            }
            Err(TrySendError::NoReceiver(_)) => error!("ioext: task gone, action dropped"),
        }
    }
}

/// The end of a transfer, to the bridge.
pub fn report_io(
    bridge: &mut impl Mutex<T = &'static mut Bridge<ChainLink>>,
    result: Result<WireBits, IoExtError>,
) {
    let taken = bridge.lock(|b| match &result {
        Ok(rx) => b.on_io_done(rx),
        Err(_) => b.on_io_failed(),
    });
    if let Err(e) = result {
        warn!("ioext: transfer failed ({})", e);
    }
    if taken.is_err() {
        warn!("ioext: a transfer ended that the bridge did not run");
    }
}

/// Reprogram the I2C own addresses if the bridge's address base changed
/// since the last call (through either bus).
pub fn apply_address_change(
    bridge: &mut impl Mutex<T = &'static mut Bridge<ChainLink>>,
    i2c: &mut I2cSlaveDriver,
) {
    if let Some((p, s)) = bridge.lock(|b| b.take_address_change().then(|| b.i2c_addresses())) {
        i2c.set_addresses(p, s);
    }
}
