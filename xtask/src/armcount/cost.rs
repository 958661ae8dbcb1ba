//! The measured cost `bridge_logic::rate` fits the tick rate to
//! (`firmware/logic/src/rate/measured.rs`): each bench checks its figure
//! there and, with `--write`, puts the measurement in. A check fails when
//! the code costs more than the file says (the rate would be fitted to a
//! cost lower than the truth); a cost lower than the file's is reported
//! and left (the fit errs safe) until a `--write`.

use std::path::PathBuf;

use crate::util::{self, bail, Result};

/// The file, from the workspace root.
pub const FILE: &str = "firmware/logic/src/rate/measured.rs";

/// The value of `pub const NAME: u32 = …;` in `text`.
pub fn value(text: &str, name: &str) -> Option<u32> {
    let head = format!("pub const {name}: u32 = ");
    let line = text.lines().find(|l| l.starts_with(&head))?;
    let v = line
        .get(head.len()..)?
        .trim_end_matches(';')
        .replace('_', "");
    v.parse().ok()
}

/// `text` with `NAME`'s value replaced by `v` (written with `_` groups,
/// as rustfmt leaves them); `None` if there is no such constant.
pub fn with_value(text: &str, name: &str, v: u32) -> Option<String> {
    let head = format!("pub const {name}: u32 = ");
    value(text, name)?;
    let mut out = String::with_capacity(text.len());
    for l in text.lines() {
        if l.starts_with(&head) {
            out.push_str(&format!("{head}{};", grouped(v)));
        } else {
            out.push_str(l);
        }
        out.push('\n');
    }
    Some(out)
}

/// 15342 → "15_342".
fn grouped(v: u32) -> String {
    let s = v.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i) % 3 == 0 {
            out.push('_');
        }
        out.push(c);
    }
    out
}

fn path() -> PathBuf {
    util::root().join(FILE)
}

/// Check (or with `write`, set) constant `name` against a measurement of
/// `measured` cycles, rounded up; prints the verdict as a RESULT line.
pub fn check(name: &str, measured: f64, write: bool) -> Result {
    let p = path();
    let text = std::fs::read_to_string(&p).map_err(|e| format!("{}: {e}", p.display()))?;
    let m = measured.ceil() as u32;
    let Some(have) = value(&text, name) else {
        bail!("{FILE} has no constant {name}");
    };
    if write {
        let Some(new) = with_value(&text, name, m) else {
            bail!("{FILE} has no constant {name}");
        };
        std::fs::write(&p, new).map_err(|e| format!("{}: {e}", p.display()))?;
        println!("RESULT rate::fit's cost {name}: {m} cycles written to {FILE} (was {have})");
        return Ok(());
    }
    // Within 1 %: the same code measured again, or a change too small to matter.
    if f64::from(m) > f64::from(have) * 1.01 {
        bail!(
            "{name}: measured {m} cycles, {FILE} says {have}: the tick rate would be fitted to a cost below the truth; run the bench with --write"
        );
    }
    println!("RESULT rate::fit's cost {name}: {have} cycles in {FILE}, measured {m}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str =
        "//! doc\npub const SYSCLK_HZ: u32 = 168_000_000;\npub const TICK: u32 = 15_342;\n";

    #[test]
    fn values_read_with_or_without_groups() {
        assert_eq!(value(TEXT, "TICK"), Some(15_342));
        assert_eq!(value(TEXT, "SYSCLK_HZ"), Some(168_000_000));
        assert_eq!(value(TEXT, "NONE"), None);
    }

    #[test]
    fn a_value_is_replaced_in_place() {
        let t = with_value(TEXT, "TICK", 9_001).unwrap();
        assert_eq!(value(&t, "TICK"), Some(9_001));
        assert!(t.contains("pub const TICK: u32 = 9_001;\n"));
        assert_eq!(value(&t, "SYSCLK_HZ"), Some(168_000_000));
        assert!(t.starts_with("//! doc\n"));
        assert_eq!(with_value(TEXT, "NONE", 1), None);
    }

    #[test]
    fn groups_of_three() {
        assert_eq!(grouped(548), "548");
        assert_eq!(grouped(15_342), "15_342");
        assert_eq!(grouped(1_000_000), "1_000_000");
    }
}
