//! What every bus-master harness needs from a bridge on simulated chips.

use bridge_logic::bridge::{Bridge, SettingsSource};
use bridge_logic::postep60::analog::AnalogSample;
use bridge_logic::postep60::{PowerStage, Settings};
use bridge_logic::powerstep::{ChainBus, Command};
use stepbridge_sim::{Powerstep01, SimChain};

/// The harnesses' control period.
pub const TICK_US: u32 = 1000;

/// A bridge on `n` simulated chips with `settings`, measuring 24 V and 25 °C
/// (not yet ticked: the caller runs it until the chips are configured).
pub fn new_bridge(n: usize, settings: Settings, board: PowerStage) -> Bridge<SimChain> {
    new_bridge_at(n, settings, board, TICK_US)
}

/// [`new_bridge`] ticked every `tick_us` µs (the firmware's build setting
/// `STEPBRIDGE_TICK_HZ`; 1000, 500 and 200 µs are tested).
pub fn new_bridge_at(
    n: usize,
    settings: Settings,
    board: PowerStage,
    tick_us: u32,
) -> Bridge<SimChain> {
    let mut bridge = Bridge::new(
        SimChain::new(n),
        board,
        settings,
        SettingsSource::Stored,
        tick_us,
    );
    measure_24v_25c(&mut bridge);
    if overlapped_from_env() {
        tick_overlapped(&mut bridge, n, tick_us);
    }
    bridge
}

/// Tick `bridge` (`n` chips, every `tick_us` µs) overlapped, its batches
/// within the windows the board's period would hold (`rate::fit`), as the
/// firmware runs a chain that needs it.
pub fn tick_overlapped(bridge: &mut Bridge<SimChain>, n: usize, tick_us: u32) {
    bridge.set_overlapped(true);
    let windows = bridge_logic::rate::fit(1_000_000 / tick_us.max(1), n).windows;
    bridge.set_window_budget(usize::from(windows));
}

std::thread_local! {
    static OVERLAPPED: std::cell::Cell<Option<bool>> = const { std::cell::Cell::new(None) };
}

/// Whether the simulated bridges made on this thread tick overlapped
/// (`Bridge::set_overlapped`: batch k on the bus while batch k + 1 is
/// planned): as [`overlapped_in`] says, else `STEPBRIDGE_TICK_OVERLAP=1`
/// in the environment (CI runs the motion suites so).
pub fn overlapped_from_env() -> bool {
    OVERLAPPED
        .get()
        .unwrap_or_else(|| std::env::var("STEPBRIDGE_TICK_OVERLAP").is_ok_and(|v| v == "1"))
}

/// Run `f` with the bridges it makes on this thread ticking overlapped
/// (`on`) or not, whatever the environment says.
pub fn overlapped_in<R>(on: bool, f: impl FnOnce() -> R) -> R {
    let before = OVERLAPPED.replace(Some(on));
    let r = f();
    OVERLAPPED.set(before);
    r
}

/// A bridge on `chain` as it boots from an empty settings page: factory
/// settings, the reference power stage, a 1 ms tick, measuring 24 V and
/// 25 °C (not yet ticked).
pub fn factory_bridge_on<C: ChainBus>(chain: C) -> Bridge<C> {
    let mut bridge = Bridge::new(
        chain,
        PowerStage::REFERENCE,
        Settings::FACTORY,
        SettingsSource::FactoryEmpty,
        TICK_US,
    );
    measure_24v_25c(&mut bridge);
    bridge
}

/// The ADC's raw sample of a 24 V supply at 25 °C on the reference stage.
fn measure_24v_25c<C: ChainBus>(bridge: &mut Bridge<C>) {
    bridge.on_analog(AnalogSample::NOMINAL_24V_25C);
}

/// Every axis settled (profile done, chip landed and confirmed).
pub fn all_settled(bridge: &Bridge<SimChain>) -> bool {
    (0..bridge.axes()).all(|k| bridge.axis(k).is_some_and(|a| a.is_settled()))
}

/// Simulated chip `k` (panics if there is none: a test bug).
pub fn chip(bridge: &Bridge<SimChain>, k: usize) -> &Powerstep01 {
    bridge.chain().bus().device(k).expect("chip")
}

/// The last `n` commands chip `k` received, oldest first (for a failing
/// test's message).
pub fn last_received(bridge: &Bridge<SimChain>, k: usize, n: usize) -> Vec<Command> {
    let all: Vec<Command> = chip(bridge, k).received().copied().collect();
    all[all.len().saturating_sub(n)..].to_vec()
}

pub fn chip_mut(bridge: &mut Bridge<SimChain>, k: usize) -> &mut Powerstep01 {
    bridge.chain_mut().bus_mut().device_mut(k).expect("chip")
}

/// Tick `run_ms(1)` until every axis is settled; panics after `cap` ms.
pub fn settle<H>(
    h: &mut H,
    cap: u64,
    bridge: impl Fn(&H) -> &Bridge<SimChain>,
    mut run_ms: impl FnMut(&mut H),
) {
    for _ in 0..cap {
        if all_settled(bridge(h)) {
            return;
        }
        run_ms(h);
    }
    panic!("not settled after {cap} ms");
}

/// A clone of the value named `name`, built once per thread by `make` (the
/// fuzz targets and property tests start every input from one configured
/// bridge instead of configuring the simulated chips again for each). Each
/// call site names its own template.
pub fn template<T: Clone + 'static>(name: &'static str, make: impl FnOnce() -> T) -> T {
    use std::any::Any;
    use std::cell::RefCell;
    use std::collections::HashMap;
    thread_local! {
        static TEMPLATES: RefCell<HashMap<&'static str, Box<dyn Any>>> =
            RefCell::new(HashMap::new());
    }
    TEMPLATES.with(|t| {
        let mut t = t.borrow_mut();
        let entry = t.entry(name).or_insert_with(|| Box::new(make()));
        match entry.downcast_ref::<T>() {
            Some(v) => v.clone(),
            None => panic!("template {name:?} used with two types"),
        }
    })
}

/// A simulated chain whose bus fails while `broken` (SPI errors: no chip
/// sees the window), for the tests of a chain that stops answering.
#[derive(Debug)]
pub struct Breakable {
    pub sim: SimChain,
    pub broken: bool,
}

impl Breakable {
    /// `n` simulated chips, the bus working.
    pub fn new(n: usize) -> Breakable {
        Breakable {
            sim: SimChain::new(n),
            broken: false,
        }
    }
}

impl ChainBus for Breakable {
    type Error = ();
    fn window(&mut self, tx: &[u8], rx: &mut [u8]) -> Result<(), ()> {
        if self.broken {
            return Err(());
        }
        self.sim.transfer(tx, rx);
        Ok(())
    }
}
