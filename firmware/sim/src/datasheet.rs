//! The powerSTEP01's tables as the model states them, written from the
//! datasheet (DS: powerSTEP01 DocID025022, and where the powerSTEP01's own
//! pages were not available the L6470/L6480 pages of the same logic core)
//! and ST's protocol note AN4290 — not from the driver crate. Where the two
//! disagree the model takes the reading under which the chip refuses more,
//! and says so on the row.
//!
//! * [`OPCODES`] — every command byte: its fixed bits, the bits that carry a
//!   parameter (DIR, ACT, register address), argument and response lengths.
//! * [`REGISTERS`] — every register: address, names, width, SPI byte count,
//!   reset value, when it may be written.
//! * [`status`] — the STATUS bit layout; [`config`] — the CONFIG bits the
//!   model acts on.
//! * [`command_byte`], [`decode`] and [`encode`] — the model's own codec over
//!   these tables. [`decode`] and [`encode`] speak the driver crate's
//!   [`Command`] type as a vocabulary only (see [`crate::vocab`]).

use powerstep01::{Command, Direction, MotorStatus, SwitchAction, ThermalStatus};

use crate::vocab;

// ------------------------------------------------------------ commands ----

/// The 19 application commands (DS command table; AN4290 §1 Table 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Op {
    Nop,
    SetParam,
    GetParam,
    Run,
    StepClock,
    Move,
    GoTo,
    GoToDir,
    GoUntil,
    ReleaseSw,
    GoHome,
    GoMark,
    ResetPos,
    ResetDevice,
    SoftStop,
    HardStop,
    SoftHiZ,
    HardHiZ,
    GetStatus,
}

/// Bits of a command byte that carry a parameter instead of the opcode.
pub mod field {
    /// DIR, bit 0: 1 = forward, 0 = reverse (DS command table).
    pub const DIR: u8 = 0x01;
    /// ACT, bit 3 of GoUntil/ReleaseSW: 0 = reset ABS_POS, 1 = copy ABS_POS
    /// to MARK (DS GoUntil/ReleaseSW description).
    pub const ACT: u8 = 0x08;
    /// The register address, bits 4:0 of SetParam/GetParam (AN4290 §1
    /// Tables 2 and 3).
    pub const PARAM: u8 = 0x1F;
}

/// How many bytes follow a command byte, or come back after it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Length {
    Fixed(u8),
    /// The addressed register's byte count ([`RegisterSpec::bytes`]).
    OfRegister,
}

/// One row of the command table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OpcodeSpec {
    pub op: Op,
    /// The datasheet's name.
    pub name: &'static str,
    /// The command byte with every parameter bit 0.
    pub code: u8,
    /// The parameter bits ([`field`]); a byte is this command when
    /// `byte & !fields == code`.
    pub fields: u8,
    /// Argument bytes after the command byte (AN4290 §1 Table 1).
    pub args: Length,
    /// Response bytes in the following windows (AN4290 §1 Table 1).
    pub response: Length,
    /// Significant bits of the argument value (0: no argument value).
    pub value_bits: u8,
}

const fn op(
    op: Op,
    name: &'static str,
    code: u8,
    fields: u8,
    args: Length,
    response: Length,
    value_bits: u8,
) -> OpcodeSpec {
    OpcodeSpec {
        op,
        name,
        code,
        fields,
        args,
        response,
        value_bits,
    }
}

use field::{ACT, DIR, PARAM};
use Length::{Fixed, OfRegister};

