//! A chain of 74HC165 (parallel in, serial out: buttons, switches) and
//! 74HC595 (serial in, latched parallel out: lamps) on one SPI port, driven
//! at pin level: [`ShiftChain::step`] takes the levels the master holds on
//! CS, SCK and MOSI for one half clock period ([`Lines`]) and returns the
//! level the chain puts on MISO meanwhile. It knows nothing of the I/O
//! extension's transfer plans; the callers turn those into line levels.
//!
//! # Wiring assumed
//!
//! ```text
//!  SCK ──► CLK of every '165, SRCLK of every '595
//!  MOSI ─► SER of '595 #0;  QH' of '595 #k ─► SER of '595 #k+1
//!  MISO ◄─ QH of '165 #0;   SER of '165 #k ◄─ QH of '165 #k+1;  SER of the last '165 ◄─ GND
//!  CS ───► RCLK of every '595
//!  CS ─►[inverter]─► SH/LD of every '165
//!  '165 CLK INH ─ GND   '595 SRCLR ─ VCC   '595 OE ─ GND
//! ```
//!
//! The inverter is needed: SH/LD low *loads* the '165 (asynchronously, as
//! long as it is low, and the clock is ignored meanwhile), and the
//! extension's CS is low *during* the transfer. Wired directly, a '165
//! would reload all the time CS is low and MISO would read input H for every
//! bit. With the inverter the '165s follow their inputs while CS is high and
//! freeze them when CS falls.
//!
//! # What the parts do (datasheet behaviour)
//!
//! * **74HC165** — SH/LD low: the eight stages take the parallel inputs A..H
//!   (transparent while low); QH shows stage H, so bit H is on MISO right
//!   after the load, before the first clock. SH/LD high and CLK INH low: on
//!   every CLK rising edge the stages shift towards H (H ← G … B ← A, A ←
//!   SER). Falling edges do nothing.
//! * **74HC595** — on every SRCLK rising edge the shift register shifts
//!   towards QH (QA ← SER, QB ← QA …, QH' = QH before the edge); on an RCLK
//!   rising edge the output latches take the shift register. Falling edges
//!   do nothing; SRCLK is not gated by CS.
//! * Every part samples its data input with the levels *before* the edge
//!   (its hold time); MISO changes only after an edge. CS and SCK changing
//!   at the same boundary are taken CS first.
//!
//! Numbering: receive bit `i` of a transfer is input `H − i % 8` (pin index
//! `7 − i % 8`, A = 0) of '165 #`i / 8`; after an n-bit transfer transmit bit
//! `i` sits in '595 stage `n − 1 − i` (stage `8c + x` = output Q(A + x) of
//! '595 #c). With as many bits as stages, transmit bit 0 is QH of the last
//! '595 and bit n − 1 is QA of '595 #0.
//!
//! # What each SPI mode gives (the parts are mode-0/mode-3 devices)
//!
//! * Modes 0 and 3: exact in both directions.
//! * Mode 2 (CPOL 1, CPHA 0): exact too, but the '595 then shifts on the
//!   edge at which the master changes MOSI, so on real hardware it relies on
//!   MOSI changing after the '595's hold time (the timer engine changes it a
//!   DMA latency later; on the SPI engine it is a race).
//! * Mode 1 (CPOL 0, CPHA 1): everything is one bit late. The '165 shifts on
//!   the leading edge before the master samples, so the master receives
//!   inputs 1..n−1 and then the next bit (SER, 0 past the chain) — input 0 is
//!   lost. The '595 shifts on the leading edge, where MOSI still holds the
//!   previous bit, so it receives b0, b0, b1, …, b(n−2).

/// Most chips of each kind (256 bits).
pub const MAX_CHIPS: usize = 32;

/// The levels the master drives during one half period of SCK (true = high).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Lines {
    /// Chip select (the '595s' RCLK; the '165s' SH/LD through an inverter).
    pub cs: bool,
    pub sck: bool,
    pub mosi: bool,
}

impl Lines {
    /// CS high, SCK low, MOSI low: the lines at power-up.
    pub const IDLE: Lines = Lines {
        cs: true,
        sck: false,
        mosi: false,
    };

