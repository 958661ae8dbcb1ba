//! A Cortex-M4 cycle estimate per instruction, from the Cortex-M4
//! Technical Reference Manual (r0p1, §3.3 "Instruction set summary", table
//! 3-1 "Cortex-M4 instruction set summary"), at zero flash wait states.
//! Two things the table leaves open are parameters: P, the pipeline refill
//! after a taken branch (1–3 cycles, depending on alignment and width of
//! the target), and the cycles of SDIV/UDIV (2–12, early termination).
//! The estimate errs where the table does: IT folding, stalls on a load's
//! result, and bus contention are not modelled.

/// Condition-code suffixes (ARMv7-M ARM §A7.3).
const CC: [&str; 17] = [
    "eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt", "le",
    "al",
];

/// Single loads and stores ("LDR/STR and their byte, halfword, exclusive
/// and unprivileged forms").
const SINGLE_LDST: [&str; 14] = [
    "ldr", "ldrb", "ldrh", "ldrsb", "ldrsh", "ldrex", "str", "strb", "strh", "strex", "ldrt",
    "strt", "ldrbt", "strbt",
];

/// Mnemonics that keep their cost when an IT block makes them conditional.
const CONDITIONAL_FORMS: [&str; 10] = [
    "b", "bx", "bl", "blx", "ldm", "stm", "ldrd", "strd", "pop", "push",
];

/// What an instruction costs, by kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// B, BL, BX, BLX: 1 + P.
    Branch,
    /// B<cc>, CBZ, CBNZ: 1, or 1 + P when taken.
    CondBranch,
    /// TBB, TBH: 2 + P.
    TableBranch,
    /// POP, LDM: 1 + N registers (+ P when PC is loaded).
    LoadMultiple,
    /// PUSH, STM, VPUSH, VPOP, VLDM, VSTM: 1 + N (words).
    StoreMultiple,
    /// LDRD, STRD: 1 + 2.
    Double,
    /// A single load: 2, or 1 after another single load or store (their
    /// address and data phases pipeline); a load into PC 2 + P.
    Load,
    /// A single store: 1 (the write buffer takes it).
    Store,
    /// VLDR, VSTR: 2.
    FpLoadStore,
    /// SDIV, UDIV: the DIV parameter.
    Div,
    /// VDIV, VSQRT: 14.
    FpDivSqrt,
    /// VMLA and the other fused/chained FP multiply-accumulates: 3.
    FpMac,
    /// Everything else, multiplies (MUL, MLA, UMULL, SMLAL, ... are
    /// single-cycle on the M4), IT, NOP and FP arithmetic included: 1.
    Single,
}

/// The mnemonic without width qualifier (".w", ".n") or data type (".f32").
pub fn base(mnemonic: &str) -> &str {
    mnemonic.split('.').next().unwrap_or(mnemonic)
}

/// The mnemonic without its IT-block condition, where the condition does
/// not change the cost ("popne" → "pop", "ldrbeq" → "ldrb").
fn unconditional(m: &str) -> &str {
    if SINGLE_LDST.contains(&m) || m.len() <= 2 {
        return m;
    }
    let (head, tail) = m.split_at(m.len() - 2);
    if CC.contains(&tail) && (SINGLE_LDST.contains(&head) || CONDITIONAL_FORMS.contains(&head)) {
        head
    } else {
        m
    }
}

pub fn kind(mnemonic: &str) -> Kind {
    let m = base(mnemonic);
    if let Some(cc) = m.strip_prefix('b') {
        if CC.contains(&cc) {
            return Kind::CondBranch;
        }
    }
    let m = unconditional(m);
    match m {
        "b" | "bl" | "blx" | "bx" => Kind::Branch,
        "cbz" | "cbnz" => Kind::CondBranch,
        "tbb" | "tbh" => Kind::TableBranch,
        "ldrd" | "strd" => Kind::Double,
        "vldr" | "vstr" => Kind::FpLoadStore,
        "sdiv" | "udiv" => Kind::Div,
        "vdiv" | "vsqrt" => Kind::FpDivSqrt,
        "vmla" | "vmls" | "vnmla" | "vnmls" | "vfma" | "vfms" | "vfnma" | "vfnms" => Kind::FpMac,
        _ if m == "pop" || m.starts_with("ldm") => Kind::LoadMultiple,
        _ if m == "push"
            || m.starts_with("stm")
            || m == "vpush"
            || m == "vpop"
            || m.starts_with("vldm")
            || m.starts_with("vstm") =>
        {
            Kind::StoreMultiple
        }
        _ if SINGLE_LDST.contains(&m) => {
            if m.starts_with("str") {
                Kind::Store
            } else {
                Kind::Load
            }
        }
        _ => Kind::Single,
    }
}

/// Is this a single load or store (for the pipelining of the next load)?
pub fn is_single_ldst(mnemonic: &str) -> bool {
    SINGLE_LDST.contains(&unconditional(base(mnemonic)))
}