/// Every command, in the datasheet's order. Binary encodings from the DS
/// command table (the same in the L6470 DS's Table 37 for the shared logic
/// core), lengths from AN4290 §1 Table 1.
///
/// GetStatus is 1101 0000 = 0xD0. AN4290's Table 5 prints 1011 0000 for it,
/// which is SoftStop's encoding: an error in the note (the datasheet's
/// command table and ST's own driver both say 0xD0).
///
/// NOP comes first: 0x00 is also "SetParam of address 0", and there is no
/// register 0, so the byte is NOP.
pub const OPCODES: [OpcodeSpec; 19] = [
    op(Op::Nop, "NOP", 0x00, 0, Fixed(0), Fixed(0), 0),
    // 000P PPPP
    op(
        Op::SetParam,
        "SetParam",
        0x00,
        PARAM,
        OfRegister,
        Fixed(0),
        0,
    ),
    // 001P PPPP
    op(
        Op::GetParam,
        "GetParam",
        0x20,
        PARAM,
        Fixed(0),
        OfRegister,
        0,
    ),
    // 0101 000D + SPD (20 bit)
    op(Op::Run, "Run", 0x50, DIR, Fixed(3), Fixed(0), 20),
    // 0101 100D
    op(Op::StepClock, "StepClock", 0x58, DIR, Fixed(0), Fixed(0), 0),
    // 0100 000D + N_STEP (22 bit)
    op(Op::Move, "Move", 0x40, DIR, Fixed(3), Fixed(0), 22),
    // 0110 0000 + ABS_POS (22 bit)
    op(Op::GoTo, "GoTo", 0x60, 0, Fixed(3), Fixed(0), 22),
    // 0110 100D + ABS_POS (22 bit)
    op(Op::GoToDir, "GoTo_DIR", 0x68, DIR, Fixed(3), Fixed(0), 22),
    // 1000 A01D + SPD (20 bit)
    op(
        Op::GoUntil,
        "GoUntil",
        0x82,
        ACT | DIR,
        Fixed(3),
        Fixed(0),
        20,
    ),
    // 1001 A01D
    op(
        Op::ReleaseSw,
        "ReleaseSW",
        0x92,
        ACT | DIR,
        Fixed(0),
        Fixed(0),
        0,
    ),
    // 0111 0000
    op(Op::GoHome, "GoHome", 0x70, 0, Fixed(0), Fixed(0), 0),
    // 0111 1000
    op(Op::GoMark, "GoMark", 0x78, 0, Fixed(0), Fixed(0), 0),
    // 1101 1000
    op(Op::ResetPos, "ResetPos", 0xD8, 0, Fixed(0), Fixed(0), 0),
    // 1100 0000
    op(
        Op::ResetDevice,
        "ResetDevice",
        0xC0,
        0,
        Fixed(0),
        Fixed(0),
        0,
    ),
    // 1011 0000
    op(Op::SoftStop, "SoftStop", 0xB0, 0, Fixed(0), Fixed(0), 0),
    // 1011 1000
    op(Op::HardStop, "HardStop", 0xB8, 0, Fixed(0), Fixed(0), 0),
    // 1010 0000
    op(Op::SoftHiZ, "SoftHiZ", 0xA0, 0, Fixed(0), Fixed(0), 0),
    // 1010 1000
    op(Op::HardHiZ, "HardHiZ", 0xA8, 0, Fixed(0), Fixed(0), 0),
    // 1101 0000, STATUS MSB then LSB
    op(Op::GetStatus, "GetStatus", 0xD0, 0, Fixed(0), Fixed(2), 0),
];

/// The command table's row for `byte` (the first whose fixed bits match),
/// `None` for a byte that is no command (e.g. the reserved 0xEB and 0xF8).
pub fn opcode(byte: u8) -> Option<&'static OpcodeSpec> {
    OPCODES.iter().find(|o| byte & !o.fields == o.code)
}

/// The row of `op`.
pub fn opcode_of(op: Op) -> &'static OpcodeSpec {
    // OPCODES has one row per Op (a test holds it); NOP's row otherwise.
    OPCODES.iter().find(|o| o.op == op).unwrap_or(&OPCODES[0])
}

/// What the chip does with a byte received as a command byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// A command that waits for this many argument bytes (0..=3).
    Takes(u8),
    /// Refused at once with CMD_ERROR, no argument bytes consumed: an
    /// unknown byte (DS command management), a SetParam of a read-only or
    /// non-existent register (AN4290 §1, Figure 3), a GetParam of a
    /// non-existent register (DS: treated as an unknown command).
    Refused,
}

/// Classify a command byte by the tables.
pub fn command_byte(byte: u8) -> Verdict {
    let Some(o) = opcode(byte) else {
        return Verdict::Refused;
    };
    match o.op {
        Op::SetParam => match register(byte & PARAM) {
            Some(r) if r.access != Access::ReadOnly => Verdict::Takes(r.bytes),
            _ => Verdict::Refused,
        },
        Op::GetParam => match register(byte & PARAM) {
            Some(_) => Verdict::Takes(0),
            None => Verdict::Refused,
        },
        _ => match o.args {
            Fixed(n) => Verdict::Takes(n),
            OfRegister => Verdict::Refused,
        },
    }
}

/// Response bytes that the command byte `byte` loads (0 for a refused byte).
pub fn response_len(byte: u8) -> u8 {
    match (command_byte(byte), opcode(byte)) {
        (Verdict::Takes(_), Some(o)) => match o.response {
            Fixed(n) => n,
            OfRegister => register(byte & PARAM).map_or(0, |r| r.bytes),
        },
        _ => 0,
    }
}

fn direction(byte: u8) -> Direction {
    if byte & DIR != 0 {
        Direction::Forward
    } else {
        Direction::Reverse
    }
}

fn dir_bit(d: Direction) -> u8 {
    match d {
        Direction::Forward => DIR,
        Direction::Reverse => 0,
    }
}

