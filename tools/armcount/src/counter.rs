//! What the plugin keeps: the translated blocks, which counter is running,
//! and per counter the instructions, blocks and cache misses. Plain Rust,
//! no QEMU types: `ffi` feeds it what QEMU reports.
//!
//! Counters are selected by *marker addresses*: `mark=A0,mark=A1,...`
//! make counter k current whenever a block starting at Ak runs (counter 0
//! counts nothing). Every instruction of every block that runs while
//! counter k > 0 is current is counted in k, per instruction address too.
//! A bench calls an empty marker function before and after a region, so
//! the region's instructions, plus a marker's own few, land in its counter.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;

use crate::art::{Art, Misses};

/// Plugin arguments (`-plugin libarmcount.so,ARG,ARG,...`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Config {
    /// Marker addresses, counter 0 first (Thumb bit cleared).
    pub marks: Vec<u64>,
    /// The report is written when a block starting here runs (and at exit).
    pub dump: Option<u64>,
    /// Report file.
    pub out: PathBuf,
    /// A block starting here ends an *epoch* (a bench's tick): each
    /// counter's largest count within one epoch is reported too.
    pub epoch: Option<u64>,
}

/// Parse `mark=ADDR` (repeated, in counter order), `dump=ADDR`, `out=FILE`.
/// Addresses are hexadecimal with `0x` or decimal.
pub fn parse_args<'a>(args: impl IntoIterator<Item = &'a str>) -> Result<Config, String> {
    let mut c = Config {
        marks: Vec::new(),
        dump: None,
        out: PathBuf::from("armcount.out"),
        epoch: None,
    };
    for a in args {
        let (key, value) = a
            .split_once('=')
            .ok_or_else(|| format!("argument '{a}' is not KEY=VALUE"))?;
        match key {
            "mark" => c.marks.push(parse_addr(value)?),
            "dump" => c.dump = Some(parse_addr(value)?),
            "out" => c.out = PathBuf::from(value),
            "epoch" => c.epoch = Some(parse_addr(value)?),
            _ => {
                return Err(format!(
                    "unknown argument '{a}' (mark=, dump=, out=, epoch=)"
                ))
            }
        }
    }
    if c.marks.is_empty() {
        return Err("no mark= given: nothing would be counted".into());
    }
    Ok(c)
}

fn parse_addr(s: &str) -> Result<u64, String> {
    let v = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(hex) => u64::from_str_radix(hex, 16),
        None => s.parse(),
    }
    .map_err(|_| format!("'{s}' is not an address"))?;
    // Thumb function symbols have bit 0 set; instructions start at even
    // addresses.
    Ok(v & !1)
}

/// One translated block: its instructions and what ran of it.
#[derive(Debug)]
struct Block {
    start: u64,
    /// First byte after its last instruction.
    end: u64,
    /// (address, size) of each instruction.
    insns: Vec<(u64, u8)>,
    /// The counter a run of this block makes current (it starts at a marker).
    selects: Option<usize>,
    /// A run of this block writes the report.
    dumps: bool,
    /// A run of this block ends an epoch.
    epoch: bool,
    /// Runs per counter.
    runs: Vec<u64>,
    /// Per counter: runs after which the next block was not the one right
    /// after this one (a taken branch, a call, a return, an exception).
    left_by_jump: Vec<u64>,
}

/// Per-counter totals.
#[derive(Debug, Clone, Copy, Default)]
struct Totals {
    insns: u64,
    blocks: u64,
    /// Cache seeing only counted blocks.
    warm: Misses,
    /// Cache seeing every block (counted in the counter current at the time).
    cold: Misses,
    /// Instructions since the last epoch, and the most in any one epoch.
    since_epoch: u64,
    epoch_max: u64,
    /// The epoch (0 = before the first epoch block) of `epoch_max`.
    epoch_max_at: u64,
}

/// The plugin's state.
#[derive(Debug)]
pub struct Counter {
    config: Config,
    blocks: Vec<Block>,
    current: usize,
    /// The block that ran last and the counter current while it ran.
    previous: Option<(usize, usize)>,
    totals: Vec<Totals>,
    warm: Art,
    cold: Art,
    reported: bool,
    /// Epoch blocks run so far.
    epochs: u64,
    /// Instructions of every counter since the last epoch block, and the
    /// most of one epoch with the epoch it was (a bench's whole tick).
    epoch_all: u64,
    epoch_all_max: (u64, u64),
}

impl Counter {
    pub fn new(config: Config) -> Self {
        let n = config.marks.len();
        Self {
            config,
            blocks: Vec::new(),
            current: 0,
            previous: None,
            totals: vec![Totals::default(); n],
            warm: Art::default(),
            cold: Art::default(),
            reported: false,
            epochs: 0,
            epoch_all: 0,
            epoch_all_max: (0, 0),
        }
    }

