//! The powerSTEP01 register map (datasheet, ST AN4290 table 4).
//!
//! One table, [`REGISTERS`], is the single source of truth for address,
//! width, SPI byte count, access class, names and reset value. Everything
//! else (command encoding, the simulator, the scheduler) asks this table.
//!
//! Deviation from the datasheet, decided in `docs/DECISIONS.md`: EL_POS is
//! classed **WH** (writable only in HiZ) as ST's own protocol note (AN4290,
//! table 4) says, not WS. The stricter class is safe for the bridge (it never
//! writes EL_POS while the bridges are on) and makes the simulator catch it.

/// Who may write a register, and when (datasheet "Access").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Access {
    /// R: read-only. A SetParam is refused at the command byte.
    ReadOnly,
    /// WR: writable at any time.
    Always,
    /// WS: writable only while the motor is stopped.
    WhenStopped,
    /// WH: writable only while the bridges are in high impedance.
    WhenHiZ,
}

/// A powerSTEP01 register. The discriminant is the register address.
///
/// Names are the voltage-mode names; the current-mode aliases share the
/// same storage (`TVAL_HOLD` is [`Register::KvalHold`], and so on).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Register {
    AbsPos = 0x01,
    ElPos = 0x02,
    Mark = 0x03,
    Speed = 0x04,
    Acc = 0x05,
    Dec = 0x06,
    MaxSpeed = 0x07,
    MinSpeed = 0x08,
    KvalHold = 0x09,
    KvalRun = 0x0A,
    KvalAcc = 0x0B,
    KvalDec = 0x0C,
    IntSpeed = 0x0D,
    StSlp = 0x0E,
    FnSlpAcc = 0x0F,
    FnSlpDec = 0x10,
    KTherm = 0x11,
    AdcOut = 0x12,
    OcdTh = 0x13,
    StallTh = 0x14,
    FsSpd = 0x15,
    StepMode = 0x16,
    AlarmEn = 0x17,
    GateCfg1 = 0x18,
    GateCfg2 = 0x19,
    Config = 0x1A,
    Status = 0x1B,
}

/// Current-mode aliases (same address, same storage).
impl Register {
    pub const TVAL_HOLD: Register = Register::KvalHold;
    pub const TVAL_RUN: Register = Register::KvalRun;
    pub const TVAL_ACC: Register = Register::KvalAcc;
    pub const TVAL_DEC: Register = Register::KvalDec;
    pub const T_FAST: Register = Register::StSlp;
    pub const TON_MIN: Register = Register::FnSlpAcc;
    pub const TOFF_MIN: Register = Register::FnSlpDec;
}

/// Everything the bridge knows about one register.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RegisterInfo {
    pub register: Register,
    /// Address, `0x01..=0x1B`.
    pub address: u8,
    /// Number of significant bits (values are right-aligned).
    pub bits: u8,
    /// Number of value bytes after the SetParam/GetParam command byte.
    pub bytes: u8,
    pub access: Access,
    pub voltage_mode_name: &'static str,
    /// `None` where the register only exists in voltage mode.
    pub current_mode_name: Option<&'static str>,
    /// Power-up value (datasheet; the current-mode registers share their
    /// storage with the voltage-mode ones, so they reset to the same values).
    pub reset: u32,
}

const fn reg(
    register: Register,
    bits: u8,
    bytes: u8,
    access: Access,
    voltage_mode_name: &'static str,
    current_mode_name: Option<&'static str>,
    reset: u32,
) -> RegisterInfo {
    RegisterInfo {
        register,
        address: register as u8,
        bits,
        bytes,
        access,
        voltage_mode_name,
        current_mode_name,
        reset,
    }
}

use Access::{Always, ReadOnly, WhenHiZ, WhenStopped};

