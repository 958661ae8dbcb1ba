//! `cargo xtask chain-cpu`: per event of a streaming batch on 8 chips (5
//! windows of 8 bytes; firmware/tests/chain_cost.rs hands the driver the
//! events its interrupts would, QEMU having no DMA and no TIM7), the
//! empty-marker calibration subtracted, then a cycle estimate: 1.5 cycles
//! per instruction (the control tick's own CPI with wait states is ~1.9;
//! these paths are short and straight), plus 4 cycles per load or store that
//! is not a stack or literal-pool access — a peripheral access costs 1 to 4
//! wait cycles (AHB1 DMA2 / GPIOA, APB2 SPI1 at 84 MHz, APB1 TIM7 at 42
//! MHz), RAM ones less, so the estimate errs high —, plus the exception
//! entry and return of every interrupt (12 + 10 cycles on the Cortex-M4 with
//! the FPU context unused: Cortex-M4 TRM §5.5.1; tail-chaining would save
//! some). tests/chain_spi.rs logs the real cycles on a board.

use super::*;

/// Batches the test runs (the counts are divided by it).
const N: u64 = 200;
/// Windows of a batch.
const WINDOWS: u64 = 5;
/// Exception entry and return, cycles.
const ENTRY_EXIT: f64 = 22.0;

/// The test's markers; counter 7 is the calibration.
const RUN: Run = Run {
    image: Image::FirmwareTest("chain_cost"),
    marks: &[
        "armcost_mark_off",
        "armcost_mark_start",
        "armcost_mark_gap",
        "armcost_mark_setup",
        "armcost_mark_window",
        "armcost_mark_last",
        "armcost_mark_poll",
        "armcost_mark_cal",
    ],
    dump: "armcost_mark_dump",
    epoch: None,
    out: "chain.out",
};

/// The events of a batch: counter, name, runs per batch, and whether it is
/// an interrupt (else the control tick's).
const EVENTS: [(usize, &str, u64, bool); 6] = [
    (1, "start of a batch (control tick)", 1, false),
    (
        2,
        "end of a gap (TIM7): CS low, set-up timed",
        WINDOWS,
        true,
    ),
    (3, "end of a set-up (TIM7): TXDMAEN", WINDOWS, true),
    (
        4,
        "end of a window (DMA2_STREAM0): CS high, next armed, gap",
        WINDOWS - 1,
        true,
    ),
    (5, "end of the last window (DMA2_STREAM0)", 1, true),
    (6, "hand-over (poll, control tick)", 1, false),
];

/// `cargo xtask chain-cpu`.
pub fn chain_cpu(args: &[String]) -> Result {
    let (d, c) = Armcount::new()?.run(&RUN, false)?;
    let acc = data_accesses(&d, &c);
    let cal = c.insns(7) as f64 / N as f64;
    println!(
        "chain DMA driver, streaming batch of {WINDOWS} windows x 8 bytes ({N} batches; empty marker pair {cal:.0} instructions, subtracted)"
    );
    let mut batch = Batch::default();
    for (k, name, per, isr) in EVENTS {
        let calls = (N * per) as f64;
        let insn = c.insns(k) as f64 / calls - cal;
        let a = acc.get(&k).copied().unwrap_or(0) as f64 / calls;
        let cyc = 1.5 * insn + 4.0 * a + if isr { ENTRY_EXIT } else { 0.0 };
        println!(
            "  {name:58} {insn:6.0} instructions, ~{a:4.0} loads/stores, ~{cyc:5.0} cycles{}",
            if isr { " (with entry/return)" } else { "" }
        );
        batch.add(insn * per as f64, cyc * per as f64, isr);
    }
    println!(
        "RESULT per batch: {:.0} instructions ({:.0} in {} interrupts), ~{:.0} cycles ({:.0} in the interrupts)",
        batch.insn,
        batch.isr_insn,
        3 * WINDOWS,
        batch.cycles,
        batch.isr_cycles
    );
    for hz in RATES_HZ {
        println!(
            "RESULT CPU share of the chain driver at {} kHz: {:.2} %",
            hz / 1000,
            share(batch.cycles, hz)
        );
    }
    cost::check(
        "CHAIN_DRIVER_TICK_CYCLES",
        batch.tick_cycles,
        write_flag(args),
    )?;
    // The overlapped tick's computation is preempted by these.
    cost::check(
        "CHAIN_DRIVER_ISR_CYCLES",
        batch.isr_cycles,
        write_flag(args),
    )
}

/// Loads and stores other than stack and literal-pool ones, per counter:
/// every peripheral access is one of them (RAM ones are counted too).
fn data_accesses(d: &Disasm, c: &Counts) -> HashMap<usize, u64> {
    let mut acc: HashMap<usize, u64> = HashMap::new();
    for p in &c.pcs {
        if let Some(i) = d.insns.get(&p.pc) {
            let ldst = i.mnemonic.starts_with("ldr") || i.mnemonic.starts_with("str");
            if ldst && !i.operands.contains("[sp") && !i.operands.contains("[pc") {
                *acc.entry(p.counter).or_default() += p.count;
            }
        }
    }
    acc
}

/// A batch's totals: all of it, its interrupts' part and the control
/// tick's part (start and hand-over).
#[derive(Debug, Default)]
struct Batch {
    insn: f64,
    cycles: f64,
    isr_insn: f64,
    isr_cycles: f64,
    tick_cycles: f64,
}

impl Batch {
    fn add(&mut self, insn: f64, cycles: f64, isr: bool) {
        self.insn += insn;
        self.cycles += cycles;
        if isr {
            self.isr_insn += insn;
            self.isr_cycles += cycles;
        } else {
            self.tick_cycles += cycles;
        }
    }
}