    pub const fn new(cs: bool, sck: bool, mosi: bool) -> Lines {
        Lines { cs, sck, mosi }
    }
}

/// `m` 74HC165s and `p` 74HC595s wired as the module doc shows.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ShiftChain {
    n165: usize,
    n595: usize,
    /// Parallel inputs of each '165: bit x = input A + x.
    inputs: [u8; MAX_CHIPS],
    /// '165 stages: bit x = stage A + x (QH = bit 7).
    sr165: [u8; MAX_CHIPS],
    /// '595 shift register: bit x = stage QA + x.
    sr595: [u8; MAX_CHIPS],
    /// '595 output latches: bit x = output QA + x.
    out595: [u8; MAX_CHIPS],
    /// Level on the last '165's SER.
    tail: bool,
    /// Line levels now ([`Lines::IDLE`] at power-up).
    lines: Lines,
    rising_edges: u64,
    latches: u64,
}

impl ShiftChain {
    /// `n165` and `n595` chips (each clamped to 0..=[`MAX_CHIPS`]), all
    /// inputs low, all registers and outputs 0, lines idle (CS high, SCK low).
    pub fn new(n165: usize, n595: usize) -> ShiftChain {
        ShiftChain {
            n165: n165.min(MAX_CHIPS),
            n595: n595.min(MAX_CHIPS),
            inputs: [0; MAX_CHIPS],
            sr165: [0; MAX_CHIPS],
            sr595: [0; MAX_CHIPS],
            out595: [0; MAX_CHIPS],
            tail: false,
            lines: Lines::IDLE,
            rising_edges: 0,
            latches: 0,
        }
    }

    /// Set parallel input `pin` (0 = A … 7 = H) of '165 #`chip`.
    pub fn set_input(&mut self, chip: usize, pin: usize, level: bool) {
        if chip < self.n165 {
            if let Some(b) = self.inputs.get_mut(chip) {
                let m = 1u8 << (pin % 8);
                if level {
                    *b |= m;
                } else {
                    *b &= !m;
                }
            }
        }
        if self.lines.cs {
            self.load();
        }
    }

    /// Set the input that receive bit `i` reads ('165 #`i / 8`, input
    /// `H − i % 8`).
    pub fn set_rx_bit(&mut self, i: usize, level: bool) {
        self.set_input(i / 8, 7usize.saturating_sub(i % 8), level);
    }

    /// Output `pin` (0 = QA … 7 = QH) of '595 #`chip` (false past the chain).
    pub fn output(&self, chip: usize, pin: usize) -> bool {
        chip < self.n595
            && self
                .out595
                .get(chip)
                .is_some_and(|b| b & (1 << (pin % 8)) != 0)
    }

    /// Output stage `s` (= 8·chip + pin) of the '595 chain.
    pub fn stage(&self, s: usize) -> bool {
        self.output(s / 8, s % 8)
    }

    /// The latched output that shows transmit bit `i` after an n-bit
    /// transfer: stage n − 1 − i (false if it fell off the chain).
    pub fn tx_bit_output(&self, n: usize, i: usize) -> bool {
        n.checked_sub(1)
            .and_then(|l| l.checked_sub(i))
            .is_some_and(|s| self.stage(s))
    }

    /// The level on MISO now.
    pub fn miso(&self) -> bool {
        if self.n165 == 0 {
            return self.tail;
        }
        self.sr165[0] & 0x80 != 0
    }

    /// SCK rising edges seen so far (with CS low or high).
    pub fn rising_edges(&self) -> u64 {
        self.rising_edges
    }

    /// RCLK rising edges (output latches) so far.
    pub fn latches(&self) -> u64 {
        self.latches
    }

    fn load(&mut self) {
        self.sr165 = self.inputs;
    }

    /// Clock a whole transfer: each half period's lines with whether the
    /// master samples MISO at its end. The sampled levels in wire order,
    /// most significant bit first in each 16-bit word (sample k is bit
    /// `15 − k % 16` of word `k / 16`, the I/O extension's receive layout);
    /// samples past `W` words are dropped.
    pub fn clock_transfer<const W: usize>(
        &mut self,
        halves: impl IntoIterator<Item = (Lines, bool)>,
    ) -> [u16; W] {
        let mut words = [0u16; W];
        let mut k = 0usize;
        for (lines, sample) in halves {
            let miso = self.step(lines);
            if sample {
                if let Some(w) = words.get_mut(k / 16) {
                    // 15 ^ i = 15 − i for i < 16.
                    *w |= u16::from(miso) << (15 ^ (k % 16) as u32);
                }
                k = k.saturating_add(1);
            }
        }
        words
    }

