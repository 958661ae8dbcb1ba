//! The instruction-count benchmarks on the real ISA: bench images for
//! thumbv7em run under QEMU 7.2 with the repository's own TCG plugin
//! (`tools/armcount`), which counts every guest instruction between marker
//! functions; the analysis here adds per-function breakdowns, 64-bit
//! division helper calls, ART cache misses and a Cortex-M4 cycle estimate.
//!
//! * `tick-cpu`: the control tick (8 axes streaming against simulated
//!   chips: `cargo xtask bench`'s workload), `firmware/armcount-bench`'s
//!   `tick-armcount`. `STEPBRIDGE_TICK_HZ` selects the build's tick rate.
//! * `chain-cpu`: the chain's DMA driver per streaming batch
//!   (`firmware/tests/chain_cost.rs`).
//! * `ioext-cpu`: the I/O extension per 256-bit transfer
//!   (`ioext-armcount`) and the board driver's transfer start
//!   (`firmware/tests/ioext_cost.rs`).
//!
//! Flash wait states: 5 at 168 MHz and 2.7–3.6 V (RM0090 §3.5.1, table 10
//! "Number of wait states according to CPU clock (HCLK) frequency"); a
//! line the ART cache (`tools/armcount`'s model, RM0090 §3.4.2) misses
//! costs them, half hidden by the prefetch buffer when the miss is
//! sequential (RM0090 §3.4.1): 2.5 cycles, else 5. Not timed tests.

mod chain;
pub mod cost;
pub mod cycles;
pub mod disasm;
mod ioext;
mod tick;

pub use chain::chain_cpu;
pub use ioext::ioext_cpu;
pub use tick::tick_cpu;

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::setup::{self, Qemu, TARGET};
use crate::util::{self, bail, Result};
use disasm::Disasm;

/// CPU clock of the board (RM0090 §6: 168 MHz maximum; platform/stm32f405.rs's PLL (freeze_clocks)).
const SYSCLK_HZ: f64 = 168e6;
/// Flash wait states at 168 MHz (RM0090 table 10).
const WAIT_STATES: f64 = 5.0;
/// Control-tick rates the CPU shares are shown for.
const RATES_HZ: [u32; 4] = [1000, 2000, 5000, 10_000];

/// One counter's totals from the plugin.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Totals {
    pub insns: u64,
    pub blocks: u64,
    pub lines: u64,
    pub warm_seq: u64,
    pub warm_jump: u64,
    pub cold_seq: u64,
    pub cold_jump: u64,
    /// The most instructions of one epoch (a bench's tick; 0 without one).
    pub epoch_max: u64,
}

/// One instruction's count in one counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PcCount {
    pub pc: u64,
    pub counter: usize,
    pub count: u64,
    pub taken: u64,
}

/// The plugin's report (`tools/armcount`'s format).
#[derive(Debug, Default)]
pub struct Counts {
    pub totals: HashMap<usize, Totals>,
    pub pcs: Vec<PcCount>,
    /// With epochs: the most instructions of all counters in one epoch, and
    /// which epoch (0 = before the first epoch block).
    pub epoch_max: Option<(u64, u64)>,
}

impl Counts {
    pub fn parse(text: &str) -> Result<Self> {
        let mut c = Counts::default();
        let mut lines = text.lines();
        if lines.next() != Some("armcount-report 1") {
            bail!("not an armcount report");
        }
        for l in lines {
            let f: Vec<&str> = l.split_whitespace().collect();
            let num = |i: usize| -> Result<u64> {
                f.get(i)
                    .and_then(|v| v.parse().ok())
                    .ok_or_else(|| format!("bad report line '{l}'").into())
            };
            match f.first() {
                Some(&"counter") => {
                    let k = usize::try_from(num(1)?).map_err(|_| "bad counter")?;
                    c.totals.insert(
                        k,
                        Totals {
                            insns: num(3)?,
                            blocks: num(5)?,
                            lines: num(7)?,
                            warm_seq: num(9)?,
                            warm_jump: num(10)?,
                            cold_seq: num(12)?,
                            cold_jump: num(13)?,
                            epoch_max: num(15).unwrap_or(0),
                        },
                    );
                }
                Some(&"epochs") => c.epoch_max = Some((num(3)?, num(5)?)),
                Some(&"pc") => {
                    let pc = f
                        .get(1)
                        .and_then(|a| u64::from_str_radix(a, 16).ok())
                        .ok_or_else(|| format!("bad report line '{l}'"))?;
                    c.pcs.push(PcCount {
                        pc,
                        counter: usize::try_from(num(3)?).map_err(|_| "bad counter")?,
                        count: num(4)?,
                        taken: num(5)?,
                    });
                }
                _ => {}
            }
        }
        Ok(c)
    }