fn action(byte: u8) -> SwitchAction {
    if byte & ACT != 0 {
        SwitchAction::CopyToMark
    } else {
        SwitchAction::ResetAbsPos
    }
}

fn act_bit(a: SwitchAction) -> u8 {
    match a {
        SwitchAction::ResetAbsPos => 0,
        SwitchAction::CopyToMark => ACT,
    }
}

const fn bits_mask(bits: u8) -> u32 {
    if bits >= 32 {
        u32::MAX
    } else {
        (1u32 << bits).wrapping_sub(1)
    }
}

/// Sign-extend a 22-bit two's-complement position (ABS_POS, MARK, GoTo).
pub const fn sign_extend_22(raw: u32) -> i32 {
    ((raw << 10) as i32) >> 10
}

/// A position in the 22-bit two's-complement register format.
pub const fn wrap_22(pos: i32) -> u32 {
    (pos as u32) & bits_mask(22)
}

/// One complete command as the chip receives it (command byte, then exactly
/// its argument bytes, MSB first), in the driver crate's vocabulary.
/// `None` for a refused command byte or a wrong number of argument bytes.
pub fn decode(frame: &[u8]) -> Option<Command> {
    let (&byte, args) = frame.split_first()?;
    let Verdict::Takes(n) = command_byte(byte) else {
        return None;
    };
    if args.len() != usize::from(n) {
        return None;
    }
    let o = opcode(byte)?;
    let value =
        args.iter().fold(0u32, |acc, b| (acc << 8) | u32::from(*b)) & bits_mask(o.value_bits);
    let dir = direction(byte);
    Some(match o.op {
        Op::Nop => Command::Nop,
        Op::SetParam => {
            let spec = register(byte & PARAM)?;
            let all = args.iter().fold(0u32, |acc, b| (acc << 8) | u32::from(*b));
            Command::SetParam(vocab::register(spec.address)?, all & spec.mask())
        }
        Op::GetParam => Command::GetParam(vocab::register(byte & PARAM)?),
        Op::Run => Command::Run(dir, value),
        Op::StepClock => Command::StepClock(dir),
        Op::Move => Command::Move(dir, value),
        Op::GoTo => Command::GoTo(sign_extend_22(value)),
        Op::GoToDir => Command::GoToDir(dir, sign_extend_22(value)),
        Op::GoUntil => Command::GoUntil(action(byte), dir, value),
        Op::ReleaseSw => Command::ReleaseSw(action(byte), dir),
        Op::GoHome => Command::GoHome,
        Op::GoMark => Command::GoMark,
        Op::ResetPos => Command::ResetPos,
        Op::ResetDevice => Command::ResetDevice,
        Op::SoftStop => Command::SoftStop,
        Op::HardStop => Command::HardStop,
        Op::SoftHiZ => Command::SoftHiZ,
        Op::HardHiZ => Command::HardHiZ,
        Op::GetStatus => Command::GetStatus,
    })
}

/// The bytes of one command on the wire (1..=4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame {
    bytes: [u8; 4],
    len: usize,
}

impl Frame {
    pub fn as_slice(&self) -> &[u8] {
        self.bytes.get(..self.len).unwrap_or(&[])
    }
}

/// The bytes that send `cmd` to the chip, by the model's tables: the
/// command byte, then the argument right-aligned in the argument bytes, MSB
/// first. Argument values follow the vocabulary type's documented meaning:
/// speeds and step counts saturate at their width, positions wrap to 22
/// bits, SetParam values are masked to the register's width.
pub fn encode(cmd: &Command) -> Frame {
    let (byte, value, n) = match *cmd {
        Command::SetParam(r, v) => {
            let a = vocab::address(r);
            match register(a) {
                Some(spec) => (
                    opcode_of(Op::SetParam).code | a,
                    v & spec.mask(),
                    spec.bytes,
                ),
                None => (opcode_of(Op::SetParam).code | a, 0, 0),
            }
        }
        Command::GetParam(r) => (opcode_of(Op::GetParam).code | vocab::address(r), 0, 0),
        Command::Run(d, spd) => with_value(Op::Run, dir_bit(d), spd),
        Command::StepClock(d) => with_value(Op::StepClock, dir_bit(d), 0),
        Command::Move(d, n) => with_value(Op::Move, dir_bit(d), n),
        Command::GoTo(p) => (opcode_of(Op::GoTo).code, wrap_22(p), 3),
        Command::GoToDir(d, p) => (opcode_of(Op::GoToDir).code | dir_bit(d), wrap_22(p), 3),
        Command::GoUntil(a, d, spd) => with_value(Op::GoUntil, act_bit(a) | dir_bit(d), spd),
        Command::ReleaseSw(a, d) => with_value(Op::ReleaseSw, act_bit(a) | dir_bit(d), 0),
        Command::Nop => with_value(Op::Nop, 0, 0),
        Command::GoHome => with_value(Op::GoHome, 0, 0),
        Command::GoMark => with_value(Op::GoMark, 0, 0),
        Command::ResetPos => with_value(Op::ResetPos, 0, 0),
        Command::ResetDevice => with_value(Op::ResetDevice, 0, 0),
        Command::SoftStop => with_value(Op::SoftStop, 0, 0),
        Command::HardStop => with_value(Op::HardStop, 0, 0),
        Command::SoftHiZ => with_value(Op::SoftHiZ, 0, 0),
        Command::HardHiZ => with_value(Op::HardHiZ, 0, 0),
        Command::GetStatus => with_value(Op::GetStatus, 0, 0),
    };
    let be = value.to_be_bytes();
    let n = usize::from(n.min(3));
    let mut bytes = [byte, 0, 0, 0];
    for (dst, src) in bytes
        .iter_mut()
        .skip(1)
        .zip(be.iter().skip(4usize.saturating_sub(n)))
    {
        *dst = *src;
    }
    Frame { bytes, len: 1 + n }
}

