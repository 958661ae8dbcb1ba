//! The pin table is written once in code (the type aliases of
//! `firmware/src/pins.rs`) and repeated for readers (`docs/pins.md`, the
//! README's wiring table). This test reads the source and the documents as
//! text and fails on any difference, so the documents cannot drift.
//!
//! Checked: every alias `pub type Name = gpio::PXn<…>` has a document row
//! `| NAME | PXn | … |` (names compared without underscores, case-blind);
//! every non-reserved row has an alias; a row whose notes start with
//! `reserved:` names a pin no alias uses; no pin is used twice; an alias in
//! `Alternate<N>` has `AFN` in its notes; every `NAME_PIN: u8 = n` constant
//! (the drivers' BSRR/IDR bit numbers) is the alias's pin number.

use std::collections::BTreeMap;

const PINS_RS: &str = include_str!("../../firmware/src/pins.rs");
const PINS_MD: &str = include_str!("../../docs/pins.md");
const README: &str = include_str!("../../README.md");

/// An alias: its pin ("PA5") and the alternate function it is in, if any.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Alias {
    pin: String,
    af: Option<u8>,
}

/// "ChainSck" / "CHAIN_SCK" → "CHAINSCK".
fn key(name: &str) -> String {
    name.chars()
        .filter(|c| *c != '_')
        .flat_map(char::to_uppercase)
        .collect()
}

/// `pub type Name = gpio::PA5<Alternate<5>>;` → (key, alias).
fn aliases(src: &str) -> BTreeMap<String, Alias> {
    let mut out = BTreeMap::new();
    for line in src.lines() {
        let Some(rest) = line.trim().strip_prefix("pub type ") else {
            continue;
        };
        let Some((name, ty)) = rest.split_once(" = gpio::") else {
            continue;
        };
        let pin: String = ty
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric())
            .collect();
        let af = ty
            .split_once("Alternate<")
            .and_then(|(_, a)| a.split(|c: char| !c.is_ascii_digit()).next())
            .and_then(|n| n.parse().ok());
        out.insert(key(name), Alias { pin, af });
    }
    out
}

/// `pub const NAME_PIN: u8 = 4;` → (key of NAME, 4).
fn pin_numbers(src: &str) -> Vec<(String, u8)> {
    src.lines()
        .filter_map(|l| {
            let rest = l.trim().strip_prefix("pub const ")?;
            let (name, value) = rest.split_once(": u8 = ")?;
            let signal = name.strip_suffix("_PIN")?;
            Some((key(signal), value.trim_end_matches(';').parse().ok()?))
        })
        .collect()
}

/// A document's pin rows: `| SIGNAL | PXn | notes |`.
fn rows(doc: &str) -> Vec<(String, String, String)> {
    doc.lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l
                .trim()
                .strip_prefix('|')?
                .split('|')
                .map(str::trim)
                .collect();
            let (signal, pin, notes) = (cells.first()?, cells.get(1)?, cells.get(2)?);
            let is_pin = pin.len() >= 3
                && pin.starts_with('P')
                && pin.as_bytes().get(1).is_some_and(u8::is_ascii_uppercase)
                && pin
                    .get(2..)
                    .is_some_and(|n| n.bytes().all(|b| b.is_ascii_digit()));
            let is_signal = signal
                .bytes()
                .all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_');
            (is_pin && is_signal && !signal.is_empty())
                .then(|| (signal.to_string(), pin.to_string(), notes.to_string()))
        })
        .collect()
}

fn check(doc_name: &str, doc: &str, expect_all: bool) {
    let code = aliases(PINS_RS);
    let table = rows(doc);
    let mut seen = BTreeMap::new();
    for (signal, pin, notes) in &table {
        if let Some(other) = seen.insert(pin.clone(), signal.clone()) {
            panic!("{doc_name}: {pin} is both {other} and {signal}");
        }
        if notes.starts_with("reserved:") {
            let user = code.iter().find(|(_, a)| &a.pin == pin);
            assert!(
                user.is_none(),
                "{doc_name}: {pin} is reserved but {user:?} uses it"
            );
            continue;
        }
        let alias = code
            .get(&key(signal))
            .unwrap_or_else(|| panic!("{doc_name}: {signal} has no alias in pins.rs"));
        assert_eq!(&alias.pin, pin, "{doc_name}: {signal}'s pin");
        if let Some(af) = alias.af {
            assert!(
                notes.contains(&format!("AF{af}")),
                "{doc_name}: {signal} is in AF{af} in pins.rs; the notes say {notes:?}"
            );
        }
    }
    if expect_all {
        for (k, alias) in &code {
            assert!(
                table.iter().any(|(s, _, _)| &key(s) == k),
                "{doc_name}: pins.rs's {k} ({}) has no row",
                alias.pin
            );
        }
    }
}

#[test]
fn docs_pins_md_lists_every_alias_of_pins_rs_with_its_pin_and_alternate_function() {
    assert!(aliases(PINS_RS).len() >= 20, "the parser found the aliases");
    check("docs/pins.md", PINS_MD, true);
}

#[test]
fn every_pin_row_of_the_readme_agrees_with_pins_rs() {
    check("README.md", README, false);
}

#[test]
fn every_pin_row_elsewhere_in_docs_agrees_with_pins_rs() {
    for entry in std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/../docs")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "md") {
            let text = std::fs::read_to_string(&path).unwrap();
            check(&path.display().to_string(), &text, false);
        }
    }
}

#[test]
fn the_drivers_pin_numbers_are_their_aliases_pins() {
    let code = aliases(PINS_RS);
    let numbers = pin_numbers(PINS_RS);
    assert!(numbers.len() >= 5, "the parser found the *_PIN constants");
    for (signal, n) in numbers {
        let alias = code
            .get(&signal)
            .unwrap_or_else(|| panic!("{signal}_PIN has no alias"));
        assert_eq!(
            alias.pin.get(2..),
            Some(n.to_string().as_str()),
            "{signal}_PIN"
        );
    }
}

#[test]
fn the_checker_catches_a_moved_pin_a_wrong_af_and_a_used_reserved_pin() {
    let moved = PINS_MD.replace("| CHAIN_CS | PA4 |", "| CHAIN_CS | PA8 |");
    assert!(std::panic::catch_unwind(|| check("moved", &moved, true)).is_err());
    let af = PINS_MD.replace("SPI1 SCK (AF5)", "SPI1 SCK (AF6)");
    assert!(std::panic::catch_unwind(|| check("af", &af, true)).is_err());
    let reserved = PINS_MD.replace(
        "| STATUS_LED | PB12 | GPIO push-pull, high = on |",
        "| STATUS_LED | PB12 | reserved: nothing |",
    );
    assert!(std::panic::catch_unwind(|| check("reserved", &reserved, true)).is_err());
    let missing = PINS_MD.replace("| USB_DP | PA12 |", "| USB_DPX | PA12 |");
    assert!(std::panic::catch_unwind(|| check("missing", &missing, true)).is_err());
}