    pub fn out_path(&self) -> &std::path::Path {
        &self.config.out
    }

    /// QEMU translated a block of `insns` (address, size): its handle for
    /// `executed`.
    pub fn translated(&mut self, insns: Vec<(u64, u8)>) -> usize {
        let start = insns.first().map_or(0, |&(pc, _)| pc);
        let end = insns
            .last()
            .map_or(start, |&(pc, size)| pc.saturating_add(u64::from(size)));
        let n = self.totals.len();
        let selects = self.config.marks.iter().position(|&m| m == start);
        self.blocks.push(Block {
            start,
            end,
            insns,
            selects,
            dumps: self.config.dump == Some(start),
            epoch: self.config.epoch == Some(start),
            runs: vec![0; n],
            left_by_jump: vec![0; n],
        });
        self.blocks.len() - 1
    }

    /// Block `handle` is about to run. Returns true when it is the dump
    /// block (the caller writes the report then).
    pub fn executed(&mut self, handle: usize) -> bool {
        let Some(block) = self.blocks.get(handle) else {
            return false;
        };
        let (start, end, selects, dumps, n_insns) = (
            block.start,
            block.end,
            block.selects,
            block.dumps,
            block.insns.len() as u64,
        );
        if block.epoch {
            for t in &mut self.totals {
                if t.since_epoch > t.epoch_max {
                    t.epoch_max = t.since_epoch;
                    t.epoch_max_at = self.epochs;
                }
                t.since_epoch = 0;
            }
            if self.epoch_all > self.epoch_all_max.0 {
                self.epoch_all_max = (self.epoch_all, self.epochs);
            }
            self.epoch_all = 0;
            self.epochs += 1;
        }
        // How was the previous block left?
        if let Some((prev, ctr)) = self.previous {
            if ctr != 0 {
                if let Some(p) = self.blocks.get_mut(prev) {
                    if p.end != start {
                        if let Some(t) = p.left_by_jump.get_mut(ctr) {
                            *t += 1;
                        }
                    }
                }
            }
        }
        if let Some(k) = selects {
            self.current = k;
        }
        let k = self.current;
        // Code outside the flash (run from SRAM) bypasses the ART.
        let art = crate::art::through_art(start);
        let cold = if art {
            self.cold.fetch_range(start, end)
        } else {
            Misses::default()
        };
        let counting = k != 0;
        let warm = if counting && art {
            self.warm.fetch_range(start, end)
        } else {
            Misses::default()
        };
        if let Some(t) = self.totals.get_mut(k) {
            add(&mut t.cold, cold);
            if counting {
                add(&mut t.warm, warm);
                t.insns += n_insns;
                t.since_epoch += n_insns;
                self.epoch_all += n_insns;
                t.blocks += 1;
            }
        }
        if counting {
            if let Some(r) = self.blocks.get_mut(handle).and_then(|b| b.runs.get_mut(k)) {
                *r += 1;
            }
        }
        self.previous = Some((handle, k));
        dumps
    }

    /// The report, once: `None` if it was already made.
    pub fn take_report(&mut self) -> Option<String> {
        if self.reported {
            return None;
        }
        self.reported = true;
        Some(self.report())
    }

    /// The report (format in the crate doc).
    pub fn report(&self) -> String {
        // (address, counter) -> (size, count, taken)
        let mut per_pc: BTreeMap<(u64, usize), (u8, u64, u64)> = BTreeMap::new();
        for b in &self.blocks {
            let last = b.insns.len().saturating_sub(1);
            for (k, (&runs, &jumps)) in b.runs.iter().zip(&b.left_by_jump).enumerate().skip(1) {
                if runs == 0 && jumps == 0 {
                    continue;
                }
                for (i, &(pc, size)) in b.insns.iter().enumerate() {
                    let e = per_pc.entry((pc, k)).or_insert((size, 0, 0));
                    e.1 += runs;
                    if i == last {
                        e.2 += jumps;
                    }
                }
            }
        }
        let mut s = String::new();
        let _ = writeln!(s, "armcount-report 1");
        let _ = writeln!(s, "counters {}", self.totals.len());
        for (k, t) in self.totals.iter().enumerate().skip(1) {
            let _ = writeln!(
                s,
                "counter {k} insns {} blocks {} lines {} warm {} {} cold {} {} epochmax {} at {}",
                t.insns,
                t.blocks,
                t.warm.lines,
                t.warm.sequential,
                t.warm.jump,
                t.cold.sequential,
                t.cold.jump,
                t.epoch_max,
                t.epoch_max_at
            );
        }
        if self.config.epoch.is_some() {
            // Only epochs an epoch block ended (what runs after the last
            // one is no tick).
            let (max, at) = self.epoch_all_max;
            let _ = writeln!(s, "epochs {} max {max} at {at}", self.epochs);
        }
        for ((pc, k), (size, count, taken)) in per_pc {
            let _ = writeln!(s, "pc {pc:x} {size} {k} {count} {taken}");
        }
        s
    }

