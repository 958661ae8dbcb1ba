//! The body of the `ioext_registers` fuzz target (and of a test over a fixed
//! corpus, so it builds on stable): arbitrary register reads and writes on
//! any address, control ticks, transfers through simulated shift registers
//! that complete or fail, input changes and persistence round-trips, in any
//! order. Panics if an invariant breaks:
//!
//! * a refused read or write changes nothing;
//! * the configuration reads with SPI mode set and every undocumented bit 0;
//! * no transfer is planned while one runs; a plan has the configured bit
//!   count and mode, a period never shorter than requested, exactly
//!   `bits` leading and trailing edges;
//! * after a completed transfer the status bit is set and the receive words
//!   past the bit count read 0;
//! * the persisted settings round-trip through their image.
//!
//! Input: a stream of ops; each op is a tag byte (low 3 bits: 0 read, 1
//! write, 2 tick, 3 complete, 4 fail, 5 set an input, 6 configure, 7
//! persist), then its arguments (see [`run`]). Missing bytes read 0.

#![allow(clippy::panic, clippy::arithmetic_side_effects)]

use bridge_logic::ioext::config::cfg;
use bridge_logic::ioext::registers::addr;
use bridge_logic::ioext::wire::wire;
use bridge_logic::ioext::{
    requested_period_ns, Action, AxisOutputs, Clocks, IoExtension, IoSettings, TransferPlan,
    IMAGE_LEN,
};
use stepbridge_sim::ShiftChain;

struct Bytes<'a>(core::slice::Iter<'a, u8>);

impl Bytes<'_> {
    fn u8(&mut self) -> u8 {
        self.0.next().copied().unwrap_or(0)
    }
    fn u16(&mut self) -> u16 {
        u16::from_be_bytes([self.u8(), self.u8()])
    }
    /// An address: mostly inside the page, sometimes anywhere.
    fn addr(&mut self) -> u16 {
        let lo = self.u8();
        let hi = self.u8();
        if hi & 0x80 != 0 {
            u16::from_be_bytes([hi, lo])
        } else {
            addr::FIRST | u16::from(lo)
        }
    }
}

fn check_plan(io: &IoExtension, p: &TransferPlan) {
    let c = io.config();
    assert_eq!(p.bits, c.bits());
    assert_eq!(p.mode, c.mode());
    assert!(p
        .clock
        .period
        .at_least_ns(requested_period_ns(c.period_n())));
    assert_eq!(p.tx, p.tx.truncated(p.bits));
    let steps: Vec<_> = wire(p).collect();
    let mut edges = 0usize;
    for w in steps.windows(2) {
        if let [a, b] = w {
            assert!(!(a.cs != b.cs && a.sck != b.sck));
            if a.sck != b.sck {
                edges += 1;
            }
        }
    }
    assert_eq!(edges, 2 * usize::from(p.bits));
}

fn check_state(io: &mut IoExtension, last_bits: u16) {
    let before = *io;
    let mut cfg_words = [0u16; 2];
    assert!(io.read(addr::CONFIG, &mut cfg_words).is_ok());
    assert_eq!(*io, before, "reading the configuration changes nothing");
    let c = (u32::from(cfg_words[0]) << 16) | u32::from(cfg_words[1]);
    assert_eq!(c & !cfg::DOCUMENTED, 0);
    assert_ne!(c & cfg::SPI_MODE, 0);
    assert_eq!(c & cfg::STATUS != 0, io.status());
    assert_eq!(
        io.rx(),
        io.rx().truncated(last_bits),
        "rx past the bit count is 0"
    );
}

/// One fuzz input (see the module doc).
pub fn run(data: &[u8]) {
    let mut io = IoExtension::new(IoSettings::FACTORY, Clocks::BOARD);
    let mut chain = ShiftChain::new(32, 32);
    let mut running: Option<TransferPlan> = None;
    let mut last_bits = 0u16;
    let mut b = Bytes(data.iter());
    while let Some(&tag) = b.0.next() {
        match tag & 7 {
            0 => read(&mut io, &mut b),
            1 => write(&mut io, &mut b),
            2 => tick(&mut io, &mut b, &mut running),
            3 => {
                if let Some(p) = running.take() {
                    let rx = crate::ioext_wire::transfer(&mut chain, &p);
                    assert!(io.complete(&rx).is_ok());
                    assert!(io.status());
                    last_bits = p.bits;
                } else {
                    assert!(io.complete(&bridge_logic::ioext::WireBits::ZERO).is_err());
                }
            }
            4 => {
                let was = running.take().is_some();
                assert_eq!(io.fail().is_ok(), was);
            }
            5 => {
                let i = usize::from(b.u8());
                chain.set_rx_bit(i, b.u8() & 1 != 0);
            }
            6 => configure(&mut io, &mut b),
            _ => persist(&io, data),
        }
        check_state(&mut io, last_bits);
    }
}

/// Op 0: read up to 23 registers anywhere; refused, it changes nothing.
fn read(io: &mut IoExtension, b: &mut Bytes) {
    let a = b.addr();
    let mut out = [0u16; 24];
    let n = usize::from(b.u8() % 24);
    let before = *io;
    let r = io.read(a, out.get_mut(..n).unwrap_or(&mut []));
    if r.is_err() {
        assert_eq!(*io, before, "a refused read changes nothing");
    }
}

/// Op 1: write up to 23 registers anywhere; refused, it changes nothing.
fn write(io: &mut IoExtension, b: &mut Bytes) {
    let a = b.addr();
    let n = usize::from(b.u8() % 24);
    let mut d = [0u16; 24];
    for w in d.iter_mut().take(n) {
        *w = b.u16();
    }
    let before = *io;
    if io.write(a, d.get(..n).unwrap_or(&[])).is_err() {
        assert_eq!(*io, before, "a refused write changes nothing");
    }
}

/// Op 2: a control tick with the axes' lamps from one byte; a planned
/// transfer is checked and becomes the running one.
fn tick(io: &mut IoExtension, b: &mut Bytes, running: &mut Option<TransferPlan>) {
    let lamps = b.u8();
    let outs = [AxisOutputs {
        moving: lamps & 1 != 0,
        fault: lamps & 2 != 0,
        idle: lamps & 4 != 0,
    }; 8];
    let was_running = io.is_running();
    match io.tick(&outs) {
        Some(Action::Transfer(p)) => {
            assert!(!was_running, "a transfer planned while one runs");
            check_plan(io, &p);
            *running = Some(p);
        }
        Some(Action::Disable) => assert!(!was_running && !io.enabled()),
        None => {}
    }
}

/// Op 6: a valid configuration and enable, to reach deep states fast.
fn configure(io: &mut IoExtension, b: &mut Bytes) {
    let v = u32::from_be_bytes([b.u8(), b.u8(), b.u8(), b.u8()]) | cfg::SPI_MODE;
    let _ = io.write(addr::CONFIG, &[(v >> 16) as u16, v as u16]);
    let _ = io.write(addr::IO_OPTIONS, &[0, u16::from(b.u8() & 1)]);
}

/// Op 7: the persisted settings round-trip through their image; the input
/// itself decodes to an image or an error, never a panic.
fn persist(io: &IoExtension, data: &[u8]) {
    let s = io.settings();
    let mut img = [0u8; IMAGE_LEN];
    s.encode(&mut img);
    assert_eq!(IoSettings::decode(&img), Ok(s));
    let _ = IoSettings::decode(data);
}
