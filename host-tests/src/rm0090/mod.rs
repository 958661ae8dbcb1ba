//! Host-side models of the STM32F405's peripherals, written from RM0090
//! (the STM32F405/415/407/417/427/437/429/439 reference manual, rev 19
//! numbering), that the drivers of `drivers_core` run against in
//! `cargo test`: the same driver code the firmware runs on the chip, here on
//! a model that applies the manual's rules — which access sets or clears
//! which flag, in which order, when SCL is stretched, what an interrupt line
//! shows.
//!
//! * [`chain_spi`] — SPI1 as the chain's master (§28), DMA2 streams 0/3
//!   (§10), TIM7 (§20) and the CS line, with the simulated chips on MISO.
//! * [`ioext`] — the I/O extension's port: SPI2 (§28), TIM1 (§17), DMA1
//!   streams 3/4 and DMA2 streams 2/6 (§10), GPIOB's pins as levels (§8),
//!   with 74HC165/74HC595 shift registers on them.
//! * [`i2c`] — I2C1 in slave mode (§27), with [`i2c_rig`]: a simulated
//!   master and the NVIC's order of the two I2C interrupts.
//! * [`flash`] — the flash interface (§3): unlock keys, sector erase,
//!   program with PSIZE, error flags, lock, the data cache; power cuts.
//! * [`usart`] — USART2 (§30) with the RS-485 DE line, in bit times.
//! * [`iwdg`] — the independent watchdog (§21): keys, PR/RLR with PVU/RVU,
//!   the down-counter.
//!
//! Each model's module doc lists its rules with the RM0090 section each one
//! comes from, and marks UNCONFIRMED what the manual does not say (or what
//! could not be checked against it here). RM0090 itself is not in this
//! repository: the rules and section numbers were written from the manual
//! as known; of its text, only the flash erase/program sequences and their
//! errors (§3.5.3, §3.5.4) were checked against a copy while writing them,
//! so every other section number is UNCONFIRMED as to its exact numbering
//! (the rules themselves are the manual's, and the tests pin them down). A model records what RM0090 calls
//! undefined or forbidden as a *violation* (`violations()`), and the tests
//! assert there are none; what the silicon would do anyway (a lost byte, a
//! flag that never clears, an interrupt that never stops) the model does
//! too, so a wrong driver fails by its effect on the bus as well.

use std::cell::{Ref, RefCell, RefMut};
use std::rc::Rc;

use drivers_core::Regs;

pub mod chain_spi;
pub mod flash;
pub mod i2c;
pub mod i2c_rig;
pub mod ioext;
pub mod iwdg;
pub mod spi;
pub mod usart;

/// A shared handle on a model: the driver under test holds one, the test
/// another. Each register access through [`Regs`] first lets one bus
/// access's time pass in the model.
#[derive(Debug)]
pub struct Handle<M>(Rc<RefCell<M>>);

impl<M> Clone for Handle<M> {
    fn clone(&self) -> Self {
        Handle(Rc::clone(&self.0))
    }
}

impl<M> Handle<M> {
    /// A handle on `model`.
    pub fn of(model: M) -> Handle<M> {
        Handle(Rc::new(RefCell::new(model)))
    }

    pub fn model(&self) -> Ref<'_, M> {
        self.0.borrow()
    }

    pub fn model_mut(&self) -> RefMut<'_, M> {
        self.0.borrow_mut()
    }
}

/// A model's register file as a driver reaches it through a [`Handle`].
pub trait RegisterFile<R> {
    /// The time of one bus access passes.
    fn tick_access(&mut self);
    fn read_reg(&mut self, reg: R) -> u32;
    fn write_reg(&mut self, reg: R, value: u32);
}

impl<R: Copy, M: RegisterFile<R>> Regs<R> for Handle<M> {
    fn read(&mut self, reg: R) -> u32 {
        let mut m = self.0.borrow_mut();
        m.tick_access();
        m.read_reg(reg)
    }

    fn write(&mut self, reg: R, value: u32) {
        let mut m = self.0.borrow_mut();
        m.tick_access();
        m.write_reg(reg, value);
    }
}