/// The 27 registers, in address order (`REGISTERS[i].address == i + 1`).
pub const REGISTERS: [RegisterInfo; 27] = [
    reg(
        Register::AbsPos,
        22,
        3,
        WhenStopped,
        "ABS_POS",
        Some("ABS_POS"),
        0,
    ),
    reg(Register::ElPos, 9, 2, WhenHiZ, "EL_POS", Some("EL_POS"), 0),
    reg(Register::Mark, 22, 3, Always, "MARK", Some("MARK"), 0),
    reg(Register::Speed, 20, 3, ReadOnly, "SPEED", Some("SPEED"), 0),
    reg(Register::Acc, 12, 2, WhenStopped, "ACC", Some("ACC"), 0x08A),
    reg(Register::Dec, 12, 2, WhenStopped, "DEC", Some("DEC"), 0x08A),
    reg(
        Register::MaxSpeed,
        10,
        2,
        Always,
        "MAX_SPEED",
        Some("MAX_SPEED"),
        0x041,
    ),
    reg(
        Register::MinSpeed,
        13,
        2,
        WhenStopped,
        "MIN_SPEED",
        Some("MIN_SPEED"),
        0,
    ),
    reg(
        Register::KvalHold,
        8,
        1,
        Always,
        "KVAL_HOLD",
        Some("TVAL_HOLD"),
        0x29,
    ),
    reg(
        Register::KvalRun,
        8,
        1,
        Always,
        "KVAL_RUN",
        Some("TVAL_RUN"),
        0x29,
    ),
    reg(
        Register::KvalAcc,
        8,
        1,
        Always,
        "KVAL_ACC",
        Some("TVAL_ACC"),
        0x29,
    ),
    reg(
        Register::KvalDec,
        8,
        1,
        Always,
        "KVAL_DEC",
        Some("TVAL_DEC"),
        0x29,
    ),
    reg(
        Register::IntSpeed,
        14,
        2,
        WhenHiZ,
        "INT_SPEED",
        None,
        0x0408,
    ),
    reg(
        Register::StSlp,
        8,
        1,
        WhenHiZ,
        "ST_SLP",
        Some("T_FAST"),
        0x19,
    ),
    reg(
        Register::FnSlpAcc,
        8,
        1,
        WhenHiZ,
        "FN_SLP_ACC",
        Some("TON_MIN"),
        0x29,
    ),
    reg(
        Register::FnSlpDec,
        8,
        1,
        WhenHiZ,
        "FN_SLP_DEC",
        Some("TOFF_MIN"),
        0x29,
    ),
    reg(Register::KTherm, 4, 1, Always, "K_THERM", None, 0x0),
    reg(
        Register::AdcOut,
        5,
        1,
        ReadOnly,
        "ADC_OUT",
        Some("ADC_OUT"),
        0,
    ),
    reg(
        Register::OcdTh,
        5,
        1,
        Always,
        "OCD_TH",
        Some("OCD_TH"),
        0x08,
    ),
    reg(Register::StallTh, 5, 1, Always, "STALL_TH", None, 0x10),
    reg(
        Register::FsSpd,
        11,
        2,
        Always,
        "FS_SPD",
        Some("FS_SPD"),
        0x027,
    ),
    reg(
        Register::StepMode,
        8,
        1,
        WhenHiZ,
        "STEP_MODE",
        Some("STEP_MODE"),
        0x07,
    ),
    reg(
        Register::AlarmEn,
        8,
        1,
        WhenStopped,
        "ALARM_EN",
        Some("ALARM_EN"),
        0xFF,
    ),
    reg(
        Register::GateCfg1,
        12,
        2,
        WhenHiZ,
        "GATECFG1",
        Some("GATECFG1"),
        0x000,
    ),
    reg(
        Register::GateCfg2,
        8,
        1,
        WhenHiZ,
        "GATECFG2",
        Some("GATECFG2"),
        0x00,
    ),
    reg(
        Register::Config,
        16,
        2,
        WhenHiZ,
        "CONFIG",
        Some("CONFIG"),
        0x2C88,
    ),
    reg(
        Register::Status,
        16,
        2,
        ReadOnly,
        "STATUS",
        Some("STATUS"),
        0,
    ),
];

impl Register {
    /// All registers in address order.
    pub fn all() -> impl Iterator<Item = Register> {
        REGISTERS.iter().map(|r| r.register)
    }

    /// The register at `address`, if one exists (5-bit command field).
    // Indexed only after the range check on the line before.
    #[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
    pub const fn from_address(address: u8) -> Option<Register> {
        // `address` comes from a command byte: never index with it unchecked.
        if address == 0 || address as usize > REGISTERS.len() {
            return None;
        }
        Some(REGISTERS[address as usize - 1].register)
    }

    /// The table entry. Discriminants are 1..=27, so the index cannot fail.
    // (`table_is_in_address_order` pins the layout.)
    #[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
    pub const fn info(self) -> &'static RegisterInfo {
        &REGISTERS[self as usize - 1]
    }

    pub const fn address(self) -> u8 {
        self as u8
    }

    /// Value bytes after a SetParam/GetParam command byte.
    pub const fn bytes(self) -> u8 {
        self.info().bytes
    }

    pub const fn bits(self) -> u8 {
        self.info().bits
    }

    /// Mask of the significant bits.
    pub const fn mask(self) -> u32 {
        // bits() is 1..=22 for every register.
        (1u32 << self.bits()).wrapping_sub(1)
    }

    pub const fn access(self) -> Access {
        self.info().access
    }
}

