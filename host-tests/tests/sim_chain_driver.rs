//! The driver's chain owner (`powerstep::Chain`) on the simulated chain:
//! detection of every length, a dead device, status polls and a batch. The
//! simulator's own tests use no driver code, so these integration checks
//! live here, where both crates are visible.

use bridge_logic::powerstep::{
    Batch, Chain, ChainError, Command, Direction, Register, MAX_DEVICES,
};
use stepbridge_sim::{Fault, SimChain};

#[test]
fn chain_detect_finds_every_length_from_1_to_8() {
    for n in 1..=MAX_DEVICES {
        let mut chain = Chain::new(SimChain::new(n));
        assert_eq!(chain.detect(), Ok(n));
        assert_eq!(chain.len(), n);
    }
}

#[test]
fn chain_detect_reports_no_echo_when_a_device_is_dead() {
    for stuck in [0xFF, 0x00] {
        for n in 1..=MAX_DEVICES {
            for k in 0..n {
                let mut sim = SimChain::new(n);
                sim.device_mut(k).unwrap().inject(Fault::Dead(stuck));
                let mut chain = Chain::new(sim);
                assert_eq!(
                    chain.detect(),
                    Err(ChainError::NoEcho),
                    "n {n} k {k} {stuck:#x}"
                );
            }
        }
    }
}

#[test]
fn chain_poll_status_reads_each_devices_own_status() {
    let mut chain = Chain::new(SimChain::new(4));
    chain.detect().unwrap();
    let first = chain.poll_status().unwrap();
    for k in 0..4 {
        assert!(first.status(k).unwrap().uvlo(), "power-up UVLO, device {k}");
    }
    let sim = chain.bus_mut();
    sim.device_mut(2).unwrap().inject(Fault::Overcurrent);
    sim.device_mut(0).unwrap().set_switch(true);
    sim.device_mut(3).unwrap().inject(Fault::Stall);
    let r = chain.poll_status().unwrap();
    for k in 0..4 {
        let s = r.status(k).unwrap();
        assert!(!s.uvlo(), "cleared by the first poll");
        assert_eq!(s.overcurrent(), k == 2, "device {k}");
        assert_eq!(s.switch_closed(), k == 0, "device {k}");
        assert_eq!(s.stalled(), k == 3, "device {k}");
        assert!(s.hiz());
    }
    let again = chain.poll_status().unwrap();
    assert!(
        !again.status(2).unwrap().overcurrent(),
        "GetStatus released OCD"
    );
    assert!(again.status(0).unwrap().switch_closed(), "SW_F is a level");
}

#[test]
fn chain_batch_runs_every_device_and_reads_positions_back() {
    let mut chain = Chain::new(SimChain::new(3));
    chain.detect().unwrap();
    chain.poll_status().unwrap();
    let mut b = Batch::new(3);
    for d in 0..3 {
        let dir = if d == 1 {
            Direction::Reverse
        } else {
            Direction::Forward
        };
        b.push(d, Command::Run(dir, 10_000 * (d as u32 + 1)))
            .unwrap();
    }
    chain.execute(&b).unwrap();
    chain.bus_mut().advance(1_000_000_000);
    let mut read = Batch::new(3);
    for d in 0..3 {
        read.push(d, Command::GetParam(Register::AbsPos)).unwrap();
    }
    let r = chain.execute(&read).unwrap();
    for d in 0..3 {
        let dev = chain.bus().device(d).unwrap();
        let raw = r.param(d, Register::AbsPos).unwrap();
        assert_eq!(raw, dev.register(Register::AbsPos), "device {d}");
        assert_eq!(dev.abs_pos() < 0, d == 1);
        assert_ne!(dev.abs_pos(), 0);
        assert_eq!(dev.command_errors(), 0);
    }
}
