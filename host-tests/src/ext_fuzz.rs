//! Arbitrary extension-space traffic (reads and writes of any address and
//! length on any axis, control ticks in between) into a bridge on two
//! simulated chips: the body of the `ext_space` fuzz target and of a
//! property test in `tests/`.
//!
//! What must hold whatever arrives:
//! * nothing panics;
//! * no write reaches a chip that the chip refuses (the access classes are
//!   checked before anything goes on the wire): the simulated chips count
//!   no CMD_ERROR;
//! * no motor moves unless a homing start (0x0400 = 1) was accepted — the
//!   extension space has no other motion command.

use crate::clock::SimClock;
use bridge_logic::postep60::{PowerStage, Settings};

use crate::sim_bridge::{chip, new_bridge, TICK_US};

/// Addresses worth hitting: the blocks that exist, their edges, and any.
fn address(hi: u8, lo: u8) -> u16 {
    let block = match hi % 8 {
        0 => 0x01,
        1 => 0x02,
        2 => 0x03,
        3 => 0x04,
        4 => 0x05,
        5 => 0x06,
        6 => 0x00,
        _ => hi,
    };
    u16::from_be_bytes([block, lo])
}

/// Run the traffic in `data`; returns the requests made.
pub fn check_ext_stream(data: &[u8]) -> usize {
    let (mut bridge, mut clock) = crate::sim_bridge::template("ext_stream", || {
        let mut s = Settings::FACTORY;
        s.axes[0].end_switch = true;
        let mut bridge = new_bridge(2, s, PowerStage::REFERENCE);
        let mut clock = SimClock::new(TICK_US);
        clock.run(&mut bridge, 30);
        (bridge, clock)
    });
    let mut it = data.iter().copied();
    let mut homing = false;
    let mut requests = 0;
    while let Some(tag) = it.next() {
        let k = usize::from(tag >> 6);
        let (hi, lo) = (it.next().unwrap_or(0), it.next().unwrap_or(0));
        let addr = address(hi, lo);
        match tag & 3 {
            0 => {
                let n = usize::from(it.next().unwrap_or(0) % 40);
                let mut out = vec![0u16; n];
                let _ = bridge.ext_read(k, addr, &mut out);
                requests += 1;
            }
            1 | 2 => {
                let n = usize::from(it.next().unwrap_or(0) % 20);
                let words: Vec<u16> = (0..n)
                    .map(|_| u16::from_be_bytes([it.next().unwrap_or(0), it.next().unwrap_or(0)]))
                    .collect();
                let ok = bridge.ext_write(k, addr, &words).is_ok();
                if ok && addr == 0x0400 && words.first() == Some(&1) {
                    homing = true;
                }
                requests += 1;
            }
            _ => clock.run(&mut bridge, u64::from(hi % 50)),
        }
    }
    clock.run(&mut bridge, 50);
    for k in 0..2 {
        let c = chip(&bridge, k);
        assert_eq!(
            c.command_errors(),
            0,
            "chip {k} refused a command the bridge sent"
        );
        if !homing {
            assert_eq!(
                c.shaft_position(),
                0,
                "chip {k} moved without a motion command"
            );
        }
    }
    requests
}