/// Command byte, saturated value and argument count of a fixed-length command.
fn with_value(op: Op, params: u8, value: u32) -> (u8, u32, u8) {
    let o = opcode_of(op);
    let n = match o.args {
        Fixed(n) => n,
        OfRegister => 0,
    };
    (o.code | params, value.min(bits_mask(o.value_bits)), n)
}

// ----------------------------------------------------------- registers ----

/// When a register may be written (DS register map, access column; AN4290
/// §1 Table 4 notes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Access {
    /// R: SetParam refused at the command byte (AN4290 §1, Figure 3).
    ReadOnly,
    /// WR: writable at any time.
    Always,
    /// WS: writable only while the motor is stopped; otherwise refused after
    /// the last argument byte (AN4290 §1, Figure 4).
    WhenStopped,
    /// WH: writable only while the bridges are in high impedance; otherwise
    /// refused after the last argument byte.
    WhenHiZ,
}

/// One row of the register table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RegisterSpec {
    /// 0x01..=0x1B (the 5-bit PARAM field).
    pub address: u8,
    /// Voltage-mode name.
    pub name: &'static str,
    /// Current-mode name (same storage); `None` where only voltage mode has it.
    pub current_mode_name: Option<&'static str>,
    /// Significant bits, right-aligned; the rest of a written value is ignored.
    pub bits: u8,
    /// Value bytes after SetParam/GetParam (AN4290 §1 Table 4).
    pub bytes: u8,
    /// Power-up value.
    pub reset: u32,
    pub access: Access,
}

impl RegisterSpec {
    /// Mask of the significant bits.
    pub const fn mask(&self) -> u32 {
        bits_mask(self.bits)
    }
}

/// Register addresses.
pub mod addr {
    pub const ABS_POS: u8 = 0x01;
    pub const EL_POS: u8 = 0x02;
    pub const MARK: u8 = 0x03;
    pub const SPEED: u8 = 0x04;
    pub const ACC: u8 = 0x05;
    pub const DEC: u8 = 0x06;
    pub const MAX_SPEED: u8 = 0x07;
    pub const MIN_SPEED: u8 = 0x08;
    pub const KVAL_HOLD: u8 = 0x09;
    pub const KVAL_RUN: u8 = 0x0A;
    pub const KVAL_ACC: u8 = 0x0B;
    pub const KVAL_DEC: u8 = 0x0C;
    pub const INT_SPEED: u8 = 0x0D;
    pub const ST_SLP: u8 = 0x0E;
    pub const FN_SLP_ACC: u8 = 0x0F;
    pub const FN_SLP_DEC: u8 = 0x10;
    pub const K_THERM: u8 = 0x11;
    pub const ADC_OUT: u8 = 0x12;
    pub const OCD_TH: u8 = 0x13;
    pub const STALL_TH: u8 = 0x14;
    pub const FS_SPD: u8 = 0x15;
    pub const STEP_MODE: u8 = 0x16;
    pub const ALARM_EN: u8 = 0x17;
    pub const GATECFG1: u8 = 0x18;
    pub const GATECFG2: u8 = 0x19;
    pub const CONFIG: u8 = 0x1A;
    pub const STATUS: u8 = 0x1B;
}

const fn reg(
    address: u8,
    name: &'static str,
    current_mode_name: Option<&'static str>,
    bits: u8,
    bytes: u8,
    reset: u32,
    access: Access,
) -> RegisterSpec {
    RegisterSpec {
        address,
        name,
        current_mode_name,
        bits,
        bytes,
        reset,
        access,
    }
}

