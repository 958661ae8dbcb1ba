//! `llvm-objdump -d [-l] --no-show-raw-insn --demangle` of a bench image,
//! parsed: every instruction with its function and (with `-l`) the
//! innermost source location of the line table, and the functions'
//! addresses (the markers are found by name here).

use std::collections::{BTreeMap, HashMap};

#[derive(Debug, Clone)]
pub struct Insn {
    pub mnemonic: String,
    pub operands: String,
    func: Option<usize>,
    file: Option<usize>,
}

#[derive(Debug, Default)]
pub struct Disasm {
    pub insns: BTreeMap<u64, Insn>,
    funcs: Vec<String>,
    files: Vec<String>,
    symbols: HashMap<String, u64>,
}

/// "08000458 <name>:" → (address, name).
fn header(line: &str) -> Option<(u64, &str)> {
    let (addr, rest) = line.split_once(' ')?;
    if addr.len() < 8 || !addr.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let name = rest.strip_prefix('<')?.strip_suffix(">:")?;
    Some((u64::from_str_radix(addr, 16).ok()?, name))
}

/// "; /path/file.rs:123" → "/path/file.rs" (not "; name():").
fn source(line: &str) -> Option<&str> {
    let rest = line.strip_prefix("; ")?;
    let (file, num) = rest.rsplit_once(':')?;
    (!num.is_empty() && num.bytes().all(|b| b.is_ascii_digit())).then_some(file)
}

/// " 8000404:      \tldr\tr0, [pc, #0x38]   @ 0x8000440" → (address,
/// mnemonic, operands). Data words (".word", shown with their bytes) are not
/// instructions.
fn instruction(line: &str) -> Option<(u64, &str, &str)> {
    let t = line.trim_start();
    let (addr, rest) = t.split_once(':')?;
    if addr.is_empty() || !addr.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let rest = rest.trim_start();
    let (mnemonic, operands) = match rest.split_once(char::is_whitespace) {
        Some((m, o)) => (m, o.trim()),
        None => (rest, ""),
    };
    if mnemonic.is_empty()
        || mnemonic.starts_with('.')
        || (mnemonic.len() == 2 && mnemonic.bytes().all(|b| b.is_ascii_hexdigit()))
    {
        return None;
    }
    Some((u64::from_str_radix(addr, 16).ok()?, mnemonic, operands))
}

fn intern(list: &mut Vec<String>, index: &mut HashMap<String, usize>, s: &str) -> usize {
    if let Some(&i) = index.get(s) {
        return i;
    }
    list.push(s.to_owned());
    index.insert(s.to_owned(), list.len() - 1);
    list.len() - 1
}

impl Disasm {
    pub fn parse(text: &str) -> Self {
        let mut d = Disasm::default();
        let (mut fi, mut si) = (HashMap::new(), HashMap::new());
        let (mut func, mut file) = (None, None);
        for line in text.lines() {
            if let Some((addr, name)) = header(line) {
                d.symbols.entry(name.to_owned()).or_insert(addr);
                func = Some(intern(&mut d.funcs, &mut fi, name));
                file = None;
            } else if let Some(f) = source(line) {
                file = Some(intern(&mut d.files, &mut si, f));
            } else if let Some((pc, m, o)) = instruction(line) {
                d.insns.insert(
                    pc,
                    Insn {
                        mnemonic: m.to_owned(),
                        operands: o.to_owned(),
                        func,
                        file,
                    },
                );
            }
        }
        d
    }

    /// A function's address.
    pub fn symbol(&self, name: &str) -> Option<u64> {
        self.symbols.get(name).copied()
    }

    pub fn func(&self, pc: u64) -> Option<&str> {
        let i = self.insns.get(&pc)?.func?;
        self.funcs.get(i).map(String::as_str)
    }

    pub fn file(&self, pc: u64) -> Option<&str> {
        let i = self.insns.get(&pc)?.file?;
        self.files.get(i).map(String::as_str)
    }

    /// The instruction before `pc` in memory.
    pub fn previous(&self, pc: u64) -> Option<&Insn> {
        self.insns.range(..pc).next_back().map(|(_, i)| i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = "
target/x:\tfile format elf32-littlearm

Disassembly of section .text:

08000400 <__stext>:
; Reset():
 8000400:      \tbl\t0x800a5a6 <__pre_init>  @ imm = #0xa1a2
 8000404:      \tldr\tr0, [pc, #0x38]         @ 0x8000440 <__stext+0x40>
 8000440: 00 00 00 20  \t.word\t0x20000000

08000458 <armcost_mark_off>:
; armcost_mark_off():
; /w/src/main.rs:49
 8000458:      \tpush\t{r7, lr}
; /rustc/abc/library/core/src/hint.rs:12
 800045a:      \tmov\tr7, sp
";

    #[test]
    fn parses_objdump() {
        let d = Disasm::parse(TEXT);
        assert_eq!(d.symbol("armcost_mark_off"), Some(0x0800_0458));
        assert_eq!(d.insns.len(), 4);
        assert_eq!(d.func(0x0800_0404), Some("__stext"));
        assert_eq!(d.file(0x0800_0404), None);
        assert_eq!(d.file(0x0800_0458), Some("/w/src/main.rs"));
        assert_eq!(
            d.file(0x0800_045a),
            Some("/rustc/abc/library/core/src/hint.rs")
        );
        let i = &d.insns[&0x0800_0404];
        assert_eq!(i.mnemonic, "ldr");
        assert!(i.operands.starts_with("r0, [pc, #0x38]"));
        assert_eq!(
            d.previous(0x0800_0404).map(|i| i.mnemonic.as_str()),
            Some("bl")
        );
        assert!(!d.insns.contains_key(&0x0800_0440));
    }
}
