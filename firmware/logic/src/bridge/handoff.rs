//! The reset handoff: what the MCU restarts into ([`ResetTarget`]), carried
//! across a software reset in one 32-bit word that the firmware keeps in RAM
//! the reset does not clear (a `.uninit` word).
//!
//! # What it guarantees
//!
//! * **Round trip**: [`decode`]`(`[`encode`]`(t))` is `Some(t)` for every
//!   target.
//! * **Garbage is a normal start**: a word [`encode`] did not write decodes
//!   to `None` — after power-up the RAM holds noise, and the firmware then
//!   starts the application as always. A word decodes only if its high half
//!   is [`MAGIC`], its low byte is the complement of the code byte and the
//!   code is one of the three targets: 3 words of the 2³² (a random word
//!   passes with probability 7·10⁻¹⁰), and no single flipped bit turns one
//!   target's word into another's or into a valid word at all.
//! * **Cleared is a normal start**: [`CLEARED`] (what the firmware writes
//!   back after reading the word, so a later reset of any other kind — pin,
//!   watchdog — starts normally) decodes to `None`, and so do all-zero and
//!   all-one words.
//!
//! # Assumptions
//!
//! The firmware reads the word once at the very top of `init`, writes
//! [`CLEARED`] at once, and writes [`encode`]`(t)` only right before
//! `SCB::sys_reset()`.

use super::ResetTarget;

/// High half of every handoff word ("SB", stepbridge).
pub const MAGIC: u32 = 0x5342;
/// What the firmware leaves in the word once it has read it.
pub const CLEARED: u32 = 0;

const fn code(target: ResetTarget) -> u8 {
    match target {
        ResetTarget::Application => 0x01,
        ResetTarget::BootMode => 0x02,
        ResetTarget::RomDfu => 0x03,
    }
}

/// The word that makes the next start go to `target`.
pub const fn encode(target: ResetTarget) -> u32 {
    let c = code(target);
    MAGIC << 16 | (c as u32) << 8 | (!c) as u32
}

/// What the word read at boot asks for; `None` for anything [`encode`] did
/// not write (a normal start).
pub const fn decode(word: u32) -> Option<ResetTarget> {
    if word >> 16 != MAGIC {
        return None;
    }
    let c = (word >> 8) as u8;
    if word as u8 != !c {
        return None;
    }
    match c {
        0x01 => Some(ResetTarget::Application),
        0x02 => Some(ResetTarget::BootMode),
        0x03 => Some(ResetTarget::RomDfu),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TARGETS: [ResetTarget; 3] = [
        ResetTarget::Application,
        ResetTarget::BootMode,
        ResetTarget::RomDfu,
    ];

    #[test]
    fn every_target_round_trips() {
        for t in TARGETS {
            assert_eq!(decode(encode(t)), Some(t), "{t:?}");
        }
    }

    #[test]
    fn the_three_words_differ() {
        assert_ne!(encode(TARGETS[0]), encode(TARGETS[1]));
        assert_ne!(encode(TARGETS[1]), encode(TARGETS[2]));
        assert_ne!(encode(TARGETS[0]), encode(TARGETS[2]));
    }

    #[test]
    fn cleared_zero_and_all_ones_are_a_normal_start() {
        assert_eq!(decode(CLEARED), None);
        assert_eq!(decode(0), None);
        assert_eq!(decode(u32::MAX), None);
    }

    #[test]
    fn only_three_words_with_the_magic_decode() {
        let valid = (0..=u16::MAX)
            .map(|low| MAGIC << 16 | u32::from(low))
            .filter(|&w| decode(w).is_some())
            .count();
        assert_eq!(valid, 3);
    }

    #[test]
    fn no_word_without_the_magic_decodes() {
        // Every other high half, with the low halves of the valid words and
        // a spread of others.
        let lows: Vec<u32> = TARGETS
            .iter()
            .map(|&t| encode(t) & 0xFFFF)
            .chain([0, 0xFFFF, 0x1234, 0x02FD])
            .collect();
        for high in (0..=u16::MAX as u32).filter(|&h| h != MAGIC) {
            for &low in &lows {
                assert_eq!(decode(high << 16 | low), None, "{:#010x}", high << 16 | low);
            }
        }
    }

    #[test]
    fn one_flipped_bit_never_gives_a_valid_word() {
        for t in TARGETS {
            for bit in 0..32 {
                let w = encode(t) ^ 1 << bit;
                assert_eq!(decode(w), None, "{t:?} with bit {bit} flipped");
            }
        }
    }
}