use Access::{Always, ReadOnly, WhenHiZ, WhenStopped};

/// The 27 registers in address order (`REGISTERS[i].address == i + 1`).
///
/// Addresses, widths and reset values from the DS register map (p.54 for
/// EL_POS, MARK, SPEED, ACC); byte counts from AN4290 §1 Table 4 (a 12-bit
/// register takes 2 bytes, a 4-bit one 1). Access: the DS register map's
/// access column and AN4290 Table 4's notes, the stricter where they differ.
/// The current-mode registers (TVAL_*, T_FAST, TON_MIN, TOFF_MIN) are the
/// same storage as the voltage-mode ones at their address; their 7-bit
/// current-mode values fit the 8-bit width.
#[rustfmt::skip]
pub const REGISTERS: [RegisterSpec; 27] = [
    // DS: WS. AN4290 Table 4 has no restriction: WS is the stricter.
    reg(addr::ABS_POS, "ABS_POS", Some("ABS_POS"), 22, 3, 0x00_0000, WhenStopped),
    // DS: WS. AN4290 Table 4: "writable when in HiZ only". WH is the
    // stricter (the bridges are only in HiZ with the motor stopped).
    reg(addr::EL_POS, "EL_POS", Some("EL_POS"), 9, 2, 0x000, WhenHiZ),
    reg(addr::MARK, "MARK", Some("MARK"), 22, 3, 0x00_0000, Always),
    reg(addr::SPEED, "SPEED", Some("SPEED"), 20, 3, 0x0_0000, ReadOnly),
    reg(addr::ACC, "ACC", Some("ACC"), 12, 2, 0x08A, WhenStopped),
    reg(addr::DEC, "DEC", Some("DEC"), 12, 2, 0x08A, WhenStopped),
    reg(addr::MAX_SPEED, "MAX_SPEED", Some("MAX_SPEED"), 10, 2, 0x041, Always),
    // 12-bit MIN_SPEED plus LSPD_OPT in bit 12.
    reg(addr::MIN_SPEED, "MIN_SPEED", Some("MIN_SPEED"), 13, 2, 0x000, WhenStopped),
    reg(addr::KVAL_HOLD, "KVAL_HOLD", Some("TVAL_HOLD"), 8, 1, 0x29, Always),
    reg(addr::KVAL_RUN, "KVAL_RUN", Some("TVAL_RUN"), 8, 1, 0x29, Always),
    reg(addr::KVAL_ACC, "KVAL_ACC", Some("TVAL_ACC"), 8, 1, 0x29, Always),
    reg(addr::KVAL_DEC, "KVAL_DEC", Some("TVAL_DEC"), 8, 1, 0x29, Always),
    reg(addr::INT_SPEED, "INT_SPEED", None, 14, 2, 0x0408, WhenHiZ),
    reg(addr::ST_SLP, "ST_SLP", Some("T_FAST"), 8, 1, 0x19, WhenHiZ),
    reg(addr::FN_SLP_ACC, "FN_SLP_ACC", Some("TON_MIN"), 8, 1, 0x29, WhenHiZ),
    reg(addr::FN_SLP_DEC, "FN_SLP_DEC", Some("TOFF_MIN"), 8, 1, 0x29, WhenHiZ),
    reg(addr::K_THERM, "K_THERM", None, 4, 1, 0x0, Always),
    // Reset value depends on ADCIN; the model reads 0.
    reg(addr::ADC_OUT, "ADC_OUT", Some("ADC_OUT"), 5, 1, 0x00, ReadOnly),
    reg(addr::OCD_TH, "OCD_TH", Some("OCD_TH"), 5, 1, 0x08, Always),
    reg(addr::STALL_TH, "STALL_TH", None, 5, 1, 0x10, Always),
    // 10-bit FS_SPD plus BOOST_MODE in bit 10.
    reg(addr::FS_SPD, "FS_SPD", Some("FS_SPD"), 11, 2, 0x027, Always),
    reg(addr::STEP_MODE, "STEP_MODE", Some("STEP_MODE"), 8, 1, 0x07, WhenHiZ),
    reg(addr::ALARM_EN, "ALARM_EN", Some("ALARM_EN"), 8, 1, 0xFF, WhenStopped),
    // TCC, IGATE, TBOOST and WD_EN in bits 11:0.
    reg(addr::GATECFG1, "GATECFG1", Some("GATECFG1"), 12, 2, 0x000, WhenHiZ),
    reg(addr::GATECFG2, "GATECFG2", Some("GATECFG2"), 8, 1, 0x00, WhenHiZ),
    // 0x2C88: internal 16 MHz oscillator with 2 MHz on OSCOUT, SW_MODE 0,
    // OC_SD 1, VCCVAL 0, F_PWM_DEC 3, F_PWM_INT 1 (the L6470's 0x2E88
    // quoted by some libraries has bit 9 set, which the powerSTEP01 uses
    // for VCCVAL).
    reg(addr::CONFIG, "CONFIG", Some("CONFIG"), 16, 2, 0x2C88, WhenHiZ),
    // Assembled on every read (see [`status`]); no stored value.
    reg(addr::STATUS, "STATUS", Some("STATUS"), 16, 2, 0x0000, ReadOnly),
];