    /// Move the lines to `h`'s levels (CS first, then SCK, each edge seeing
    /// the levels before it), then hold them for the half period. Returns
    /// the MISO level during it (what a master sampling at its end reads).
    pub fn step(&mut self, h: Lines) -> bool {
        let before = self.lines;
        // CS rising: RCLK rises (latch) and SH/LD falls (load, then follow
        // the inputs). CS falling: SH/LD rises, the '165s keep the snapshot.
        if before.cs != h.cs && h.cs {
            self.out595 = self.sr595;
            self.latches = self.latches.wrapping_add(1);
            self.load();
        }
        if before.sck != h.sck && h.sck {
            self.rising_edges = self.rising_edges.wrapping_add(1);
            self.clock(h.cs, before.mosi);
        }
        self.lines = h;
        self.miso()
    }

    /// One rising edge on SCK: '165s shift when SH/LD is high (CS low),
    /// '595s always.
    fn clock(&mut self, cs: bool, mosi: bool) {
        if !cs {
            // Each '165 takes the MSB of the next one; the last takes the
            // serial input of the chain's end.
            let n = self.n165.min(self.sr165.len());
            let mut ser = self.tail;
            for slot in self.sr165.iter_mut().take(n).rev() {
                let out = *slot & 0x80 != 0;
                *slot = (*slot << 1) | u8::from(ser);
                ser = out;
            }
        }
        let mut ser = mosi;
        for slot in self.sr595.iter_mut().take(self.n595) {
            let out = *slot & 0x80 != 0;
            *slot = (*slot << 1) | u8::from(ser);
            ser = out;
        }
    }
}

/// A line of the QEMU image's I/O-extension console (the test hook that
/// presses the simulated buttons): `press N` closes the contact of input N
/// (receive bit N, wire order) and `release N` opens it. The inputs have
/// pull-ups and contacts to GND, as the box's (docs/ioext.md), so a closed
/// contact reads 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConsoleCommand {
    /// Receive bit (wire order).
    pub bit: usize,
    /// `press`: the contact closes (the bit reads 0).
    pub closed: bool,
}

impl ConsoleCommand {
    /// The command on `line` (ASCII, surrounding blanks ignored), or `None`
    /// for anything else, a bit at or past `inputs` included.
    pub fn parse(line: &[u8], inputs: usize) -> Option<ConsoleCommand> {
        let text = core::str::from_utf8(line).ok()?.trim();
        let (verb, arg) = text.split_once(' ')?;
        let closed = match verb {
            "press" => true,
            "release" => false,
            _ => return None,
        };
        let bit: usize = arg.trim().parse().ok()?;
        (bit < inputs).then_some(ConsoleCommand { bit, closed })
    }
}

/// Highest supply a `supply MV` line takes, mV.
pub const CONSOLE_SUPPLY_MAX_MV: u32 = 200_000;

/// A line of the QEMU image's test console (its first `-serial`): the
/// I/O-extension buttons ([`ConsoleCommand`]) and the faults injected into
/// the simulated hardware, so the bring-up checks (`stepctl doctor`) can be
/// tested with no board.
///
/// | line | what |
/// |---|---|
/// | `press N`, `release N` | I/O-extension input N closed / open |
/// | `chip K dead [HH]` | chip K (0 = the first axis) stops working: its SDO stuck at byte HH (hex, default FF), input ignored |
/// | `chip K revive` | undo `dead` |
/// | `chip K reset` | a power cycle of chip K: registers at their reset values, UVLO flagged |
/// | `chip K uvlo` | undervoltage lockout at chip K (a supply dip): bridges off |
/// | `chip K ocd` | overcurrent at chip K |
/// | `supply MV`, `supply off` | the ADC reads a motor supply of MV millivolts / the platform's own reading again |
/// | `jumper on`, `jumper off` | a MOSI → MISO jumper on the I/O extension's port (it then reads back what it sends) |
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConsoleLine {
    Input(ConsoleCommand),
    ChipDead {
        chip: usize,
        stuck: u8,
    },
    ChipRevive(usize),
    ChipReset(usize),
    ChipUvlo(usize),
    ChipOvercurrent(usize),
    /// mV; `None`: the platform's own reading.
    Supply(Option<u32>),
    Jumper(bool),
}

