//! A daisy chain of simulated powerSTEP01s wired exactly as AN4290 §2 shows:
//! MCU MOSI → device 0 SDI, device k SDO → device k+1 SDI, device N−1 SDO →
//! MCU MISO, CS and CK common.
//!
//! The chain is one N-byte shift register. A CS window of any length L
//! clocks L bytes: for each byte, MISO gets device N−1's register, every
//! device's register takes the previous device's, device 0's takes the MOSI
//! byte. When CS rises every device latches the byte in its register. So
//! with L = N the first byte sent lands in device N−1 and the first byte
//! received came from device N−1; with L > N the first L − N bytes fall out
//! of the far end onto MISO. A dead device drives its stuck byte on SDO
//! whatever it holds.

use core::convert::Infallible;

use heapless::Vec;

use powerstep01::chain::{ChainBus, MAX_DEVICES};

use crate::chip::Powerstep01;
use crate::shift::ShiftChain;

/// Bytes of the last window kept for [`SimChain::last_window`].
pub const TRACE_LEN: usize = 64;

/// N chained devices (1 ≤ N ≤ [`MAX_DEVICES`]).
#[derive(Clone, Debug)]
pub struct SimChain {
    devices: [Powerstep01; MAX_DEVICES],
    n: usize,
    windows: u64,
    bytes: u64,
    last_tx: Vec<u8, TRACE_LEN>,
    last_rx: Vec<u8, TRACE_LEN>,
    /// The box's shift registers on the I/O extension's port (SPI2), for
    /// harnesses that drive the whole board; none unless attached.
    io: ShiftChain,
}

impl SimChain {
    /// A chain of `n` devices just powered up; `n` is clamped to `1..=MAX_DEVICES`.
    pub fn new(n: usize) -> SimChain {
        SimChain {
            devices: core::array::from_fn(|_| Powerstep01::new()),
            n: n.clamp(1, MAX_DEVICES),
            windows: 0,
            bytes: 0,
            last_tx: Vec::new(),
            last_rx: Vec::new(),
            io: ShiftChain::new(0, 0),
        }
    }

    /// Wire `io` to the I/O extension's port (replacing what was there).
    pub fn attach_io(&mut self, io: ShiftChain) {
        self.io = io;
    }

    /// The shift registers on the I/O extension's port.
    pub fn io(&self) -> &ShiftChain {
        &self.io
    }

    pub fn io_mut(&mut self) -> &mut ShiftChain {
        &mut self.io
    }

    /// Number of devices.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Never true: a chain has at least one device.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Device `k` (0 = the one whose SDI is on MOSI).
    pub fn device(&self, k: usize) -> Option<&Powerstep01> {
        self.devices.get(..self.n)?.get(k)
    }

    pub fn device_mut(&mut self, k: usize) -> Option<&mut Powerstep01> {
        self.devices.get_mut(..self.n)?.get_mut(k)
    }

    /// All devices of the chain, device 0 first.
    pub fn devices(&self) -> &[Powerstep01] {
        self.devices.get(..self.n).unwrap_or(&[])
    }

    pub fn devices_mut(&mut self) -> &mut [Powerstep01] {
        self.devices.get_mut(..self.n).unwrap_or(&mut [])
    }

    /// Let time pass on every device.
    pub fn advance(&mut self, dt_ns: u64) {
        for d in self.devices_mut() {
            d.advance(dt_ns);
        }
    }

    /// CS windows clocked so far.
    pub fn windows(&self) -> u64 {
        self.windows
    }

    /// Bytes clocked so far (sum of window lengths).
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// MOSI bytes of the last window (first [`TRACE_LEN`] bytes).
    pub fn last_window(&self) -> &[u8] {
        &self.last_tx
    }

    /// MISO bytes of the last window (first [`TRACE_LEN`] bytes).
    pub fn last_response(&self) -> &[u8] {
        &self.last_rx
    }

    /// One CS-low window of `min(tx.len(), rx.len())` bytes, then CS high.
    pub fn transfer(&mut self, tx: &[u8], rx: &mut [u8]) {
        let n = self.n;
        let mut sr = [0u8; MAX_DEVICES];
        for (slot, d) in sr.iter_mut().zip(self.devices.iter()).take(n) {
            *slot = d.output();
        }
        // What device k drives on SDO: its register, or its stuck byte.
        let sdo = |devices: &[Powerstep01], sr: &[u8], k: usize| -> u8 {
            match devices.get(k) {
                Some(d) if d.is_dead() => d.output(),
                _ => sr.get(k).copied().unwrap_or(0),
            }
        };
        self.last_tx.clear();
        self.last_rx.clear();
        let mut count = 0u64;
        for (t, r) in tx.iter().zip(rx.iter_mut()) {
            let miso = sdo(&self.devices, &sr, n.saturating_sub(1));
            for k in (1..n).rev() {
                let b = sdo(&self.devices, &sr, k.saturating_sub(1));
                if let Some(slot) = sr.get_mut(k) {
                    *slot = b;
                }
            }
            sr[0] = *t;
            *r = miso;
            let _ = self.last_tx.push(*t);
            let _ = self.last_rx.push(miso);
            count = count.saturating_add(1);
        }
        for (d, b) in self.devices.iter_mut().zip(sr.iter()).take(n) {
            d.latch(*b);
        }
        self.windows = self.windows.saturating_add(1);
        self.bytes = self.bytes.saturating_add(count);
    }
}