/// Words in a register list "{r4, r5, r7, lr}", "{d8-d9}" (a D register is
/// two), and whether it holds PC.
pub fn register_list(operands: &str) -> (u64, bool) {
    let Some(list) = operands
        .split_once('{')
        .and_then(|(_, rest)| rest.split_once('}'))
        .map(|(l, _)| l)
    else {
        return (1, false);
    };
    let mut words = 0;
    let mut pc = false;
    for r in list.split(',').map(str::trim).filter(|r| !r.is_empty()) {
        let width = if r.starts_with('d') { 2 } else { 1 };
        let n = match r.split_once('-') {
            Some((a, b)) => {
                let num = |s: &str| s.get(1..).and_then(|n| n.parse::<u64>().ok());
                match (num(a), num(b)) {
                    (Some(a), Some(b)) if b >= a => b - a + 1,
                    _ => 1,
                }
            }
            None => 1,
        };
        words += n * width;
        pc |= r == "pc";
    }
    (words, pc)
}

/// Model parameters: P (pipeline refill) and the cycles of a division.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Model {
    pub refill: u64,
    pub div: u64,
}

/// The three models reports show: best case, middle (the one the CPU
/// shares use), worst case.
pub const MODELS: [(&str, Model); 3] = [
    ("P=1,DIV=2", Model { refill: 1, div: 2 }),
    ("P=2,DIV=7", Model { refill: 2, div: 7 }),
    ("P=3,DIV=12", Model { refill: 3, div: 12 }),
];
pub const MID: Model = Model { refill: 2, div: 7 };

/// Cycles of `count` executions of an instruction that was left by a
/// taken branch `taken` times; `after_ldst`: the instruction before it in
/// memory is a single load or store.
pub fn cycles(
    mnemonic: &str,
    operands: &str,
    count: u64,
    taken: u64,
    after_ldst: bool,
    m: Model,
) -> u64 {
    let p = m.refill;
    match kind(mnemonic) {
        Kind::Branch => count * (1 + p),
        Kind::CondBranch => count + taken * p,
        Kind::TableBranch => count * (2 + p),
        Kind::LoadMultiple => {
            let (n, pc) = register_list(operands);
            count * (1 + n + if pc { p } else { 0 })
        }
        Kind::StoreMultiple => count * (1 + register_list(operands).0),
        Kind::Double => count * 3,
        Kind::Load => {
            let into_pc = operands.split(',').next().map(str::trim) == Some("pc");
            if into_pc {
                count * (2 + p)
            } else if after_ldst {
                count
            } else {
                count * 2
            }
        }
        Kind::Store => count,
        Kind::FpLoadStore => count * 2,
        Kind::Div => count * m.div,
        Kind::FpDivSqrt => count * 14,
        Kind::FpMac => count * 3,
        Kind::Single => count,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds() {
        assert_eq!(kind("b.w"), Kind::Branch);
        assert_eq!(kind("bl"), Kind::Branch);
        assert_eq!(kind("bxeq"), Kind::Branch);
        assert_eq!(kind("bne.w"), Kind::CondBranch);
        // Branch if lower or same / less than, not BL with a suffix.
        assert_eq!(kind("bls"), Kind::CondBranch);
        assert_eq!(kind("blt"), Kind::CondBranch);
        assert_eq!(kind("cbnz"), Kind::CondBranch);
        assert_eq!(kind("tbh"), Kind::TableBranch);
        assert_eq!(kind("pop.w"), Kind::LoadMultiple);
        assert_eq!(kind("popne"), Kind::LoadMultiple);
        assert_eq!(kind("ldm.w"), Kind::LoadMultiple);
        assert_eq!(kind("stmdb"), Kind::StoreMultiple);
        assert_eq!(kind("vpush"), Kind::StoreMultiple);
        assert_eq!(kind("strdne"), Kind::Double);
        assert_eq!(kind("ldrb.w"), Kind::Load);
        assert_eq!(kind("ldrbeq.w"), Kind::Load);
        assert_eq!(kind("strh"), Kind::Store);
        assert_eq!(kind("udiv"), Kind::Div);
        assert_eq!(kind("umull"), Kind::Single);
        assert_eq!(kind("bics"), Kind::Single);
        assert_eq!(kind("itt"), Kind::Single);
        assert_eq!(kind("mls"), Kind::Single);
    }

    #[test]
    fn register_lists() {
        assert_eq!(register_list("{r4, r5, r6, r7, lr}"), (5, false));
        assert_eq!(register_list("{r4-r7, pc}"), (5, true));
        assert_eq!(register_list("r0!, {r2}"), (1, false));
        assert_eq!(register_list("{d8-d9}"), (4, false));
    }

    #[test]
    fn costs() {
        assert_eq!(cycles("bl", "0x8000 <f>", 10, 10, false, MID), 30);
        assert_eq!(cycles("bne", "0x8000 <f>", 10, 4, false, MID), 18);
        assert_eq!(
            cycles("pop", "{r4, r5, r7, pc}", 2, 2, false, MID),
            2 * (1 + 4 + 2)
        );
        assert_eq!(cycles("ldr", "r0, [r1]", 3, 0, false, MID), 6);
        assert_eq!(cycles("ldr", "r0, [r1]", 3, 0, true, MID), 3);
        assert_eq!(cycles("ldr.w", "pc, [sp], #4", 1, 1, false, MID), 4);
        assert_eq!(cycles("str", "r0, [r1]", 3, 0, false, MID), 3);
        assert_eq!(cycles("udiv", "r0, r1, r2", 1, 0, false, MID), 7);
        assert_eq!(cycles("adds", "r0, #1", 5, 0, false, MID), 5);
    }
}