impl ConsoleLine {
    /// The line (ASCII, words separated by blanks), or `None` for anything
    /// else: an input at or past `inputs`, a chip at or past `chips`, a
    /// supply above [`CONSOLE_SUPPLY_MAX_MV`].
    pub fn parse(line: &[u8], inputs: usize, chips: usize) -> Option<ConsoleLine> {
        if let Some(c) = ConsoleCommand::parse(line, inputs) {
            return Some(ConsoleLine::Input(c));
        }
        let text = core::str::from_utf8(line).ok()?;
        let mut w = [""; 4];
        let mut n = 0;
        for word in text.split_ascii_whitespace() {
            *w.get_mut(n)? = word;
            n = n.saturating_add(1);
        }
        let chip = |k: &str| k.parse::<usize>().ok().filter(|k| *k < chips);
        match w.get(..n).unwrap_or(&[]) {
            ["chip", k, "dead"] => Some(ConsoleLine::ChipDead {
                chip: chip(k)?,
                stuck: 0xFF,
            }),
            ["chip", k, "dead", hh] => Some(ConsoleLine::ChipDead {
                chip: chip(k)?,
                stuck: u8::from_str_radix(hh, 16).ok()?,
            }),
            ["chip", k, "revive"] => Some(ConsoleLine::ChipRevive(chip(k)?)),
            ["chip", k, "reset"] => Some(ConsoleLine::ChipReset(chip(k)?)),
            ["chip", k, "uvlo"] => Some(ConsoleLine::ChipUvlo(chip(k)?)),
            ["chip", k, "ocd"] => Some(ConsoleLine::ChipOvercurrent(chip(k)?)),
            ["supply", "off"] => Some(ConsoleLine::Supply(None)),
            ["supply", mv] => {
                let mv: u32 = mv.parse().ok().filter(|v| *v <= CONSOLE_SUPPLY_MAX_MV)?;
                Some(ConsoleLine::Supply(Some(mv)))
            }
            ["jumper", "on"] => Some(ConsoleLine::Jumper(true)),
            ["jumper", "off"] => Some(ConsoleLine::Jumper(false)),
            _ => None,
        }
    }

    /// The fault a `chip` line injects into its chip.
    pub fn chip_fault(&self) -> Option<(usize, super::Fault)> {
        use super::Fault;
        Some(match *self {
            ConsoleLine::ChipDead { chip, stuck } => (chip, Fault::Dead(stuck)),
            ConsoleLine::ChipRevive(chip) => (chip, Fault::Revive),
            ConsoleLine::ChipReset(chip) => (chip, Fault::PowerCycle),
            ConsoleLine::ChipUvlo(chip) => (chip, Fault::Uvlo),
            ConsoleLine::ChipOvercurrent(chip) => (chip, Fault::Overcurrent),
            _ => return None,
        })
    }
}

