//! The STM32F405's ART accelerator instruction cache, as far as the
//! reference manual describes it: RM0090 §3.4.2 "Adaptive real-time memory
//! accelerator" gives 64 lines of 128 bits for instructions; it does not
//! say how lines are placed or replaced, so the model is fully associative
//! with least-recently-used replacement (an assumption, not a datasheet
//! fact). A miss on the line right after the previous one is *sequential*:
//! the 128-bit prefetch buffer (RM0090 §3.4.1 "Instruction prefetch") can
//! have fetched it already; any other miss is a *jump*.

/// Lines of the instruction cache (RM0090 §3.4.2).
pub const LINES: usize = 64;
/// Bytes per line: 128 bits (RM0090 §3.4.2).
pub const LINE_BYTES: u64 = 16;

/// Whether code at `addr` is fetched through the ART: the flash (main
/// memory at 0x0800_0000, 1 MB on the STM32F405, and its alias at 0 when
/// booting from flash; RM0090 §2.3, §3.3). Code in SRAM (0x2000_0000) is
/// fetched at zero wait states over the S-bus and never misses.
pub fn through_art(addr: u64) -> bool {
    addr < 0x0010_0000 || (0x0800_0000..0x0810_0000).contains(&addr)
}

/// What one line fetch found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fetch {
    Hit,
    /// Missed the line right after the previously fetched one.
    SequentialMiss,
    /// Missed any other line.
    JumpMiss,
}

/// Misses of a run of fetches.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Misses {
    pub lines: u64,
    pub sequential: u64,
    pub jump: u64,
}

/// A fully associative LRU cache of `LINES` lines.
#[derive(Debug, Clone)]
pub struct Art {
    /// Line number (address / 16) held by each way, `None` while empty.
    line: [Option<u64>; LINES],
    /// When each way was last used (larger = more recent).
    used: [u64; LINES],
    clock: u64,
    /// The line of the previous fetch, hit or miss.
    last: Option<u64>,
}

impl Default for Art {
    fn default() -> Self {
        Self {
            line: [None; LINES],
            used: [0; LINES],
            clock: 0,
            last: None,
        }
    }
}

impl Art {
    /// Fetch one line (`address / LINE_BYTES`).
    pub fn fetch(&mut self, line: u64) -> Fetch {
        self.clock = self.clock.wrapping_add(1);
        let sequential = self.last.and_then(|l| l.checked_add(1)) == Some(line);
        self.last = Some(line);
        if let Some(way) = self.line.iter().position(|&l| l == Some(line)) {
            if let Some(u) = self.used.get_mut(way) {
                *u = self.clock;
            }
            return Fetch::Hit;
        }
        // An empty way first, else the least recently used one.
        let victim = self
            .line
            .iter()
            .position(Option::is_none)
            .unwrap_or_else(|| {
                self.used
                    .iter()
                    .enumerate()
                    .min_by_key(|&(_, &u)| u)
                    .map_or(0, |(way, _)| way)
            });
        if let (Some(l), Some(u)) = (self.line.get_mut(victim), self.used.get_mut(victim)) {
            *l = Some(line);
            *u = self.clock;
        }
        if sequential {
            Fetch::SequentialMiss
        } else {
            Fetch::JumpMiss
        }
    }

    /// Fetch every line the bytes `start..end` touch, in address order.
    pub fn fetch_range(&mut self, start: u64, end: u64) -> Misses {
        let mut m = Misses::default();
        if end <= start {
            return m;
        }
        for line in start / LINE_BYTES..=(end - 1) / LINE_BYTES {
            m.lines += 1;
            match self.fetch(line) {
                Fetch::Hit => {}
                Fetch::SequentialMiss => m.sequential += 1,
                Fetch::JumpMiss => m.jump += 1,
            }
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_flash_goes_through_the_art() {
        assert!(through_art(0x0800_0000) && through_art(0x080F_FFFE));
        assert!(through_art(0x0000_0400));
        assert!(!through_art(0x2000_0000) && !through_art(0x1000_0000));
        assert!(!through_art(0x0810_0000));
    }

    #[test]
    fn a_loop_that_fits_misses_once_per_line() {
        let mut art = Art::default();
        // 32 lines of straight code, run 10 times: 1 jump miss, 31
        // sequential misses, then only hits.
        let first = art.fetch_range(0x0800_0000, 0x0800_0200);
        assert_eq!(
            first,
            Misses {
                lines: 32,
                sequential: 31,
                jump: 1
            }
        );
        for _ in 0..9 {
            assert_eq!(art.fetch_range(0x0800_0000, 0x0800_0200).sequential, 0);
        }
    }

    #[test]
    fn a_loop_one_line_too_big_misses_every_line_every_time() {
        // LRU's worst case: 65 lines in a row evict each other.
        let mut art = Art::default();
        let end = 0x0800_0000 + 65 * LINE_BYTES;
        art.fetch_range(0x0800_0000, end);
        let again = art.fetch_range(0x0800_0000, end);
        assert_eq!(again.lines, 65);
        assert_eq!(again.sequential + again.jump, 65);
        assert_eq!(again.jump, 1);
    }

    #[test]
    fn least_recently_used_goes_first() {
        let mut art = Art::default();
        for l in 0..64 {
            art.fetch(l * 2);
        }
        // Touch line 0 again: line 2 is now the oldest.
        assert_eq!(art.fetch(0), Fetch::Hit);
        assert_eq!(art.fetch(1000), Fetch::JumpMiss);
        assert_eq!(art.fetch(0), Fetch::Hit);
        assert_eq!(art.fetch(2), Fetch::JumpMiss);
        assert_eq!(art.fetch(3), Fetch::SequentialMiss);
    }

    #[test]
    fn a_block_across_a_line_boundary_fetches_both() {
        let mut art = Art::default();
        let m = art.fetch_range(0x0800_000c, 0x0800_0014);
        assert_eq!(m.lines, 2);
        assert_eq!(art.fetch_range(0x0800_0010, 0x0800_0012).lines, 1);
    }
}
