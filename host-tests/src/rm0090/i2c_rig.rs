//! The I2C driver on the I2C model, with a simulated master and the NVIC:
//! `drivers_core::i2c_slave::I2cSlaveDriver` (the firmware's code) on
//! [`I2cModel`], the PoStep60 framing ([`I2cSlave`]) above it and a target
//! (the bridge, or a [`Recorder`]).
//!
//! # How the rig runs the interrupts
//!
//! * I2C1_EV and I2C1_ER are bound at one priority, so they never preempt
//!   each other and EV (the lower IRQ number) goes first when both pend —
//!   as the firmware binds them.
//! * Interrupt latency: a pending interrupt is served before the master's
//!   next bus step, or — with [`I2cRig::latency`] = n — after up to n more
//!   master steps, as long as SCL is not held (a held SCL stops the master,
//!   so then the rig serves at once). This lets the bus run ahead of the
//!   handlers as it does on a busy chip.
//! * A handler call that leaves an interrupt pending is called again; more
//!   than [`STORM`] calls in a row without the master moving is an
//!   interrupt storm (a flag the driver never clears), and the rig panics
//!   with the model's last register accesses. So does a master that finds
//!   SCL held with no interrupt pending (a bus stuck for ever).
//! * After a write, the rig reprograms the own addresses if the target
//!   changed them, as the firmware's I2C event task does.

use bridge_logic::bridge::Bridge;
use bridge_logic::powerstep::ChainBus;
use bridge_logic::transport::i2c::{I2cSlave, I2cTarget, Which, Write, RESPONSE_MAX};
use drivers_core::i2c_slave::I2cSlaveDriver;

use super::i2c::{Held, I2cModel, APB1_MHZ};

/// Handler calls in a row, the master not moving, that make a storm.
pub const STORM: usize = 16;

/// What the rig needs of a target besides [`I2cTarget`].
pub trait RigTarget: I2cTarget {
    /// New own addresses, if a write changed them.
    fn address_change(&mut self) -> Option<(u8, Option<u8>)> {
        None
    }
}

impl<B: ChainBus> RigTarget for Bridge<B> {
    fn address_change(&mut self) -> Option<(u8, Option<u8>)> {
        self.take_address_change().then(|| self.i2c_addresses())
    }
}

/// A target that records what it is given and answers every read with
/// `response`.
#[derive(Clone, Debug, Default)]
pub struct Recorder {
    /// Every write: which address, the bytes, overlong.
    pub writes: Vec<(Which, Vec<u8>, bool)>,
    /// Every read's address.
    pub reads: Vec<Which>,
    /// What a read returns (all of it).
    pub response: Vec<u8>,
}

impl I2cTarget for Recorder {
    fn i2c_write(&mut self, write: Write<'_>) {
        self.writes
            .push((write.which, write.bytes.to_vec(), write.overlong));
    }

    fn i2c_read(&mut self, which: Which, out: &mut [u8; RESPONSE_MAX]) -> usize {
        self.reads.push(which);
        let n = self.response.len().min(RESPONSE_MAX);
        out[..n].copy_from_slice(&self.response[..n]);
        n
    }
}

impl RigTarget for Recorder {}

/// Driver + model + framing + target (see the module docs).
pub struct I2cRig<T> {
    pub driver: I2cSlaveDriver<I2cModel>,
    pub slave: I2cSlave,
    pub target: T,
    /// Master steps a pending interrupt may wait (0: served at once).
    pub latency: usize,
    waited: usize,
    /// Handler calls so far (event, error).
    pub calls: (u64, u64),
}

impl<T: RigTarget> I2cRig<T> {
    /// The driver started on a fresh model at `primary` / `secondary`.
    pub fn new(target: T, primary: u8, secondary: Option<u8>) -> I2cRig<T> {
        let driver = I2cSlaveDriver::new(
            I2cModel::new(),
            drivers_core::i2c_slave::freq_mhz(APB1_MHZ * 1_000_000),
            primary,
            secondary,
        );
        I2cRig {
            driver,
            slave: I2cSlave::new(),
            target,
            latency: 0,
            waited: 0,
            calls: (0, 0),
        }
    }

    /// The peripheral model.
    pub fn model(&self) -> &I2cModel {
        self.driver.port()
    }