impl ShiftChain {
    /// Apply a console command to the inputs (pull-up: closed reads 0).
    pub fn apply(&mut self, command: ConsoleCommand) {
        self.set_rx_bit(command.bit, !command.closed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An SPI mode: clock polarity and phase.
    #[derive(Clone, Copy, Debug)]
    struct Mode {
        cpol: bool,
        cpha: bool,
    }

    const MODE0: Mode = Mode {
        cpol: false,
        cpha: false,
    };
    const MODE1: Mode = Mode {
        cpol: false,
        cpha: true,
    };
    const MODE2: Mode = Mode {
        cpol: true,
        cpha: false,
    };
    const MODE3: Mode = Mode {
        cpol: true,
        cpha: true,
    };

    /// One transfer as a textbook SPI master clocks it: CS falls with SCK at
    /// CPOL, then per bit a leading and a trailing half period, then CS
    /// rises. CPHA = 0: MOSI holds bit i before leading edge i, changes on
    /// trailing edges, the master samples on leading edges. CPHA = 1: MOSI
    /// changes on leading edges, the master samples on trailing edges.
    /// Returns each half period's lines and whether the master samples at
    /// its end.
    fn wave(tx: &[bool], mode: Mode, cs_low_before: bool, cs_hold: bool) -> Vec<(Lines, bool)> {
        let n = tx.len().max(1);
        let b = |i: usize| tx.get(i.min(n - 1)).copied().unwrap_or(false);
        let at = |cs, sck, mosi, sample| (Lines { cs, sck, mosi }, sample);
        let Mode { cpol, cpha } = mode;
        let mut w = vec![
            at(!cs_low_before, cpol, b(0), false),
            at(false, cpol, b(0), !cpha),
        ];
        for i in 0..n {
            w.push(at(false, !cpol, b(i), cpha));
            let next = if cpha { b(i) } else { b(i + 1) };
            w.push(at(false, cpol, next, !cpha && i + 1 < n));
        }
        w.push(at(!cs_hold, cpol, b(n - 1), false));
        w
    }

    /// Clock a transfer of `tx` through `c`: the bits the master receives.
    fn run(c: &mut ShiftChain, tx: &[bool], mode: Mode) -> Vec<bool> {
        run_framed(c, tx, mode, false, false)
    }

    fn run_framed(
        c: &mut ShiftChain,
        tx: &[bool],
        mode: Mode,
        cs_low_before: bool,
        cs_hold: bool,
    ) -> Vec<bool> {
        let mut rx = vec![];
        for (lines, sample) in wave(tx, mode, cs_low_before, cs_hold) {
            let miso = c.step(lines);
            if sample {
                rx.push(miso);
            }
        }
        assert_eq!(rx.len(), tx.len().max(1));
        rx
    }

    /// 256 bits that tell positions apart.
    fn pattern(seed: u32) -> Vec<bool> {
        let mut x = seed | 1;
        (0..256)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                x & 1 != 0
            })
            .collect()
    }

    /// A chain with `chips` of each kind and the inputs set to `inputs` (in
    /// receive-bit order).
    fn chain(chips: usize, inputs: &[bool]) -> ShiftChain {
        let mut c = ShiftChain::new(chips, chips);
        for (i, level) in inputs.iter().take(chips * 8).enumerate() {
            c.set_rx_bit(i, *level);
        }
        c
    }

    #[test]
    fn the_165_shows_input_h_before_the_first_clock() {
        let mut c = ShiftChain::new(1, 0);
        c.set_input(0, 7, true);
        assert!(c.miso());
        c.set_input(0, 7, false);
        assert!(!c.miso(), "transparent while SH/LD is low");
    }

    #[test]
    fn mode_0_and_3_are_exact_in_both_directions() {
        for mode in [MODE0, MODE3] {
            let (ins, tx) = (pattern(1), pattern(2));
            let mut c = chain(2, &ins);
            let rx = run(&mut c, &tx[..16], mode);
            for i in 0..16 {
                assert_eq!(rx[i], ins[i], "{mode:?} rx {i}");
                assert_eq!(c.tx_bit_output(16, i), tx[i], "{mode:?} tx {i}");
            }
            assert_eq!(c.latches(), 1);
        }
    }

    #[test]
    fn mode_2_is_exact_by_the_edge_convention() {
        let (ins, tx) = (pattern(3), pattern(4));
        let mut c = chain(2, &ins);
        let rx = run(&mut c, &tx[..16], MODE2);
        for i in 0..16 {
            assert_eq!(rx[i], ins[i], "rx {i}");
            assert_eq!(c.tx_bit_output(16, i), tx[i], "tx {i}");
        }
    }