/// Sign-extend a 22-bit two's-complement ABS_POS/MARK value.
pub const fn sign_extend_22(raw: u32) -> i32 {
    ((raw << 10) as i32) >> 10
}

/// Wrap a position into the 22-bit two's-complement register format.
pub const fn wrap_22(pos: i32) -> u32 {
    (pos as u32) & 0x3F_FFFF
}

#[cfg(test)]
mod tests {
    use super::*;

    /// (address, voltage name, current name, bits, SPI bytes, reset, access)
    /// copied from `reference/powerstep01-facts.md` §1, one row per register.
    #[allow(clippy::type_complexity)]
    const FACTS: [(u8, &str, Option<&str>, u8, u8, u32, Access); 27] = [
        (
            0x01,
            "ABS_POS",
            Some("ABS_POS"),
            22,
            3,
            0x000000,
            WhenStopped,
        ),
        // EL_POS: datasheet says WS, AN4290 table 4 says HiZ only: we take WH.
        (0x02, "EL_POS", Some("EL_POS"), 9, 2, 0x000, WhenHiZ),
        (0x03, "MARK", Some("MARK"), 22, 3, 0x000000, Always),
        (0x04, "SPEED", Some("SPEED"), 20, 3, 0x00000, ReadOnly),
        (0x05, "ACC", Some("ACC"), 12, 2, 0x08A, WhenStopped),
        (0x06, "DEC", Some("DEC"), 12, 2, 0x08A, WhenStopped),
        (0x07, "MAX_SPEED", Some("MAX_SPEED"), 10, 2, 0x041, Always),
        (
            0x08,
            "MIN_SPEED",
            Some("MIN_SPEED"),
            13,
            2,
            0x000,
            WhenStopped,
        ),
        (0x09, "KVAL_HOLD", Some("TVAL_HOLD"), 8, 1, 0x29, Always),
        (0x0A, "KVAL_RUN", Some("TVAL_RUN"), 8, 1, 0x29, Always),
        (0x0B, "KVAL_ACC", Some("TVAL_ACC"), 8, 1, 0x29, Always),
        (0x0C, "KVAL_DEC", Some("TVAL_DEC"), 8, 1, 0x29, Always),
        (0x0D, "INT_SPEED", None, 14, 2, 0x0408, WhenHiZ),
        (0x0E, "ST_SLP", Some("T_FAST"), 8, 1, 0x19, WhenHiZ),
        (0x0F, "FN_SLP_ACC", Some("TON_MIN"), 8, 1, 0x29, WhenHiZ),
        (0x10, "FN_SLP_DEC", Some("TOFF_MIN"), 8, 1, 0x29, WhenHiZ),
        (0x11, "K_THERM", None, 4, 1, 0x0, Always),
        (0x12, "ADC_OUT", Some("ADC_OUT"), 5, 1, 0, ReadOnly),
        (0x13, "OCD_TH", Some("OCD_TH"), 5, 1, 0x08, Always),
        (0x14, "STALL_TH", None, 5, 1, 0x10, Always),
        (0x15, "FS_SPD", Some("FS_SPD"), 11, 2, 0x027, Always),
        (0x16, "STEP_MODE", Some("STEP_MODE"), 8, 1, 0x07, WhenHiZ),
        (0x17, "ALARM_EN", Some("ALARM_EN"), 8, 1, 0xFF, WhenStopped),
        (0x18, "GATECFG1", Some("GATECFG1"), 12, 2, 0x000, WhenHiZ),
        (0x19, "GATECFG2", Some("GATECFG2"), 8, 1, 0x00, WhenHiZ),
        (0x1A, "CONFIG", Some("CONFIG"), 16, 2, 0x2C88, WhenHiZ),
        (0x1B, "STATUS", Some("STATUS"), 16, 2, 0, ReadOnly),
    ];

    fn check(address: u8) {
        let (addr, vname, cname, bits, bytes, reset, access) = FACTS[address as usize - 1];
        let info = Register::from_address(addr)
            .expect("register exists")
            .info();
        assert_eq!(info.address, addr);
        assert_eq!(info.register.address(), addr);
        assert_eq!(info.voltage_mode_name, vname);
        assert_eq!(info.current_mode_name, cname);
        assert_eq!(info.bits, bits, "{vname} bits");
        assert_eq!(info.bytes, bytes, "{vname} SPI bytes");
        assert_eq!(info.reset, reset, "{vname} reset");
        assert_eq!(info.access, access, "{vname} access");
        assert!(
            u32::from(info.bits) <= u32::from(info.bytes) * 8,
            "{vname} fits its bytes"
        );
        assert_eq!(
            info.reset & !info.register.mask(),
            0,
            "{vname} reset fits its bits"
        );
    }