/// The table row at `address`, `None` where there is no register.
pub fn register(address: u8) -> Option<&'static RegisterSpec> {
    slot(address).and_then(|i| REGISTERS.get(i))
}

/// The row index of `address` (its storage slot in the model).
pub fn slot(address: u8) -> Option<usize> {
    let i = usize::from(address.checked_sub(1)?);
    REGISTERS.get(i).filter(|r| r.address == address).map(|_| i)
}

// -------------------------------------------------------------- fields ----

/// The STATUS register (0x1B) bit by bit (DS STATUS register description).
/// Polarities: BUSY, UVLO, UVLO_ADC, OCD and both STALL bits are active low
/// (1 = nothing to report); the others are active high.
pub mod status {
    /// Bridges in high impedance.
    pub const HIZ: u16 = 1 << 0;
    /// Active low: 0 while a command executes (the BUSY pin).
    pub const BUSY: u16 = 1 << 1;
    /// 1 = the SW input is closed (low).
    pub const SW_F: u16 = 1 << 2;
    /// Switch turn-on event, latched.
    pub const SW_EVN: u16 = 1 << 3;
    /// 1 = forward.
    pub const DIR: u16 = 1 << 4;
    /// MOT_STATUS, bits 6:5 ([`mot`]).
    pub const MOT_SHIFT: u32 = 5;
    pub const MOT_STATUS: u16 = 0b11 << MOT_SHIFT;
    /// The last command was unknown or could not be performed, latched.
    pub const CMD_ERROR: u16 = 1 << 7;
    /// Step-clock mode.
    pub const STCK_MOD: u16 = 1 << 8;
    /// Active low, latched: undervoltage lockout or a reset.
    pub const UVLO: u16 = 1 << 9;
    /// Active low: ADCIN undervoltage.
    pub const UVLO_ADC: u16 = 1 << 10;
    /// TH_STATUS, bits 12:11 ([`th`]).
    pub const TH_SHIFT: u32 = 11;
    pub const TH_STATUS: u16 = 0b11 << TH_SHIFT;
    /// Active low, latched: overcurrent.
    pub const OCD: u16 = 1 << 13;
    /// Active low, latched: stall on one bridge. Which bridge bits 14 and
    /// 15 belong to is disputed between sources; the model names bit 14
    /// STALL_A as ST's driver does and only ever asserts that one.
    pub const STALL_A: u16 = 1 << 14;
    /// Active low, latched: stall on the other bridge.
    pub const STALL_B: u16 = 1 << 15;
    /// The bits that read 1 when there is nothing to report.
    pub const ACTIVE_LOW: u16 = BUSY | UVLO | UVLO_ADC | OCD | STALL_A | STALL_B;

    /// MOT_STATUS codes.
    pub mod mot {
        pub const STOPPED: u16 = 0b00;
        pub const ACCELERATING: u16 = 0b01;
        pub const DECELERATING: u16 = 0b10;
        pub const CONSTANT_SPEED: u16 = 0b11;
    }

    /// TH_STATUS codes.
    pub mod th {
        pub const NORMAL: u8 = 0b00;
        pub const WARNING: u8 = 0b01;
        pub const BRIDGE_SHUTDOWN: u8 = 0b10;
        pub const DEVICE_SHUTDOWN: u8 = 0b11;
    }
}

/// CONFIG (0x1A) bits the model acts on (DS CONFIG register description).
pub mod config {
    /// SW_MODE, bit 4: 0 = a SW turn-on edge hard-stops the motor, 1 = the
    /// edge is only reported (SW_EVN).
    pub const SW_MODE: u32 = 1 << 4;
    /// OC_SD, bit 7: 1 = an overcurrent switches the bridges off.
    pub const OC_SD: u32 = 1 << 7;
}