    #[test]
    fn mode_1_loses_input_0_and_shifts_the_outputs_by_one() {
        let (ins, tx) = (pattern(5), pattern(6));
        let mut c = chain(2, &ins);
        let rx = run(&mut c, &tx[..16], MODE1);
        for i in 0..15 {
            assert_eq!(rx[i], ins[i + 1], "rx {i}");
        }
        // The 16th sample is the SER tail (GND).
        assert!(!rx[15]);
        // '595: b0, b0, b1, …, b14.
        assert_eq!(c.tx_bit_output(16, 0), tx[0]);
        for i in 1..16 {
            assert_eq!(c.tx_bit_output(16, i), tx[i - 1], "tx {i}");
        }
    }

    #[test]
    fn every_bit_count_reads_the_first_n_inputs_and_shifts_n_outputs() {
        for n in [1usize, 7, 8, 9, 31, 32, 33, 255, 256] {
            for mode in [MODE0, MODE3] {
                let (ins, tx) = (pattern(n as u32), pattern(n as u32 + 1000));
                let mut c = chain(32, &ins);
                let rx = run(&mut c, &tx[..n], mode);
                for i in 0..256 {
                    // Received: the first n inputs.
                    if i < n {
                        assert_eq!(rx[i], ins[i], "n {n} rx {i}");
                    }
                    // Latched: tx bit i at stage n − 1 − i; stages ≥ n still 0.
                    if i < n {
                        assert_eq!(c.tx_bit_output(n, i), tx[i], "n {n} tx {i}");
                    } else {
                        assert!(!c.stage(i), "n {n} stage {i}");
                    }
                }
                // Mode 3: SCK goes from the power-up low to its idle high
                // once, with CS high (one more rising edge, no '165 shift).
                assert_eq!(c.rising_edges(), n as u64 + u64::from(mode.cpol));
            }
        }
    }

    #[test]
    fn cs_held_low_makes_two_transfers_one() {
        let (ins, tx) = (pattern(7), pattern(8));
        let mut c = chain(2, &ins);
        let rx1 = run_framed(&mut c, &tx[..8], MODE0, false, true);
        assert_eq!(c.latches(), 0, "no latch while CS stays low");
        // Second half: bits 8..16 of the same 16-bit string.
        let rx2 = run_framed(&mut c, &tx[8..16], MODE0, true, false);
        for i in 0..8 {
            assert_eq!(rx1[i], ins[i]);
            assert_eq!(rx2[i], ins[i + 8], "the '165s were not reloaded");
        }
        for (i, bit) in tx.iter().take(16).enumerate() {
            assert_eq!(c.tx_bit_output(16, i), *bit);
        }
        assert_eq!(c.latches(), 1);
    }

    #[test]
    fn inputs_changed_during_a_transfer_do_not_reach_it() {
        let mut c = ShiftChain::new(1, 0);
        let mut samples = vec![];
        for (k, (lines, sample)) in wave(&[false; 8], MODE0, false, false)
            .into_iter()
            .enumerate()
        {
            let miso = c.step(lines);
            if sample {
                samples.push(miso);
            }
            if k == 2 {
                c.set_input(0, 3, true); // CS is low: the snapshot stands
            }
        }
        assert_eq!(samples, [false; 8]);
        // Once CS is high again the '165 follows its inputs.
        c.set_input(0, 7, true);
        assert!(c.miso());
    }

    #[test]
    fn a_cpol_change_with_cs_high_shifts_the_595_but_not_the_165() {
        let mut c = ShiftChain::new(1, 1);
        c.set_input(0, 7, true);
        // Idle low, then a mode-2 transfer starts with SCK high: one rising
        // edge with CS high.
        let _ = run(&mut c, &[false; 8], MODE2);
        assert_eq!(c.rising_edges(), 9);
        assert!(c.miso(), "the '165 reloaded, not shifted");
    }

    #[test]
    fn step_returns_the_level_on_miso_during_the_half_period() {
        let mut c = ShiftChain::new(1, 0);
        c.set_input(0, 7, true);
        c.set_input(0, 6, false);
        let low = Lines {
            cs: false,
            sck: false,
            mosi: false,
        };
        assert!(c.step(low), "CS fell: input H frozen on QH");
        assert!(!c.step(Lines { sck: true, ..low }), "rising edge: G on QH");
        assert!(!c.step(low), "falling edges do nothing");
    }

