//! The chip image: the registers the bridge configures on its chip, the
//! values it wants there, and which of them are still to be written (and
//! confirmed by the next STATUS).

use crate::powerstep::registers::Register;

/// Registers the bridge configures on the chip (besides the motion
/// registers MAX_SPEED, ACC, DEC, ABS_POS), with the values it wants there
/// and which of them still have to be written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChipImage {
    /// Wanted values, index = address − 1.
    values: [u32; 27],
    /// Bit `address`: the bridge configures this register.
    owned: u32,
    /// Bit `address`: not written since the last reset or change.
    dirty: u32,
    /// Bit `address`: written since the last GetStatus went out (the next
    /// STATUS says whether the chip took it).
    unconfirmed: u32,
    /// Bit `address`: written before the GetStatus now in flight; its
    /// CMD_ERROR puts them back on the list ([`ChipImage::refused`]).
    checking: u32,
}

impl ChipImage {
    pub(super) const fn new() -> ChipImage {
        ChipImage {
            values: [0; 27],
            owned: 0,
            dirty: 0,
            unconfirmed: 0,
            checking: 0,
        }
    }

    /// Want `value` in `reg` (masked to its width).
    pub(super) fn set(&mut self, reg: Register, value: u32) {
        let value = value & reg.mask();
        let bit = 1u32 << reg.address();
        let slot = self.values.get_mut(usize::from(reg.address()) - 1);
        if let Some(slot) = slot {
            if self.owned & bit == 0 || *slot != value {
                *slot = value;
                self.owned |= bit;
                self.dirty |= bit;
            }
        }
    }

    /// The wanted value of `reg`, if the bridge configures it.
    pub fn get(&self, reg: Register) -> Option<u32> {
        if self.owned & (1 << reg.address()) == 0 {
            return None;
        }
        self.values.get(usize::from(reg.address()) - 1).copied()
    }

    /// The chip was reset: every owned register has to be written again.
    pub(super) fn on_reset(&mut self) {
        self.dirty = self.owned;
        self.unconfirmed = 0;
        self.checking = 0;
    }

    /// Nothing left to write.
    pub fn is_clean(&self) -> bool {
        self.dirty == 0
    }

    /// Configured registers not yet written (since the last reset or change).
    pub fn pending(&self) -> u32 {
        (self.dirty & self.owned).count_ones()
    }

    /// The next register to write: STEP_MODE, then CONFIG, then by address,
    /// among those `allowed` accepts.
    pub(super) fn next(&self, allowed: impl Fn(Register) -> bool) -> Option<(Register, u32)> {
        // The control tick asks every tick; almost always nothing is dirty.
        if self.dirty == 0 {
            return None;
        }
        let first = [Register::StepMode, Register::Config];
        first
            .into_iter()
            .chain(Register::all())
            .filter(|r| self.dirty & (1 << r.address()) != 0 && allowed(*r))
            .find_map(|r| self.get(r).map(|v| (r, v)))
    }

    /// Some register waits to be written.
    pub(super) fn dirty(&self) -> bool {
        self.dirty != 0
    }

    pub(super) fn written(&mut self, reg: Register) {
        let bit = 1u32 << reg.address();
        self.dirty &= !bit;
        self.unconfirmed |= bit;
    }

    /// A GetStatus goes out: the writes before it are what its CMD_ERROR
    /// would be about.
    pub(super) fn status_requested(&mut self) {
        self.checking |= self.unconfirmed;
        self.unconfirmed = 0;
    }

    /// That STATUS came back: with CMD_ERROR the chip refused a command
    /// since the previous one — maybe one of these writes — so they are
    /// written again (the same values: harmless if the refusal was another
    /// command's). A register is written only once the chip has taken it.
    pub(super) fn status_seen(&mut self, cmd_error: bool) {
        if cmd_error {
            self.dirty |= self.checking & self.owned;
        }
        self.checking = 0;
    }

    /// Write `reg` again (if owned) at the next chance.
    pub(super) fn touch(&mut self, reg: Register) {
        let bit = 1u32 << reg.address();
        self.dirty |= self.owned & bit;
    }
}