    pub fn model_mut(&mut self) -> &mut I2cModel {
        self.driver.port_mut()
    }

    fn pending(&self) -> bool {
        self.model().event_irq() || self.model().error_irq()
    }

    /// Serve interrupts until none is pending (EV before ER). Panics on a
    /// storm.
    pub fn serve(&mut self) {
        let mut n = 0;
        loop {
            if self.model().event_irq() {
                self.calls.0 += 1;
                self.driver.on_event(&mut self.slave, &mut self.target);
                if let Some((p, s)) = self.target.address_change() {
                    self.driver.set_addresses(p, s);
                }
            } else if self.model().error_irq() {
                self.calls.1 += 1;
                self.driver.on_error(&mut self.slave, &mut self.target);
            } else {
                break;
            }
            n += 1;
            assert!(
                n <= STORM,
                "interrupt storm: {n} handler calls and still pending, {:?}\nlast accesses:\n{}",
                self.model(),
                self.model().trace()
            );
        }
        self.waited = 0;
    }

    /// One master bus step: interrupts first if they waited long enough,
    /// then `op`, retried after serving while SCL is held.
    pub fn step<R>(&mut self, what: &str, op: impl Fn(&mut I2cModel) -> Result<R, Held>) -> R {
        if self.pending() {
            if self.waited >= self.latency {
                self.serve();
            } else {
                self.waited += 1;
            }
        }
        for _ in 0..=STORM {
            match op(self.model_mut()) {
                Ok(r) => return r,
                Err(Held) => {
                    assert!(
                        self.pending(),
                        "bus stuck before {what}: SCL held low and no interrupt pending, {:?}\nlast accesses:\n{}",
                        self.model(),
                        self.model().trace()
                    );
                    self.serve();
                }
            }
        }
        panic!("{what}: SCL held low for good\n{}", self.model().trace())
    }

    /// Let every pending interrupt run (the bus idle for a while).
    pub fn settle(&mut self) {
        self.serve();
    }

    /// START, address + W, `bytes`, STOP. Returns the ACK bits: the
    /// address's, then each byte's (false for the address: nothing sent).
    pub fn write(&mut self, addr: u8, bytes: &[u8]) -> Vec<bool> {
        let mut acks = self.write_open(addr, bytes);
        if acks.first() == Some(&false) {
            acks.truncate(1);
        }
        self.step("STOP", |m| m.stop());
        self.settle();
        acks
    }

    /// START, address + W and `bytes`, no STOP (for a repeated START next).
    pub fn write_open(&mut self, addr: u8, bytes: &[u8]) -> Vec<bool> {
        self.step("START", |m| m.start());
        let acked = self.step("address", |m| m.address(addr, false));
        let mut acks = vec![acked];
        if acked {
            for &b in bytes {
                acks.push(self.step("data byte", |m| m.master_write(b)));
            }
        }
        acks
    }

    /// START (or repeated START), address + R, `n` bytes (every one ACKed
    /// but the last), STOP. None: the address was not ACKed.
    pub fn read(&mut self, addr: u8, n: usize) -> Option<Vec<u8>> {
        let out = self.read_open(addr, n);
        self.step("STOP", |m| m.stop());
        self.settle();
        out
    }

    /// [`I2cRig::read`] without the STOP.
    pub fn read_open(&mut self, addr: u8, n: usize) -> Option<Vec<u8>> {
        self.step("START", |m| m.start());
        if !self.step("address", |m| m.address(addr, true)) {
            return None;
        }
        let mut out = Vec::with_capacity(n);
        for k in 0..n {
            let ack = k + 1 < n;
            out.push(self.step("read byte", |m| m.master_read(ack)));
        }
        Some(out)
    }

    /// The manual's read-after-write with a repeated START: START, address
    /// + W, `bytes`, Sr, address + R, `n` bytes, STOP.
    pub fn write_read(&mut self, addr: u8, bytes: &[u8], n: usize) -> Option<Vec<u8>> {
        let acks = self.write_open(addr, bytes);
        if acks.iter().any(|a| !a) {
            self.step("STOP", |m| m.stop());
            self.settle();
            return None;
        }
        self.read(addr, n)
    }
}