/// Field masks of the speed and step registers (DS register descriptions).
pub mod fields {
    /// STEP_MODE bits 2:0, STEP_SEL: microsteps per full step = 2^STEP_SEL.
    pub const STEP_SEL: u32 = 0b111;
    /// MIN_SPEED bits 11:0 (bit 12 is LSPD_OPT).
    pub const MIN_SPEED: u32 = 0xFFF;
    /// MAX_SPEED bits 9:0.
    pub const MAX_SPEED: u32 = 0x3FF;
    /// ACC = 0xFFF: infinite acceleration (DS ACC register).
    pub const ACC_INFINITE: u32 = 0xFFF;
    /// EL_POS: 9 bits of 1/128 step.
    pub const EL_POS: u32 = 0x1FF;
}

/// A STATUS value read with the model's own layout ([`status`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct StatusWord(pub u16);

impl StatusWord {
    /// From the two response bytes (MSB first).
    pub const fn from_bytes(msb: u8, lsb: u8) -> StatusWord {
        StatusWord(u16::from_be_bytes([msb, lsb]))
    }
    pub const fn raw(self) -> u16 {
        self.0
    }
    const fn has(self, m: u16) -> bool {
        self.0 & m != 0
    }
    pub const fn hiz(self) -> bool {
        self.has(status::HIZ)
    }
    pub const fn busy(self) -> bool {
        !self.has(status::BUSY)
    }
    pub const fn switch_closed(self) -> bool {
        self.has(status::SW_F)
    }
    pub const fn switch_event(self) -> bool {
        self.has(status::SW_EVN)
    }
    pub const fn direction(self) -> Direction {
        if self.has(status::DIR) {
            Direction::Forward
        } else {
            Direction::Reverse
        }
    }
    pub const fn motor_status(self) -> MotorStatus {
        match (self.0 & status::MOT_STATUS) >> status::MOT_SHIFT {
            status::mot::STOPPED => MotorStatus::Stopped,
            status::mot::ACCELERATING => MotorStatus::Accelerating,
            status::mot::DECELERATING => MotorStatus::Decelerating,
            _ => MotorStatus::ConstantSpeed,
        }
    }
    pub const fn command_error(self) -> bool {
        self.has(status::CMD_ERROR)
    }
    pub const fn step_clock_mode(self) -> bool {
        self.has(status::STCK_MOD)
    }
    pub const fn uvlo(self) -> bool {
        !self.has(status::UVLO)
    }
    pub const fn uvlo_adc(self) -> bool {
        !self.has(status::UVLO_ADC)
    }
    pub const fn thermal(self) -> ThermalStatus {
        thermal_status(((self.0 & status::TH_STATUS) >> status::TH_SHIFT) as u8)
    }
    pub const fn overcurrent(self) -> bool {
        !self.has(status::OCD)
    }
    pub const fn stall_a(self) -> bool {
        !self.has(status::STALL_A)
    }
    pub const fn stall_b(self) -> bool {
        !self.has(status::STALL_B)
    }
    pub const fn stalled(self) -> bool {
        self.stall_a() || self.stall_b()
    }
}