    #[test]
    fn console_lines_press_and_release_inputs_within_the_chain() {
        let parse = |l: &str| ConsoleCommand::parse(l.as_bytes(), 16);
        assert_eq!(
            parse("press 3"),
            Some(ConsoleCommand {
                bit: 3,
                closed: true
            })
        );
        assert_eq!(
            parse("  release 15 "),
            Some(ConsoleCommand {
                bit: 15,
                closed: false
            })
        );
        assert_eq!(parse("press 16"), None, "past the chain");
        for bad in ["", "press", "press x", "push 3", "press -1", "PRESS 3"] {
            assert_eq!(parse(bad), None, "{bad:?}");
        }
        assert_eq!(ConsoleCommand::parse(&[0xFF, b' ', b'1'], 16), None);

        let mut chain = ShiftChain::new(2, 1);
        for i in 0..16 {
            chain.set_rx_bit(i, true);
        }
        let zeros = [false; 16];
        assert_eq!(
            run(&mut chain, &zeros, MODE0),
            [true; 16],
            "pull-ups: all open"
        );
        chain.apply(ConsoleCommand {
            bit: 3,
            closed: true,
        });
        let rx = run(&mut chain, &zeros, MODE0);
        for (i, b) in rx.iter().enumerate() {
            assert_eq!(*b, i != 3, "bit 3 closed reads 0 (bit {i})");
        }
        chain.apply(ConsoleCommand {
            bit: 3,
            closed: false,
        });
        assert_eq!(run(&mut chain, &zeros, MODE0), [true; 16]);
    }

    #[test]
    fn console_lines_inject_chip_faults_supply_readings_and_a_jumper() {
        use crate::Fault;
        let parse = |l: &str| ConsoleLine::parse(l.as_bytes(), 16, 4);
        assert_eq!(
            parse("press 3"),
            Some(ConsoleLine::Input(ConsoleCommand {
                bit: 3,
                closed: true
            }))
        );
        assert_eq!(
            parse("chip 2 dead"),
            Some(ConsoleLine::ChipDead {
                chip: 2,
                stuck: 0xFF
            })
        );
        assert_eq!(
            parse(" chip 0  dead 00 "),
            Some(ConsoleLine::ChipDead { chip: 0, stuck: 0 })
        );
        assert_eq!(parse("chip 3 revive"), Some(ConsoleLine::ChipRevive(3)));
        assert_eq!(parse("chip 1 reset"), Some(ConsoleLine::ChipReset(1)));
        assert_eq!(parse("chip 1 uvlo"), Some(ConsoleLine::ChipUvlo(1)));
        assert_eq!(parse("chip 1 ocd"), Some(ConsoleLine::ChipOvercurrent(1)));
        assert_eq!(
            parse("supply 12000"),
            Some(ConsoleLine::Supply(Some(12_000)))
        );
        assert_eq!(parse("supply 0"), Some(ConsoleLine::Supply(Some(0))));
        assert_eq!(parse("supply off"), Some(ConsoleLine::Supply(None)));
        assert_eq!(parse("jumper on"), Some(ConsoleLine::Jumper(true)));
        assert_eq!(parse("jumper off"), Some(ConsoleLine::Jumper(false)));
        for bad in [
            "",
            "chip 4 dead",
            "chip x reset",
            "chip 1",
            "chip 1 explode",
            "chip 1 dead 100",
            "chip 1 dead FF extra",
            "supply -1",
            "supply 200001",
            "supply 12 V",
            "jumper maybe",
            "mcu reset",
            "CHIP 1 reset",
        ] {
            assert_eq!(parse(bad), None, "{bad:?}");
        }
        assert_eq!(ConsoleLine::parse(&[0xFF, b' ', b'1'], 16, 4), None);
        assert_eq!(
            parse("chip 2 dead 5A").and_then(|l| l.chip_fault()),
            Some((2, Fault::Dead(0x5A)))
        );
        assert_eq!(
            parse("chip 1 reset").and_then(|l| l.chip_fault()),
            Some((1, Fault::PowerCycle))
        );
        assert_eq!(
            parse("chip 1 ocd").and_then(|l| l.chip_fault()),
            Some((1, Fault::Overcurrent))
        );
        assert_eq!(parse("supply 9000").and_then(|l| l.chip_fault()), None);
    }
}