impl ChainBus for SimChain {
    type Error = Infallible;

    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), Infallible> {
        self.transfer(tx, rx);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use std::vec;
    use std::vec::Vec;

    use powerstep01::{Command, Register};

    use super::*;
    use crate::chip::Fault;
    use crate::vocab;

    fn window(c: &mut SimChain, tx: &[u8]) -> Vec<u8> {
        let mut rx = vec![0xAA; tx.len()];
        c.transfer(tx, &mut rx);
        rx
    }

    #[test]
    fn new_clamps_the_length_to_1_through_max_devices() {
        assert_eq!(SimChain::new(0).len(), 1);
        assert_eq!(SimChain::new(3).len(), 3);
        assert_eq!(SimChain::new(99).len(), MAX_DEVICES);
        assert!(SimChain::new(2).device(2).is_none());
        assert!(SimChain::new(2).device(1).is_some());
    }

    #[test]
    fn window_of_n_bytes_delivers_byte_j_to_device_n_minus_1_minus_j() {
        for n in 1..=MAX_DEVICES {
            let mut c = SimChain::new(n);
            // Byte j = GetParam of register j+1: distinct and harmless.
            let tx: Vec<u8> = (0..n as u8).map(|j| 0x20 | (j + 1)).collect();
            window(&mut c, &tx);
            for j in 0..n {
                let dev = c.device(n - 1 - j).unwrap();
                let reg = vocab::register(j as u8 + 1).unwrap();
                assert_eq!(
                    dev.received().last(),
                    Some(&Command::GetParam(reg)),
                    "n {n} j {j}"
                );
            }
        }
    }

    /// `n` chips, chip k's KVAL_HOLD = 0x40 + k, each sent GetParam(KVAL_HOLD)
    /// (its answer waits in its shift register).
    fn kval_hold_queued(n: usize) -> SimChain {
        let mut c = SimChain::new(n);
        for k in 0..n {
            c.device_mut(k)
                .unwrap()
                .set_register_raw(Register::KvalHold, 0x40 + k as u32);
        }
        window(&mut c, &vec![0x29; n]);
        c
    }

    #[test]
    fn window_of_n_bytes_returns_device_n_minus_1_minus_j_output_in_rx_j() {
        for n in 1..=MAX_DEVICES {
            let mut c = kval_hold_queued(n);
            let rx = window(&mut c, &vec![0x00; n]);
            let want: Vec<u8> = (0..n).map(|j| 0x40 + (n - 1 - j) as u8).collect();
            assert_eq!(rx, want, "n {n}");
            assert_eq!(window(&mut c, &vec![0x00; n]), vec![0; n]);
        }
    }

    #[test]
    fn a_longer_window_shifts_the_first_bytes_out_onto_miso() {
        for n in 1..=MAX_DEVICES {
            let mut c = kval_hold_queued(n);
            let l = n + 3;
            let tx: Vec<u8> = (0..l as u8).map(|i| 0x21 + i).collect();
            let rx = window(&mut c, &tx);
            for (j, b) in rx.iter().take(n).enumerate() {
                assert_eq!(*b, 0x40 + (n - 1 - j) as u8, "n {n} j {j}");
            }
            for i in 0..3 {
                assert_eq!(rx[n + i], tx[i], "n {n}: byte {i} falls out");
            }
            // Device k holds tx[l - 1 - k] at CS rise.
            for k in 0..n {
                let reg = vocab::register(tx[l - 1 - k] & 0x1F).unwrap();
                let dev = c.device(k).unwrap();
                assert_eq!(dev.received().last(), Some(&Command::GetParam(reg)));
            }
            assert_eq!(c.windows(), 2);
            assert_eq!(c.bytes(), (n + l) as u64);
            assert_eq!(c.last_window(), &tx[..]);
            assert_eq!(c.last_response(), &rx[..]);
        }
    }

    #[test]
    fn a_shorter_window_only_reaches_the_first_devices() {
        let mut c = SimChain::new(4);
        window(&mut c, &[0x29, 0x29]);
        // Devices 0 and 1 got GetParam; devices 2 and 3 got the bytes that
        // devices 1 and 0 shifted out (0x00 = NOP).
        assert_eq!(c.device(0).unwrap().received_count(), 1);
        assert_eq!(c.device(1).unwrap().received_count(), 1);
        assert_eq!(c.device(2).unwrap().received_count(), 0);
        assert_eq!(c.device(3).unwrap().received_count(), 0);
    }

    #[test]
    fn mismatched_buffer_lengths_use_the_shorter_one() {
        let mut c = SimChain::new(3);
        let mut rx = [0xAAu8; 2];
        c.transfer(&[0x00; 5], &mut rx);
        assert_eq!(c.bytes(), 2);
        let mut rx = [0xAAu8; 6];
        c.transfer(&[0x00; 1], &mut rx);
        assert_eq!(rx[1..], [0xAA; 5]);
        c.transfer(&[], &mut []);
        assert_eq!(c.windows(), 3);
    }

    #[test]
    fn dead_device_drives_its_stuck_byte_downstream_and_to_miso() {
        let mut c = SimChain::new(3);
        c.device_mut(1).unwrap().inject(Fault::Dead(0xFF));
        let rx = window(&mut c, &[0x00, 0x00, 0x00]);
        // rx[0] from device 2 (healthy), rx[1] = what device 1 drove last window…
        assert_eq!(rx[0], 0x00);
        // …device 2 now holds 0xFF (an unknown command): CMD_ERROR.
        assert!(c.device(2).unwrap().status_word().command_error());
        assert!(!c.device(0).unwrap().status_word().command_error());
        let rx = window(&mut c, &[0x00; 4]);
        assert_eq!(rx[1..], [0xFF, 0xFF, 0xFF]);
    }
}
