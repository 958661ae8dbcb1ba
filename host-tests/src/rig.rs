//! A test rig: N simulated powerSTEP01s on a chain, an [`AxisGroup`] driving
//! them at a fixed control tick, and a virtual clock that advances the chips
//! by exactly one tick per control tick.

use crate::clock::{SimClock, SimControl};
use bridge_logic::motion::{Axis, AxisConfig, AxisGroup, AxisState, Limits, TickReport};
use bridge_logic::powerstep::chain::Chain;
use bridge_logic::powerstep::registers::sign_extend_22;
use bridge_logic::powerstep::{DriveMode, StepSel};
use stepbridge_sim::SimChain;

/// An axis's configuration at the build's control tick
/// (`STEPBRIDGE_TICK_HZ`; CI runs the motion suites at 1, 2 and 5 kHz).
pub fn config(logical_shift: u8, step: StepSel, drive: DriveMode) -> AxisConfig {
    AxisConfig {
        tick_us: bridge_logic::rate::TICK_US,
        logical_shift,
        step,
        drive,
    }
}

/// An axis group and its chain as one simulated control loop.
pub struct GroupOnChain<'a> {
    pub group: &'a mut AxisGroup,
    pub chain: &'a mut Chain<SimChain>,
    /// What the last tick put on the chain (`None`: the chain failed).
    pub report: Option<TickReport>,
}

impl SimControl for GroupOnChain<'_> {
    fn control_tick(&mut self, _now_ms: u64) {
        self.report = self.group.tick(self.chain).ok();
    }
    fn chips(&mut self) -> &mut SimChain {
        self.chain.bus_mut()
    }
}

/// Simulated chain + axes + virtual clock.
pub struct Rig {
    pub chain: Chain<SimChain>,
    pub group: AxisGroup,
    /// The virtual clock; `clock.ticks()` control ticks have run.
    pub clock: SimClock,
    /// Unwrapped ABS_POS of every simulated chip (tracked tick by tick).
    chip_wide: Vec<i64>,
    chip_raw: Vec<i32>,
    /// Largest |profile − chip| seen while streaming, per axis, in microsteps.
    pub max_following: Vec<i64>,
    pub last_report: Option<TickReport>,
}

impl Rig {
    /// A chain of `configs.len()` chips, detected, with one axis per chip,
    /// configured (setup ticks run).
    pub fn new(configs: &[AxisConfig], limits: Limits) -> Rig {
        let n = configs.len();
        let mut chain = Chain::new(SimChain::new(n));
        assert_eq!(chain.detect(), Ok(n), "chain detection");
        let mut group = AxisGroup::new();
        for cfg in configs {
            assert!(group.push(Axis::new(*cfg, limits)).is_ok());
        }
        let tick_us = configs.first().map(|c| c.tick_us).unwrap_or(1000);
        let mut rig = Rig {
            chain,
            group,
            clock: SimClock::new(tick_us),
            chip_wide: vec![0; n],
            chip_raw: vec![0; n],
            max_following: vec![0; n],
            last_report: None,
        };
        rig.run_until_settled(100);
        rig
    }

    pub fn axis(&mut self, k: usize) -> &mut Axis {
        self.group.axis_mut(k).expect("axis exists")
    }

    /// Unwrapped position of simulated chip `k` (microsteps).
    pub fn chip_position(&self, k: usize) -> i64 {
        self.chip_wide[k]
    }

    /// One control tick: the batch goes out, then the chips run for one tick.
    pub fn tick(&mut self) {
        let mut on_chain = GroupOnChain {
            group: &mut self.group,
            chain: &mut self.chain,
            report: None,
        };
        self.clock.tick(&mut on_chain);
        self.last_report = Some(on_chain.report.expect("chain tick"));
        for k in 0..self.group.len() {
            let raw = self.chain.bus().device(k).expect("device").abs_pos();
            let delta = sign_extend_22((raw.wrapping_sub(self.chip_raw[k]) as u32) & 0x3F_FFFF);
            self.chip_raw[k] = raw;
            self.chip_wide[k] += i64::from(delta);
            let axis = self.group.axis(k).expect("axis");
            if axis.state() == AxisState::Streaming {
                let e = (axis.profile_physical() - self.chip_wide[k]).abs();
                self.max_following[k] = self.max_following[k].max(e);
            }
        }
    }

    pub fn run(&mut self, ticks: u32) {
        for _ in 0..ticks {
            self.tick();
        }
    }

    /// Tick until every axis is settled (panics after `cap_ms` ms of ticks,
    /// whatever the tick period); returns the ticks it took.
    pub fn run_until_settled(&mut self, cap_ms: u32) -> u32 {
        let cap = cap_ms.saturating_mul(1000) / self.clock.tick_us().max(1);
        let mut n = 0;
        while !self.group.is_settled() {
            self.tick();
            n += 1;
            assert!(
                n <= cap,
                "not settled after {cap} ticks: {}",
                self.describe()
            );
        }
        n
    }

    /// One line per axis: state, profile mode, speed, positions.
    pub fn describe(&self) -> String {
        let mut out = String::new();
        for (k, a) in self.group.iter().enumerate() {
            out.push_str(&format!(
                "\n  axis {k}: {:?} {:?} v={} prof={} chip={} limits={:?} fault={:?}",
                a.state(),
                a.profile().mode(),
                a.profile().velocity(),
                a.profile().position_round(),
                self.chip_wide[k],
                a.profile().limits(),
                a.fault()
            ));
        }
        out
    }

    pub fn states(&self) -> Vec<AxisState> {
        self.group.iter().map(|a| a.state()).collect()
    }

    /// Re-base the rig's unwrapped chip position after the chip's frame was re-based.
    pub fn resync_chip_tracking(&mut self, k: usize, wide: i64) {
        self.chip_wide[k] = wide;
        self.chip_raw[k] = self.chain.bus().device(k).expect("device").abs_pos();
    }
}
