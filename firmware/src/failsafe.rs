//! Last-resort paths that switch the powerSTEP01 bridges off: the panic
//! handler (here, on both platforms) and the HardFault handler (the
//! platform's: `platform/stm32f405.rs`, `platform/qemu.rs`).
//!
//! Both drive the chain's STBY/RESET low ([`chips_off`]), which holds every
//! chip in reset with its power bridges off, before anything else, so a
//! crashed MCU never leaves a motor running on its last command. STBY then
//! stays low until the next MCU reset: nothing after these paths drives it
//! high again. (The running firmware has a third path: the app drives the
//! same pin low once `Bridge::chain_dead()` says the chain can no longer be
//! reached over SPI.)
//!
//! * **Panic** ([`panic`], replacing panic-probe): interrupts off, STBY low,
//!   the message through defmt (once: a panic while logging skips it), then
//!   `udf`, as panic-probe does. The resulting HardFault is what probe-rs
//!   reports on the board; under QEMU the platform's HardFault handler
//!   ends QEMU with exit status 1.
//! * **HardFault** on the board (`platform/stm32f405.rs`): STBY low, then spin. The
//!   independent watchdog (started in `init`, fed by the control tick) resets
//!   the MCU within its window (≤ 47.1 ms; seconds only in `init` or during a
//!   settings save); until then, and through the reset (the pin floats from
//!   reset until `init` configures it), the board's pull-down on STBY keeps
//!   the chips in reset.
//!
//! `udf` raises a HardFault because UsageFault stays disabled (neither
//! cortex-m-rt nor RTIC enables it), so the fault escalates; interrupts
//! masked by PRIMASK do not stop that.

// One `steal` of GPIOC (an `unsafe fn` of the PAC).
#![allow(unsafe_code)]

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

use stm32f4xx_hal::gpio::Pin;
use stm32f4xx_hal::pac::GPIOC;

use crate::pins::ChainStby;

/// Port letter and pin number of a HAL pin type, at compile time.
trait PortPin {
    const PORT: char;
    const PIN: u8;
}

impl<const P: char, const N: u8, MODE> PortPin for Pin<P, N, MODE> {
    const PORT: char = P;
    const PIN: u8 = N;
}

/// STBY's pin number on GPIOC, taken from the board's pin assignment.
const STBY_PIN: u8 = <ChainStby as PortPin>::PIN;
const _: () = assert!(
    <ChainStby as PortPin>::PORT == 'C',
    "chips_off writes GPIOC: follow pins::ChainStby's port"
);

/// Drive the chain's STBY/RESET low (every chip into reset, bridges off)
/// with one write to GPIOC's BSRR, whatever state the rest of the firmware
/// is in.
///
/// Before `pins::configure` the pin is still an input (or GPIOC's clock is
/// off and the write is lost): then the chips have not been released from
/// reset yet, and the board's pull-down holds STBY low.
pub fn chips_off() {
    // SAFETY: `steal` hands out a second handle to GPIOC next to the HAL's
    // split pins. It is used for one write to the bit set/reset register
    // whose only set bit is the reset bit of the STBY pin: BSRR writes are
    // atomic in hardware and change only the output bit written, so no other
    // pin changes and no register the HAL may be in the middle of updating
    // (MODER, PUPDR, ...) is touched. Nothing is read and the handle is
    // dropped at once.
    let gpioc = unsafe { GPIOC::steal() };
    gpioc.bsrr().write(|w| w.br(STBY_PIN).reset());
}

/// The panic handler (see the module docs).
#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    static PANICKED: AtomicBool = AtomicBool::new(false);

    cortex_m::interrupt::disable();
    chips_off();
    // A panic inside the log call below comes back here: skip the log then.
    if !PANICKED.swap(true, Ordering::Relaxed) {
        defmt::error!("{}", defmt::Display2Format(info));
    }
    cortex_m::asm::udf()
}
