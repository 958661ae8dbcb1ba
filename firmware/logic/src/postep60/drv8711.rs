//! The PoStep60's DRV8711 register image (USB 0x80 / 0x81 / 0x84 / 0x85).
//!
//! A PoStep60 drives its motor with a TI DRV8711 and lets USB software read
//! and write that chip's eight 12-bit registers. The bridge has powerSTEP01s
//! instead, so it keeps the image and gives each field that has a
//! powerSTEP01 meaning that meaning; the others are stored and read back,
//! with no effect (a table in `docs/DECISIONS.md`):
//!
//! | register | field (bits) | here |
//! |---|---|---|
//! | CTRL | ENBL (0) | run (1) / sleep (0), like Run/Sleep |
//! | CTRL | RDIR (1) | inverts the direction byte of 0x90 Step/Dir (the DRV8711's DIR-pin inversion) |
//! | CTRL | RSTEP (2) | always reads 0 (self-clearing on the DRV8711); writing 1 does nothing |
//! | CTRL | MODE (6:3) | the PoStep60 step mode 0..=8 (0x33); 9..15 ignored |
//! | CTRL | ISGAIN (9:8) | Ai of the full-scale current (0x30): ISGAIN 5/10/20/40 = Ai 0/1/2/3 |
//! | TORQUE | TORQUE (7:0) | Tq of the full-scale current: I = 0.065·Tq/2^Ai A, the same encoding as I2C |
//! | STATUS | OTS…STDLAT (7:0) | the fault bits of 0x25 on read; writing a 0 bit clears (Reset faults) |
//! | CTRL EXSTALL, DTIME; TORQUE SMPLTH; OFF; BLANK; DECAY; STALL; DRIVE | | stored, read back, no effect |
//!
//! The ISGAIN/TORQUE pair matches the DRV8711 formula `I = 2.75·TORQUE /
//! (256·ISGAIN·R_sense)` with the PoStep60's sense resistor of about 33 mΩ:
//! `2.75 / (256 · 5 · 0.033) ≈ 0.065`, so ISGAIN 5 ↔ Ai 0 and each doubling
//! of the gain halves the current, as each step of Ai does.

use super::current::Current;

/// Registers in the order of the USB tables: CTRL, TORQUE, OFF, BLANK,
/// DECAY, STALL, DRIVE, STATUS.
pub const REGISTERS: usize = 8;

/// The eight registers, raw 12-bit values (bits 15:12 are the DRV8711's
/// address and read as 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Drv8711Regs(pub [u16; REGISTERS]);

/// Register indexes.
pub mod reg {
    pub const CTRL: usize = 0;
    pub const TORQUE: usize = 1;
    pub const OFF: usize = 2;
    pub const BLANK: usize = 3;
    pub const DECAY: usize = 4;
    pub const STALL: usize = 5;
    pub const DRIVE: usize = 6;
    pub const STATUS: usize = 7;
}

const ENBL: u16 = 1 << 0;
const RDIR: u16 = 1 << 1;
const RSTEP: u16 = 1 << 2;
const MODE_SHIFT: u16 = 3;
const MODE_MASK: u16 = 0xF << MODE_SHIFT;
const ISGAIN_SHIFT: u16 = 8;
const ISGAIN_MASK: u16 = 0x3 << ISGAIN_SHIFT;
const TORQUE_MASK: u16 = 0xFF;
const WIDTH: u16 = 0x0FFF;

/// The fields of the image that mean something on the bridge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Mapped {
    /// CTRL.ENBL.
    pub enable: bool,
    /// CTRL.RDIR.
    pub reverse_step_dir: bool,
    /// CTRL.MODE when 0..=8 (`None`: 9..15, ignored).
    pub step_mode: Option<u8>,
    /// CTRL.ISGAIN (Ai) and TORQUE.TORQUE (Tq).
    pub full_scale: Current,
    /// STATUS bits (the 0x25 fault layout).
    pub status: u8,
}

impl Drv8711Regs {
    /// The DRV8711's reset values (datasheet register map).
    pub const RESET: Drv8711Regs = Drv8711Regs([
        0x0C10, 0x01FF, 0x0030, 0x0080, 0x0110, 0x0040, 0x0A59, 0x0000,
    ]);

    /// Register `i` (0 for an index past STATUS).
    pub fn get(&self, i: usize) -> u16 {
        self.0.get(i).copied().unwrap_or(0)
    }

    /// The mapped fields.
    pub fn mapped(&self) -> Mapped {
        let ctrl = self.get(reg::CTRL);
        let mode = ((ctrl & MODE_MASK) >> MODE_SHIFT) as u8;
        Mapped {
            enable: ctrl & ENBL != 0,
            reverse_step_dir: ctrl & RDIR != 0,
            step_mode: (mode <= 8).then_some(mode),
            full_scale: Current {
                tq: (self.get(reg::TORQUE) & TORQUE_MASK) as u8,
                ai: ((ctrl & ISGAIN_MASK) >> ISGAIN_SHIFT) as u8,
            },
            status: (self.get(reg::STATUS) & 0xFF) as u8,
        }
    }