    /// One line per counter, for QEMU's log (`-d plugin`).
    pub fn summary(&self) -> String {
        let mut s = String::new();
        for (k, t) in self.totals.iter().enumerate().skip(1) {
            let _ = writeln!(
                s,
                "armcount: counter {k}: {} instructions in {} blocks",
                t.insns, t.blocks
            );
        }
        s
    }
}

fn add(a: &mut Misses, b: Misses) {
    a.lines += b.lines;
    a.sequential += b.sequential;
    a.jump += b.jump;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn counter() -> Counter {
        let c = parse_args(["mark=0x1001", "mark=0x2000", "dump=0x3000", "out=/dev/null"])
            .unwrap_or_else(|e| unreachable!("{e}"));
        Counter::new(c)
    }

    #[test]
    fn arguments() {
        let c = parse_args(["mark=0x1001", "mark=8192", "dump=0x3001", "out=x.txt"]);
        assert_eq!(
            c,
            Ok(Config {
                marks: vec![0x1000, 0x2000],
                dump: Some(0x3000),
                out: PathBuf::from("x.txt"),
                epoch: None,
            })
        );
        assert_eq!(
            parse_args(["mark=1", "epoch=0x41"]).map(|c| c.epoch),
            Ok(Some(0x40))
        );
        assert!(parse_args(["mark=zz"]).is_err());
        assert!(parse_args(["frob=1", "mark=1"]).is_err());
        assert!(parse_args(["out=x"]).is_err());
    }

    #[test]
    fn counts_between_markers_per_counter_and_per_pc() {
        let mut c = counter();
        let off = c.translated(vec![(0x1000, 2), (0x1002, 2)]); // marker 0
        let on = c.translated(vec![(0x2000, 2), (0x2002, 4)]); // marker 1
        let work = c.translated(vec![(0x4000, 2), (0x4002, 2), (0x4004, 2)]);
        let after = c.translated(vec![(0x4006, 2)]);
        let dump = c.translated(vec![(0x3000, 2)]);
        // Not counting yet.
        c.executed(work);
        for _ in 0..3 {
            c.executed(on);
            c.executed(work); // entered by a jump from `on`
            c.executed(after); // falls through from `work`
            c.executed(off);
        }
        c.executed(work);
        assert!(c.executed(dump));
        let r = c.report();
        // Counter 1: `on` (2) + `work` (3) + `after` (1), three times; the
        // marker-0 block switches back before it runs, so it is not counted.
        assert!(r.contains("counter 1 insns 18 blocks 9 "), "{r}");
        assert!(r.contains("pc 4000 2 1 3 0\n"), "{r}");
        // `on` was left by a jump to 0x4000 every time, `work` never.
        assert!(r.contains("pc 2002 4 1 3 3\n"), "{r}");
        assert!(r.contains("pc 4004 2 1 3 0\n"), "{r}");
        // `after` jumped to the marker each time.
        assert!(r.contains("pc 4006 2 1 3 3\n"), "{r}");
        assert!(!r.contains(" 0 0\n"), "{r}");
    }

    #[test]
    fn the_largest_count_of_one_epoch_is_reported() {
        let config = parse_args(["mark=0x1000", "mark=0x2000", "epoch=0x5000", "out=x"])
            .unwrap_or_else(|e| unreachable!("{e}"));
        let mut c = Counter::new(config);
        let off = c.translated(vec![(0x1000, 2)]);
        let on = c.translated(vec![(0x2000, 2)]);
        let work = c.translated(vec![(0x4000, 2), (0x4002, 2)]);
        let epoch = c.translated(vec![(0x5000, 2)]);
        // Epochs of 1, 3 and 2 runs of `work` (each with the marker: 3, 7, 5).
        for runs in [1, 3, 2] {
            c.executed(epoch);
            c.executed(on);
            for _ in 0..runs {
                c.executed(work);
            }
            c.executed(off);
        }
        let r = c.report();
        assert!(r.contains("counter 1 insns 15 "), "{r}");
        assert!(r.contains(" epochmax 7 at 2\n"), "{r}");
        // All counters of one epoch together (here only counter 1).
        assert!(r.contains("\nepochs 3 max 7 at 2\n"), "{r}");
    }

    #[test]
    fn report_once() {
        let mut c = counter();
        assert!(c.take_report().is_some());
        assert!(c.take_report().is_none());
    }
}
