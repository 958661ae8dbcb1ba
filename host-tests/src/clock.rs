//! Virtual time for a control loop that drives simulated chips: tick `k`
//! happens at `k · tick_us`; the control loop puts its batch on the chain at
//! that instant, then the chips live through exactly one tick period. Every
//! harness (I2C and Modbus benches, the motion rig, the benchmark) runs its
//! control loop through [`SimClock::tick`], so they all agree on what "one
//! tick" means.

use bridge_logic::bridge::Bridge;
use bridge_logic::ioext::Action;
use stepbridge_sim::SimChain;

/// A control loop that drives simulated chips.
pub trait SimControl {
    /// One control tick at `now_ms` (puts the tick's batch on the chain).
    fn control_tick(&mut self, now_ms: u64);
    /// The chips the control loop drives.
    fn chips(&mut self) -> &mut SimChain;
}

impl SimControl for Bridge<SimChain> {
    /// The bridge's tick, then what the firmware's I/O extension driver
    /// does before the next tick: run the transfer through the shift
    /// registers attached to the chain ([`SimChain::attach_io`]).
    fn control_tick(&mut self, now_ms: u64) {
        self.tick(now_ms);
        match self.take_io_action() {
            Some(Action::Transfer(plan)) => {
                let rx = crate::ioext_wire::transfer(self.chain_mut().bus_mut().io_mut(), &plan);
                let _ = self.on_io_done(&rx);
            }
            Some(Action::Disable) | None => {}
        }
    }
    fn chips(&mut self) -> &mut SimChain {
        self.chain_mut().bus_mut()
    }
}

/// The virtual clock of a simulated control loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SimClock {
    tick_us: u32,
    ticks: u64,
}

impl SimClock {
    /// A clock at time 0 whose control loop ticks every `tick_us` µs.
    pub const fn new(tick_us: u32) -> SimClock {
        SimClock { tick_us, ticks: 0 }
    }

    pub const fn tick_us(&self) -> u32 {
        self.tick_us
    }

    /// Control ticks so far.
    pub const fn ticks(&self) -> u64 {
        self.ticks
    }

    /// Time of the last control tick, µs.
    pub const fn now_us(&self) -> u64 {
        self.ticks * self.tick_us as u64
    }

    /// Time of the last control tick, ms (what the bridge's tick is given).
    pub const fn now_ms(&self) -> u64 {
        self.now_us() / 1000
    }

    /// When the next control tick is due, µs.
    pub const fn next_tick_us(&self) -> u64 {
        (self.ticks + 1) * self.tick_us as u64
    }

    /// One control tick: the control loop at the tick's time, then one tick
    /// period of chip time.
    pub fn tick(&mut self, control: &mut impl SimControl) {
        self.ticks += 1;
        control.control_tick(self.now_ms());
        control.chips().advance(u64::from(self.tick_us) * 1000);
    }

    /// `n` control ticks.
    pub fn run(&mut self, control: &mut impl SimControl, n: u64) {
        for _ in 0..n {
            self.tick(control);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Counter {
        chips: SimChain,
        seen: [u64; 3],
        n: usize,
    }

    impl SimControl for Counter {
        fn control_tick(&mut self, now_ms: u64) {
            if let Some(slot) = self.seen.get_mut(self.n) {
                *slot = now_ms;
            }
            self.n += 1;
        }
        fn chips(&mut self) -> &mut SimChain {
            &mut self.chips
        }
    }

    #[test]
    fn a_tick_runs_the_control_loop_at_its_time_then_one_period_of_chip_time() {
        let mut c = Counter {
            chips: SimChain::new(1),
            seen: [0; 3],
            n: 0,
        };
        let mut clock = SimClock::new(500);
        clock.run(&mut c, 3);
        assert_eq!(c.seen, [0, 1, 1], "ms of ticks at 0.5, 1.0, 1.5 ms");
        assert_eq!(clock.now_us(), 1500);
        assert_eq!(clock.next_tick_us(), 2000);
    }
}