    /// The image as a PoStep60 reports it: the stored registers with the
    /// mapped fields replaced by the live values. A current whose Ai is
    /// above 3 (possible over I2C) is shown as the equal one with Ai ≤ 3.
    pub fn live(&self, m: &Mapped) -> Drv8711Regs {
        let mut r = self.0.map(|v| v & WIDTH);
        let c = m.full_scale.with_ai_at_most(3);
        let mode = u16::from(m.step_mode.unwrap_or(0).min(8));
        let mut ctrl = r[reg::CTRL] & !(ENBL | RDIR | RSTEP | MODE_MASK | ISGAIN_MASK);
        if m.enable {
            ctrl |= ENBL;
        }
        if m.reverse_step_dir {
            ctrl |= RDIR;
        }
        ctrl |= mode << MODE_SHIFT;
        ctrl |= (u16::from(c.ai) << ISGAIN_SHIFT) & ISGAIN_MASK;
        r[reg::CTRL] = ctrl;
        r[reg::TORQUE] = (r[reg::TORQUE] & !TORQUE_MASK) | u16::from(c.tq);
        r[reg::STATUS] = u16::from(m.status);
        Drv8711Regs(r)
    }

    /// What to store of a written image: every register masked to 12 bits,
    /// RSTEP cleared (it is a command, not a setting), STATUS as 0 (it is
    /// read from the faults).
    pub fn stored(&self) -> Drv8711Regs {
        let mut r = self.0.map(|v| v & WIDTH);
        r[reg::CTRL] &= !RSTEP;
        r[reg::STATUS] = 0;
        Drv8711Regs(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reset_values_map_to_sleep_full_step_and_the_largest_torque() {
        let m = Drv8711Regs::RESET.mapped();
        assert!(!m.enable);
        assert_eq!(m.step_mode, Some(2)); // 0xC10: MODE = 0010
        assert_eq!(m.full_scale, Current { tq: 0xFF, ai: 0 });
    }

    #[test]
    fn ctrl_fields_sit_where_the_datasheet_puts_them() {
        // ENBL, MODE 1/256 (1000), ISGAIN 40 (11), DTIME 850 ns (11)
        let r = Drv8711Regs([0x0F41, 0x0080, 0, 0, 0, 0, 0, 0]);
        let m = r.mapped();
        assert!(m.enable && !m.reverse_step_dir);
        assert_eq!(m.step_mode, Some(8));
        assert_eq!(m.full_scale, Current { tq: 0x80, ai: 3 });
        // MODE 9..15 is not a step mode
        assert_eq!(
            Drv8711Regs([0x0048, 0, 0, 0, 0, 0, 0, 0])
                .mapped()
                .step_mode,
            None
        );
    }

    #[test]
    fn the_live_image_keeps_stored_fields_and_shows_the_mapped_ones() {
        let stored = Drv8711Regs([
            0x0C07, 0x0512, 0x0031, 0x0181, 0x0510, 0x0A40, 0x0F59, 0x00FF,
        ])
        .stored();
        assert_eq!(stored.get(reg::CTRL), 0x0C03, "RSTEP cleared");
        assert_eq!(stored.get(reg::STATUS), 0);
        let live = stored.live(&Mapped {
            enable: false,
            reverse_step_dir: true,
            step_mode: Some(4),
            full_scale: Current { tq: 123, ai: 2 },
            status: 0x21,
        });
        // DTIME 11 kept, ISGAIN 10, MODE 0100, RDIR, no ENBL
        assert_eq!(live.get(reg::CTRL), 0x0C00 | 0x0200 | (4 << 3) | 0x2);
        // SMPLTH (0x5) kept, TORQUE = Tq
        assert_eq!(live.get(reg::TORQUE), 0x0500 | 123);
        assert_eq!(live.get(reg::OFF), 0x031);
        assert_eq!(live.get(reg::DRIVE), 0xF59);
        assert_eq!(live.get(reg::STATUS), 0x21);
    }

    #[test]
    fn one_milliamp_scale_currents_with_a_large_ai_show_their_ai_3_twin() {
        let live = Drv8711Regs::RESET.live(&Mapped {
            enable: true,
            reverse_step_dir: false,
            step_mode: Some(0),
            full_scale: Current { tq: 200, ai: 5 },
            status: 0,
        });
        // 0.065·200/32 = 0.065·50/8
        assert_eq!(live.mapped().full_scale, Current { tq: 50, ai: 3 });
    }
}