    pub fn insns(&self, k: usize) -> u64 {
        self.totals.get(&k).map_or(0, |t| t.insns)
    }
}

// --- running ---------------------------------------------------------------

/// Build the plugin (host, release profile): its path.
fn plugin() -> Result<PathBuf> {
    util::run(util::cargo().args(["build", "-q", "--release", "-p", "armcount"]))?;
    let so = util::target_dir().join("release/libarmcount.so");
    if !so.is_file() {
        bail!("{} missing after the build", so.display());
    }
    Ok(so)
}

/// Build a bin of `firmware/armcount-bench` for the target (the workspace's
/// release profile) in a target directory of its own: RUSTFLAGS replaces
/// the root config's ARM rustflags (these images link no defmt).
fn bench_image(bin: &str, features: &[&str]) -> Result<PathBuf> {
    let dir = util::target_dir().join("armcount-bench");
    let mut c = util::cargo();
    c.args([
        "build",
        "-q",
        "--release",
        "-p",
        "armcount-bench",
        "--bin",
        bin,
        "--target",
        TARGET,
    ])
    .env("CARGO_TARGET_DIR", &dir)
    .env("RUSTFLAGS", "-C link-arg=-Tlink.x -C link-arg=--nmagic");
    for f in features {
        c.args(["--features", f]);
    }
    util::run(&mut c)?;
    Ok(dir.join(TARGET).join("release").join(bin))
}

/// Build an on-target test of the firmware (feature qemu, release) without
/// running it: its executable.
fn firmware_test_image(name: &str) -> Result<PathBuf> {
    let mut c = util::cargo();
    c.args([
        "test",
        "-q",
        "-p",
        "firmware",
        "--target",
        TARGET,
        "--release",
        "--features",
        "qemu",
        "--test",
        name,
        "--no-run",
        "--message-format=json-render-diagnostics",
    ]);
    let out = util::capture(&mut c)?;
    if !out.status.success() {
        eprint!("{}", String::from_utf8_lossy(&out.stderr));
        bail!("{} failed", util::show(&c));
    }
    executable_of(&String::from_utf8_lossy(&out.stdout), name)
        .ok_or_else(|| format!("cargo named no executable for test {name}").into())
}

/// The `"executable"` of test target `name` in cargo's JSON messages.
pub fn executable_of(json_lines: &str, name: &str) -> Option<PathBuf> {
    let want = format!("\"name\":\"{name}\"");
    json_lines
        .lines()
        .filter(|l| l.contains("\"reason\":\"compiler-artifact\"") && l.contains(&want))
        .find_map(|l| {
            let rest = l.split_once("\"executable\":\"")?.1;
            let path = rest.split_once('"')?.0;
            Some(PathBuf::from(path))
        })
}