/// The vocabulary name of a TH_STATUS code.
pub const fn thermal_status(code: u8) -> ThermalStatus {
    match code & 0b11 {
        status::th::NORMAL => ThermalStatus::Normal,
        status::th::WARNING => ThermalStatus::Warning,
        status::th::BRIDGE_SHUTDOWN => ThermalStatus::BridgeShutdown,
        _ => ThermalStatus::DeviceShutdown,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_op_has_exactly_one_row() {
        for (i, o) in OPCODES.iter().enumerate() {
            assert_eq!(
                OPCODES.iter().filter(|p| p.op == o.op).count(),
                1,
                "{}",
                o.name
            );
            assert_eq!(opcode_of(o.op), &OPCODES[i]);
            assert_eq!(
                o.code & o.fields,
                0,
                "{}: parameter bits in the code",
                o.name
            );
        }
    }

    #[test]
    fn no_byte_matches_two_rows_except_nop_and_set_param_of_address_0() {
        for b in 0u8..=0xFF {
            let rows: Vec<_> = OPCODES
                .iter()
                .filter(|o| b & !o.fields == o.code)
                .map(|o| o.op)
                .collect();
            if b == 0 {
                assert_eq!(rows, [Op::Nop, Op::SetParam]);
                assert_eq!(opcode(b).map(|o| o.op), Some(Op::Nop));
            } else {
                assert!(rows.len() <= 1, "{b:#04x}: {rows:?}");
            }
        }
    }

    #[test]
    fn the_command_table_has_the_datasheet_encodings() {
        let want: [(Op, u8, u8, u8); 19] = [
            (Op::Nop, 0b0000_0000, 0, 0),
            (Op::SetParam, 0b0000_0000, 0b0001_1111, 0),
            (Op::GetParam, 0b0010_0000, 0b0001_1111, 0),
            (Op::Run, 0b0101_0000, 0b1, 3),
            (Op::StepClock, 0b0101_1000, 0b1, 0),
            (Op::Move, 0b0100_0000, 0b1, 3),
            (Op::GoTo, 0b0110_0000, 0, 3),
            (Op::GoToDir, 0b0110_1000, 0b1, 3),
            (Op::GoUntil, 0b1000_0010, 0b1001, 3),
            (Op::ReleaseSw, 0b1001_0010, 0b1001, 0),
            (Op::GoHome, 0b0111_0000, 0, 0),
            (Op::GoMark, 0b0111_1000, 0, 0),
            (Op::ResetPos, 0b1101_1000, 0, 0),
            (Op::ResetDevice, 0b1100_0000, 0, 0),
            (Op::SoftStop, 0b1011_0000, 0, 0),
            (Op::HardStop, 0b1011_1000, 0, 0),
            (Op::SoftHiZ, 0b1010_0000, 0, 0),
            (Op::HardHiZ, 0b1010_1000, 0, 0),
            (Op::GetStatus, 0b1101_0000, 0, 0),
        ];
        for (op, code, fields, args) in want {
            let o = opcode_of(op);
            assert_eq!((o.code, o.fields), (code, fields), "{}", o.name);
            if op != Op::SetParam {
                assert_eq!(o.args, Fixed(args), "{}", o.name);
            }
        }
        assert_eq!(opcode_of(Op::GetStatus).response, Fixed(2));
        assert_eq!(
            opcode(0xB0).map(|o| o.op),
            Some(Op::SoftStop),
            "not GetStatus"
        );
    }

    #[test]
    fn reserved_bytes_are_no_command() {
        for b in [0xEB, 0xF8, 0xFF, 0x61, 0x80, 0xE0] {
            assert_eq!(opcode(b), None, "{b:#04x}");
            assert_eq!(command_byte(b), Verdict::Refused);
        }
    }

    #[test]
    fn the_register_table_is_in_address_order_and_self_consistent() {
        for (i, r) in REGISTERS.iter().enumerate() {
            assert_eq!(usize::from(r.address), i + 1, "{}", r.name);
            assert_eq!(slot(r.address), Some(i));
            assert!(r.bits <= r.bytes * 8, "{} fits its bytes", r.name);
            assert!(r.bits > (r.bytes - 1) * 8, "{} needs all its bytes", r.name);
            assert_eq!(r.reset & !r.mask(), 0, "{} reset fits", r.name);
        }
        assert_eq!(register(0), None);
        for a in 0x1C..=0xFF {
            assert_eq!(register(a), None);
        }
    }

    #[test]
    fn read_only_registers_are_speed_adc_out_and_status() {
        let ro: Vec<_> = REGISTERS
            .iter()
            .filter(|r| r.access == ReadOnly)
            .map(|r| r.address)
            .collect();
        assert_eq!(ro, [addr::SPEED, addr::ADC_OUT, addr::STATUS]);
    }

    #[test]
    fn every_accepted_frame_decodes_and_encodes_back_to_itself() {
        let mut accepted = 0;
        for b in 0u8..=0xFF {
            if let Verdict::Takes(n) = command_byte(b) {
                accepted += 1;
                let mut frame = vec![b];
                frame.extend((0..n).map(|i| 0x11 * (i + 1)));
                let cmd = decode(&frame).expect("decodes");
                let re = encode(&cmd);
                assert_eq!(re.as_slice()[0], b, "{b:#04x}");
                assert_eq!(re.as_slice().len(), frame.len(), "{b:#04x}");
                assert_eq!(decode(re.as_slice()), Some(cmd), "{b:#04x}");
                let short = &frame[..frame.len() - 1];
                if n > 0 {
                    assert_eq!(decode(short), None);
                }
            } else {
                assert_eq!(decode(&[b, 0, 0, 0]), None);
            }
        }
        // NOP, 24 writable SetParams, 27 GetParams, 2 Run, 2 StepClock,
        // 2 Move, GoTo, 2 GoTo_DIR, 4 GoUntil, 4 ReleaseSW and 9 more.
        assert_eq!(accepted, 1 + 24 + 27 + 2 + 2 + 2 + 1 + 2 + 4 + 4 + 9);
    }

    #[test]
    fn status_word_reads_the_forum_value_after_a_soft_stop() {
        // 0xE012: stopped, forward, bridges on, UVLO and UVLO_ADC low.
        let s = StatusWord(0xE012);
        assert!(!s.hiz() && !s.busy() && !s.command_error());
        assert_eq!(s.direction(), Direction::Forward);
        assert_eq!(s.motor_status(), MotorStatus::Stopped);
        assert!(s.uvlo() && s.uvlo_adc() && !s.overcurrent() && !s.stalled());
        assert!(StatusWord(0xE092).command_error());
    }
}