    #[test]
    fn abs_pos_entry_matches_facts() {
        check(0x01)
    }
    #[test]
    fn el_pos_entry_matches_facts_with_an4290_access() {
        check(0x02)
    }
    #[test]
    fn mark_entry_matches_facts() {
        check(0x03)
    }
    #[test]
    fn speed_entry_matches_facts() {
        check(0x04)
    }
    #[test]
    fn acc_entry_matches_facts() {
        check(0x05)
    }
    #[test]
    fn dec_entry_matches_facts() {
        check(0x06)
    }
    #[test]
    fn max_speed_entry_matches_facts() {
        check(0x07)
    }
    #[test]
    fn min_speed_entry_matches_facts() {
        check(0x08)
    }
    #[test]
    fn kval_hold_entry_matches_facts() {
        check(0x09)
    }
    #[test]
    fn kval_run_entry_matches_facts() {
        check(0x0A)
    }
    #[test]
    fn kval_acc_entry_matches_facts() {
        check(0x0B)
    }
    #[test]
    fn kval_dec_entry_matches_facts() {
        check(0x0C)
    }
    #[test]
    fn int_speed_entry_matches_facts() {
        check(0x0D)
    }
    #[test]
    fn st_slp_entry_matches_facts() {
        check(0x0E)
    }
    #[test]
    fn fn_slp_acc_entry_matches_facts() {
        check(0x0F)
    }
    #[test]
    fn fn_slp_dec_entry_matches_facts() {
        check(0x10)
    }
    #[test]
    fn k_therm_entry_matches_facts() {
        check(0x11)
    }
    #[test]
    fn adc_out_entry_matches_facts() {
        check(0x12)
    }
    #[test]
    fn ocd_th_entry_matches_facts() {
        check(0x13)
    }
    #[test]
    fn stall_th_entry_matches_facts() {
        check(0x14)
    }
    #[test]
    fn fs_spd_entry_matches_facts() {
        check(0x15)
    }
    #[test]
    fn step_mode_entry_matches_facts() {
        check(0x16)
    }
    #[test]
    fn alarm_en_entry_matches_facts() {
        check(0x17)
    }
    #[test]
    fn gatecfg1_entry_matches_facts() {
        check(0x18)
    }
    #[test]
    fn gatecfg2_entry_matches_facts() {
        check(0x19)
    }
    #[test]
    fn config_entry_matches_facts() {
        check(0x1A)
    }
    #[test]
    fn status_entry_matches_facts() {
        check(0x1B)
    }

    #[test]
    fn table_is_in_address_order() {
        for (i, info) in REGISTERS.iter().enumerate() {
            assert_eq!(usize::from(info.address), i + 1);
        }
    }

    #[test]
    fn addresses_outside_the_map_are_not_registers() {
        assert_eq!(Register::from_address(0), None);
        for a in 0x1C..=0xFF {
            assert_eq!(Register::from_address(a), None);
        }
    }

    #[test]
    fn current_mode_aliases_share_addresses() {
        assert_eq!(Register::TVAL_HOLD.address(), 0x09);
        assert_eq!(Register::TVAL_RUN.address(), 0x0A);
        assert_eq!(Register::TVAL_ACC.address(), 0x0B);
        assert_eq!(Register::TVAL_DEC.address(), 0x0C);
        assert_eq!(Register::T_FAST.address(), 0x0E);
        assert_eq!(Register::TON_MIN.address(), 0x0F);
        assert_eq!(Register::TOFF_MIN.address(), 0x10);
    }

    #[test]
    fn position_sign_extension_round_trips_22_bits() {
        assert_eq!(sign_extend_22(0x1F_FFFF), 2_097_151);
        assert_eq!(sign_extend_22(0x20_0000), -2_097_152);
        assert_eq!(sign_extend_22(0x3F_FFFF), -1);
        assert_eq!(wrap_22(-1), 0x3F_FFFF);
        assert_eq!(wrap_22(2_097_152), 0x20_0000);
        for p in [-2_097_152, -1, 0, 1, 12345, 2_097_151] {
            assert_eq!(sign_extend_22(wrap_22(p)), p);
        }
    }
}