fn objdump(elf: &Path, lines: bool) -> Result<Disasm> {
    let tool = setup::llvm_tool("llvm-objdump")?;
    let mut c = Command::new(tool);
    c.arg("-d");
    if lines {
        c.arg("-l");
    }
    c.args(["--no-show-raw-insn", "--demangle"]).arg(elf);
    let out = util::capture(&mut c)?;
    if !out.status.success() {
        bail!(
            "{} failed: {}",
            util::show(&c),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Ok(Disasm::parse(&String::from_utf8_lossy(&out.stdout)))
}

/// What a bench counts: a bin of `firmware/armcount-bench` (its name and
/// features) or an on-target test of the firmware (its name).
enum Image<'a> {
    Bench(&'a str, &'a [&'a str]),
    FirmwareTest(&'a str),
}

/// A bench run: the image, its marker functions (counter 0 first), the
/// function that writes the report, the one whose run ends an epoch (a
/// tick) if any, and the report's file in target/armcount-bench.
struct Run<'a> {
    image: Image<'a>,
    marks: &'a [&'a str],
    dump: &'a str,
    epoch: Option<&'a str>,
    out: &'a str,
}

/// What every bench runs on: the thumbv7em target, QEMU 7.x and the
/// plugin.
struct Armcount {
    qemu: Qemu,
    plugin: PathBuf,
}

impl Armcount {
    /// Install what is missing and build the plugin.
    fn new() -> Result<Self> {
        setup::ensure_target()?;
        let qemu = setup::qemu()?;
        let plugin = plugin()?;
        Ok(Armcount { qemu, plugin })
    }

    /// Build `r`'s image and count it: its disassembly (with the line
    /// tables when `lines`) and the plugin's report. A firmware test gets
    /// its name and a settings flash file of its own as semihosting
    /// arguments.
    fn run(&self, r: &Run, lines: bool) -> Result<(Disasm, Counts)> {
        let elf = match r.image {
            Image::Bench(bin, features) => bench_image(bin, features)?,
            Image::FirmwareTest(name) => firmware_test_image(name)?,
        };
        let d = objdump(&elf, lines)?;
        let c = match r.image {
            Image::Bench(..) => self.count(&elf, &d, r, "enable=on,target=native")?,
            Image::FirmwareTest(name) => {
                let flash = util::TempDir::new(&format!("stepbridge-{}", name.replace('_', "-")))?;
                let semihosting = format!(
                    "enable=on,target=native,arg={name},arg=flash={}",
                    flash.path().join("flash.bin").display()
                );
                self.count(&elf, &d, r, &semihosting)?
            }
        };
        Ok((d, c))
    }

    /// Run `elf` under QEMU with the plugin: its report.
    fn count(&self, elf: &Path, d: &Disasm, r: &Run, semihosting: &str) -> Result<Counts> {
        let addr = |name: &str| -> Result<u64> {
            d.symbol(name)
                .ok_or_else(|| format!("no function {name} in {}", elf.display()).into())
        };
        let report = util::target_dir().join("armcount-bench").join(r.out);
        let mut arg = self.plugin.display().to_string();
        for m in r.marks {
            let _ = write!(arg, ",mark={:#x}", addr(m)?);
        }
        let _ = write!(arg, ",dump={:#x},out={}", addr(r.dump)?, report.display());
        if let Some(e) = r.epoch {
            let _ = write!(arg, ",epoch={:#x}", addr(e)?);
        }
        if let Some(dir) = report.parent() {
            std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        }
        let _ = std::fs::remove_file(&report);
        let mut c = Command::new(&self.qemu.bin);
        c.args(["-M", "netduinoplus2", "-nographic", "-monitor", "none"]);
        // A firmware test has the QEMU image's Modbus USART (the second
        // port) too: nowhere, as `cargo qemu-test` runs it.
        let serials: &[&str] = match r.image {
            Image::Bench(..) => &["none"],
            Image::FirmwareTest(_) => &["none", "null"],
        };
        for s in serials {
            c.args(["-serial", s]);
        }
        c.arg("-semihosting-config").arg(semihosting);
        c.arg("-kernel")
            .arg(elf)
            .arg("-plugin")
            .arg(&arg)
            .args(["-d", "plugin"]);
        if let Some(dir) = &self.qemu.data_dir {
            c.arg("-L").arg(dir);
        }
        let out = util::capture(&mut c)?;
        if !out.status.success() {
            eprint!("{}", String::from_utf8_lossy(&out.stderr));
            bail!(
                "the bench {} failed (QEMU status {})",
                elf.display(),
                util::code(out.status)
            );
        }
        let text = std::fs::read_to_string(&report)
            .map_err(|e| format!("no report from the plugin ({}): {e}", report.display()))?;
        Counts::parse(&text)
    }
}

// --- analysis --------------------------------------------------------------

/// One counter, per iteration.
#[derive(Debug, Default)]
pub struct Stats {
    pub raw: f64,
    /// Without the markers and the bench's own loop.
    pub net: f64,
    pub div_insns: f64,
    pub div_cycles: f64,
    /// At the three models of `cycles::MODELS`.
    pub cycles: [f64; 3],
    /// Calls of division helpers, by name.
    pub calls: Vec<(String, f64)>,
    pub lines: f64,
    pub warm: (f64, f64),
    pub cold: (f64, f64),
    /// Cache lines the measured code covers.
    pub footprint: usize,
    pub by_func: Vec<(String, f64)>,
    pub by_file: Vec<(String, f64)>,
}

impl Stats {
    /// Flash wait cycles per iteration: every warm miss, half hidden when
    /// sequential.
    pub fn flash_wait(&self) -> f64 {
        WAIT_STATES / 2.0 * self.warm.0 + WAIT_STATES * self.warm.1
    }
}

/// Code that belongs to the bench, not to what it measures.
fn is_bench(func: Option<&str>) -> bool {
    func.is_none_or(|f| {
        f.contains("armcost_mark")
            || f.contains("__cortex_m_rt_main")
            || f.starts_with("__Thumbv7ABSLongThunk_armcost")
            // tick-armcount's own functions (its loops and tick, the
            // simulated bus glue, their long-call thunks): the bench's.
            || f.contains("tick_armcount::image::")
            || f.contains("tick_armcount..image..")
    })
}

/// A 64-bit (or any) division helper of compiler-builtins.
fn is_div(func: Option<&str>) -> bool {
    func.is_some_and(|f| {
        f.contains("div") || f.starts_with("__aeabi_l") || f.starts_with("__aeabi_ul")
    })
}

/// The called symbol of a `bl` to a division helper.
fn div_call(insn: &disasm::Insn) -> Option<&str> {
    if !insn.mnemonic.starts_with("bl") {
        return None;
    }
    let sym = insn.operands.split_once('<')?.1.split_once('>')?.0;
    let helper = (sym.starts_with("__aeabi_") && sym.contains("div"))
        || (sym.starts_with("__") && sym.contains("divmod"));
    helper.then_some(sym)
}

/// "name::h0123456789abcdef" → "name".
fn strip_hash(f: &str) -> &str {
    match f.rsplit_once("::h") {
        Some((head, h)) if h.len() == 16 && h.bytes().all(|b| b.is_ascii_hexdigit()) => head,
        _ => f,
    }
}

/// A source path as the report shows it: relative to the workspace, or
/// from `library/` (the Rust standard library) or the crate directory (a
/// registry crate).
fn short_path(file: &str, root: &str) -> String {
    if let Some(rel) = file.strip_prefix(root).and_then(|r| r.strip_prefix('/')) {
        return rel.to_owned();
    }
    if let Some(i) = file.find("/library/") {
        return file.get(i + 1..).unwrap_or(file).to_owned();
    }
    if let Some(i) = file.find("/registry/src/") {
        let rest = file.get(i + "/registry/src/".len()..).unwrap_or(file);
        return rest.split_once('/').map_or(rest, |(_, r)| r).to_owned();
    }
    file.to_owned()
}

fn top(map: HashMap<String, u64>, n: f64) -> Vec<(String, f64)> {
    let mut v: Vec<(String, f64)> = map.into_iter().map(|(k, c)| (k, c as f64 / n)).collect();
    v.sort_by(|a, b| b.1.total_cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    v.truncate(10);
    v
}

pub fn stats(d: &Disasm, c: &Counts, k: usize, n: f64) -> Stats {
    let root = util::root().display().to_string();
    let mut s = Stats {
        raw: c.insns(k) as f64 / n,
        ..Stats::default()
    };
    let (mut net, mut div, mut divcyc) = (0u64, 0u64, 0u64);
    let mut cyc = [0u64; 3];
    let mut calls: HashMap<String, u64> = HashMap::new();
    let (mut by_func, mut by_file): (HashMap<String, u64>, HashMap<String, u64>) =
        Default::default();
    let mut lines = std::collections::HashSet::new();
    for p in c.pcs.iter().filter(|p| p.counter == k) {
        let func = d.func(p.pc);
        if is_div(func) {
            div += p.count;
        }
        if let Some(insn) = d.insns.get(&p.pc) {
            if let Some(sym) = div_call(insn) {
                *calls.entry(sym.to_owned()).or_default() += p.count;
            }
            let after_ldst = d
                .previous(p.pc)
                .is_some_and(|i| cycles::is_single_ldst(&i.mnemonic));
            let cost = |m| {
                cycles::cycles(
                    &insn.mnemonic,
                    &insn.operands,
                    p.count,
                    p.taken,
                    after_ldst,
                    m,
                )
            };
            if is_div(func) {
                divcyc += cost(cycles::MID);
            }
            if !is_bench(func) {
                for (slot, (_, m)) in cyc.iter_mut().zip(cycles::MODELS) {
                    *slot += cost(m);
                }
            }
        }
        if is_bench(func) {
            continue;
        }
        net += p.count;
        lines.insert(p.pc >> 4);
        *by_func
            .entry(strip_hash(func.unwrap_or("?")).to_owned())
            .or_default() += p.count;
        let file = d
            .file(p.pc)
            .map_or_else(|| "?".to_owned(), |f| short_path(f, &root));
        *by_file.entry(file).or_default() += p.count;
    }
    s.net = net as f64 / n;
    s.div_insns = div as f64 / n;
    s.div_cycles = divcyc as f64 / n;
    for (slot, v) in s.cycles.iter_mut().zip(cyc) {
        *slot = v as f64 / n;
    }
    let mut calls: Vec<(String, f64)> = calls.into_iter().map(|(k, v)| (k, v as f64 / n)).collect();
    calls.sort_by(|a, b| b.1.total_cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    s.calls = calls;
    let t = c.totals.get(&k).copied().unwrap_or_default();
    s.lines = t.lines as f64 / n;
    s.warm = (t.warm_seq as f64 / n, t.warm_jump as f64 / n);
    s.cold = (t.cold_seq as f64 / n, t.cold_jump as f64 / n);
    s.footprint = lines.len();
    s.by_func = top(by_func, n);
    s.by_file = top(by_file, n);
    s
}

fn print_counter(k: usize, name: &str, s: &Stats) {
    println!("counter {k}: {name}");
    println!(
        "  instructions: {:.1} raw, {:.1} net (without markers and the bench loop)",
        s.raw, s.net
    );
    let calls: Vec<String> = s.calls.iter().map(|(f, c)| format!("{f} {c:.2}")).collect();
    println!(
        "  division helpers: {:.1} instructions ({:.0} %), ~{:.0} cycles; calls: {}",
        s.div_insns,
        100.0 * s.div_insns / s.net.max(1e-9),
        s.div_cycles,
        if calls.is_empty() {
            "none".to_owned()
        } else {
            calls.join(", ")
        }
    );
    println!(
        "  cycles at 0 wait states ({} / {} / {}): {:.0} / {:.0} / {:.0} (CPI {:.2} at {})",
        cycles::MODELS[0].0,
        cycles::MODELS[1].0,
        cycles::MODELS[2].0,
        s.cycles[0],
        s.cycles[1],
        s.cycles[2],
        s.cycles[1] / s.net.max(1e-9),
        cycles::MODELS[1].0
    );
    println!(
        "  ART cache (64 x 16 B, LRU): code footprint {} lines ({} B); lines fetched {:.0}; misses: warm {:.1} sequential + {:.1} jumps, cold {:.1} + {:.1}",
        s.footprint,
        s.footprint * 16,
        s.lines,
        s.warm.0,
        s.warm.1,
        s.cold.0,
        s.cold.1
    );
    println!("  by function:");
    for (f, c) in &s.by_func {
        println!("    {c:9.1}  {}", f.chars().take(100).collect::<String>());
    }
    println!("  by source file (innermost line-table location):");
    for (f, c) in &s.by_file {
        println!("    {c:9.1}  {}", f.chars().take(100).collect::<String>());
    }
    println!();
}

fn tick_hz() -> u32 {
    std::env::var("STEPBRIDGE_TICK_HZ")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1000)
}

/// CPU share of `cycles` per event at `hz` events per second.
pub fn share(cycles: f64, hz: u32) -> f64 {
    100.0 * cycles * f64::from(hz) / SYSCLK_HZ
}

/// `--write`: put the measurement into `rate/measured.rs` ([`cost`]).
fn write_flag(args: &[String]) -> bool {
    args.iter().any(|a| a == "--write")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plugin_report() {
        let r = "armcount-report 1\ncounters 3\ncounter 1 insns 100 blocks 20 lines 30 warm 4 5 cold 6 7\ncounter 2 insns 0 blocks 0 lines 0 warm 0 0 cold 0 0\npc 8000462 2 1 10 3\n";
        let c = Counts::parse(r).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(c.insns(1), 100);
        assert_eq!(
            c.totals[&1],
            Totals {
                insns: 100,
                blocks: 20,
                lines: 30,
                warm_seq: 4,
                warm_jump: 5,
                cold_seq: 6,
                cold_jump: 7,
                epoch_max: 0
            }
        );
        let e = Counts::parse(
            "armcount-report 1\ncounter 1 insns 1 blocks 1 lines 1 warm 0 0 cold 0 0 epochmax 9\n",
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(e.totals[&1].epoch_max, 9);
        let t = Counts::parse("armcount-report 1\nepochs 12 max 340 at 3\n")
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(t.epoch_max, Some((340, 3)));
        assert_eq!(
            c.pcs,
            vec![PcCount {
                pc: 0x0800_0462,
                counter: 1,
                count: 10,
                taken: 3
            }]
        );
        assert!(Counts::parse("T 1 2 3\n").is_err());
    }

    #[test]
    fn stats_of_a_small_counter() {
        let dis = "
08000400 <armcost_mark_on>:
 8000400:      \tbx\tlr
08000402 <work>:
; /w/x.rs:1
 8000402:      \tldr\tr0, [r1]
 8000404:      \tldr\tr2, [r1, #4]
 8000406:      \tbl\t0x8000500 <__aeabi_uldivmod>
 800040a:      \tbne\t0x8000402 <work>
";
        let d = Disasm::parse(dis);
        let r = "armcount-report 1\ncounters 2\ncounter 1 insns 9 blocks 2 lines 4 warm 1 2 cold 3 4\npc 8000400 2 1 2 2\npc 8000402 2 1 2 0\npc 8000404 2 1 2 0\npc 8000406 4 1 2 2\npc 800040a 2 1 1 1\n";
        let c = Counts::parse(r).unwrap_or_else(|e| panic!("{e}"));
        let s = stats(&d, &c, 1, 1.0);
        assert_eq!(s.raw, 9.0);
        // The marker's bx is the bench's.
        assert_eq!(s.net, 7.0);
        // ldr 2 × 2, ldr after ldr 2 × 1, bl 2 × (1 + 2), bne 1 + 1 × 2.
        assert_eq!(s.cycles[1], 4.0 + 2.0 + 6.0 + 3.0);
        assert_eq!(s.calls, vec![("__aeabi_uldivmod".to_owned(), 2.0)]);
        assert_eq!(s.by_func, vec![("work".to_owned(), 7.0)]);
        assert_eq!(s.footprint, 1);
        assert_eq!(s.flash_wait(), 2.5 + 10.0);
    }

    #[test]
    fn cargo_json_executable() {
        let j = r#"{"reason":"compiler-artifact","package_id":"x","target":{"kind":["test"],"crate_types":["bin"],"name":"chain_cost","src_path":"/w/firmware/tests/chain_cost.rs"},"profile":{},"features":[],"filenames":["/w/t/chain_cost-ab"],"executable":"/w/t/chain_cost-ab","fresh":true}
{"reason":"build-finished","success":true}"#;
        assert_eq!(
            executable_of(j, "chain_cost"),
            Some(PathBuf::from("/w/t/chain_cost-ab"))
        );
        assert_eq!(executable_of(j, "ioext_cost"), None);
    }

    #[test]
    fn names_and_paths() {
        assert_eq!(strip_hash("a::b::h0123456789abcdef"), "a::b");
        assert_eq!(strip_hash("a::hello"), "a::hello");
        assert_eq!(
            short_path("/w/firmware/logic/src/a.rs", "/w"),
            "firmware/logic/src/a.rs"
        );
        assert_eq!(
            short_path("/rustc/abc/library/core/src/cmp.rs", "/w"),
            "library/core/src/cmp.rs"
        );
        assert_eq!(
            short_path(
                "/h/.cargo/registry/src/index.crates.io-1/heapless-0.9.3/src/vec.rs",
                "/w"
            ),
            "heapless-0.9.3/src/vec.rs"
        );
        assert!((share(16800.0, 10_000) - 100.0).abs() < 1e-9);
    }
}
