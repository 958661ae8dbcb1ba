//! The 19 powerSTEP01 application commands (datasheet, AN4290 table 1).
//!
//! [`Command::encode`] produces the exact bytes (command byte first, argument
//! bytes MSB first); [`Command::decode`] is its inverse and is what the
//! simulator uses to parse what it receives. GetStatus is **0xD0**; 0xB0 is
//! SoftStop (`docs/PRODUCT.md`: the datasheet's command table).

use super::registers::{wrap_22, Register};

/// Motor direction as encoded in bit 0 of motion commands (1 = forward).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Direction {
    Reverse = 0,
    Forward = 1,
}

impl Direction {
    pub const fn bit(self) -> u8 {
        self as u8
    }
    pub const fn from_bit(bit: u8) -> Direction {
        if bit & 1 == 1 {
            Direction::Forward
        } else {
            Direction::Reverse
        }
    }
    /// +1 or −1.
    pub const fn sign(self) -> i32 {
        match self {
            Direction::Forward => 1,
            Direction::Reverse => -1,
        }
    }
}

/// What GoUntil/ReleaseSW do with ABS_POS on the switch event (ACT bit 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SwitchAction {
    /// ACT = 0: ABS_POS is reset to 0.
    ResetAbsPos = 0,
    /// ACT = 1: ABS_POS is copied into MARK.
    CopyToMark = 1,
}

/// Largest 20-bit speed (Run/GoUntil SPD, SPEED register).
pub const SPEED_MAX: u32 = 0xF_FFFF;
/// Largest 22-bit step count (Move N_STEP).
pub const N_STEP_MAX: u32 = 0x3F_FFFF;

/// One command, with its arguments in chip units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    Nop,
    /// Value is masked to the register's width when encoded.
    SetParam(Register, u32),
    GetParam(Register),
    /// Speed in SPEED units (0.28 step/tick); saturates at [`SPEED_MAX`].
    Run(Direction, u32),
    StepClock(Direction),
    /// Microsteps; saturates at [`N_STEP_MAX`].
    Move(Direction, u32),
    /// Absolute target, wrapped to the 22-bit ABS_POS format.
    GoTo(i32),
    GoToDir(Direction, i32),
    GoUntil(SwitchAction, Direction, u32),
    ReleaseSw(SwitchAction, Direction),
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

/// Opcodes (bits that are not arguments).
pub mod opcode {
    pub const NOP: u8 = 0x00;
    pub const SET_PARAM: u8 = 0x00;
    pub const GET_PARAM: u8 = 0x20;
    pub const RUN: u8 = 0x50;
    pub const STEP_CLOCK: u8 = 0x58;
    pub const MOVE: u8 = 0x40;
    pub const GO_TO: u8 = 0x60;
    pub const GO_TO_DIR: u8 = 0x68;
    pub const GO_UNTIL: u8 = 0x82;
    pub const RELEASE_SW: u8 = 0x92;
    pub const GO_HOME: u8 = 0x70;
    pub const GO_MARK: u8 = 0x78;
    pub const RESET_POS: u8 = 0xD8;
    pub const RESET_DEVICE: u8 = 0xC0;
    pub const SOFT_STOP: u8 = 0xB0;
    pub const HARD_STOP: u8 = 0xB8;
    pub const SOFT_HIZ: u8 = 0xA0;
    pub const HARD_HIZ: u8 = 0xA8;
    pub const GET_STATUS: u8 = 0xD0;
}

/// The bytes of one encoded command (1..=4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Encoded {
    bytes: [u8; 4],
    len: u8,
}

impl Encoded {
    #[inline]
    fn new(cmd: u8, value: u32, arg_bytes: u8) -> Encoded {
        // Right-aligned, MSB first: the last `arg_bytes` of the big-endian value.
        let b = value.to_be_bytes();
        let bytes = match arg_bytes {
            0 => [cmd, 0, 0, 0],
            1 => [cmd, b[3], 0, 0],
            2 => [cmd, b[2], b[3], 0],
            _ => [cmd, b[1], b[2], b[3]],
        };
        Encoded {
            bytes,
            len: arg_bytes.min(3).saturating_add(1),
        }
    }

    /// The bytes as a fixed array (unused tail bytes are 0) and their count.
    pub const fn raw(&self) -> ([u8; 4], usize) {
        (self.bytes, self.len as usize)
    }

    pub fn as_slice(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }

    pub const fn len(&self) -> usize {
        self.len as usize
    }

    pub const fn is_empty(&self) -> bool {
        false
    }
}

/// Why a byte sequence is not a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// The command byte is not a powerSTEP01 command (or names no register).
    UnknownCommand(u8),
    /// The register exists but cannot be written (SetParam to a read-only register).
    ReadOnlyRegister(Register),
    /// Fewer argument bytes than the command needs.
    MissingArguments { needed: u8, got: u8 },
    /// More bytes than the command takes.
    TrailingBytes,
    /// Empty input.
    Empty,
}

/// How a received command byte must be treated (the simulator's parser).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommandByte {
    /// A valid command needing this many argument bytes (0..=3).
    Takes(u8),
    /// Not a command, or a SetParam that is refused at the command byte
    /// (read-only / non-existent register): CMD_ERROR, no argument bytes.
    Invalid,
}

impl Command {
    /// Classify a command byte: how many argument bytes follow, or invalid.
    pub const fn classify(byte: u8) -> CommandByte {
        if byte == opcode::NOP {
            return CommandByte::Takes(0);
        }
        match byte & 0xE0 {
            0x00 => match Register::from_address(byte & 0x1F) {
                Some(r) => match r.access() {
                    super::registers::Access::ReadOnly => CommandByte::Invalid,
                    _ => CommandByte::Takes(r.bytes()),
                },
                None => CommandByte::Invalid,
            },
            0x20 => match Register::from_address(byte & 0x1F) {
                Some(_) => CommandByte::Takes(0),
                None => CommandByte::Invalid,
            },
            _ => match byte & 0xFE {
                opcode::RUN | opcode::MOVE | opcode::GO_TO_DIR => CommandByte::Takes(3),
                opcode::STEP_CLOCK => CommandByte::Takes(0),
                opcode::GO_TO => {
                    if byte == opcode::GO_TO {
                        CommandByte::Takes(3)
                    } else {
                        CommandByte::Invalid
                    }
                }
                0x82 | 0x8A => CommandByte::Takes(3),
                0x92 | 0x9A => CommandByte::Takes(0),
                _ => match byte {
                    opcode::GO_HOME
                    | opcode::GO_MARK
                    | opcode::RESET_POS
                    | opcode::RESET_DEVICE
                    | opcode::SOFT_STOP
                    | opcode::HARD_STOP
                    | opcode::SOFT_HIZ
                    | opcode::HARD_HIZ
                    | opcode::GET_STATUS => CommandByte::Takes(0),
                    _ => CommandByte::Invalid,
                },
            },
        }
    }

    /// Argument bytes after the command byte.
    pub const fn arg_len(&self) -> u8 {
        match self {
            Command::SetParam(r, _) => r.bytes(),
            Command::Run(..)
            | Command::Move(..)
            | Command::GoTo(_)
            | Command::GoToDir(..)
            | Command::GoUntil(..) => 3,
            _ => 0,
        }
    }

    /// Total bytes on the wire for this device (command byte + arguments).
    pub const fn wire_len(&self) -> u8 {
        self.arg_len().saturating_add(1)
    }

    /// Response bytes the device shifts out after the command byte.
    pub const fn response_len(&self) -> u8 {
        match self {
            Command::GetParam(r) => r.bytes(),
            Command::GetStatus => 2,
            _ => 0,
        }
    }

    /// True for commands that make the motor move (or may).
    pub const fn is_motion(&self) -> bool {
        matches!(
            self,
            Command::Run(..)
                | Command::StepClock(_)
                | Command::Move(..)
                | Command::GoTo(_)
                | Command::GoToDir(..)
                | Command::GoUntil(..)
                | Command::ReleaseSw(..)
                | Command::GoHome
                | Command::GoMark
        )
    }

    /// The exact bytes to send, command byte first, arguments MSB first.
    pub fn encode(&self) -> Encoded {
        match *self {
            Command::Nop => Encoded::new(opcode::NOP, 0, 0),
            Command::SetParam(r, v) => {
                Encoded::new(opcode::SET_PARAM | r.address(), v & r.mask(), r.bytes())
            }
            Command::GetParam(r) => Encoded::new(opcode::GET_PARAM | r.address(), 0, 0),
            Command::Run(d, spd) => Encoded::new(opcode::RUN | d.bit(), spd.min(SPEED_MAX), 3),
            Command::StepClock(d) => Encoded::new(opcode::STEP_CLOCK | d.bit(), 0, 0),
            Command::Move(d, n) => Encoded::new(opcode::MOVE | d.bit(), n.min(N_STEP_MAX), 3),
            Command::GoTo(p) => Encoded::new(opcode::GO_TO, wrap_22(p), 3),
            Command::GoToDir(d, p) => Encoded::new(opcode::GO_TO_DIR | d.bit(), wrap_22(p), 3),
            Command::GoUntil(a, d, spd) => Encoded::new(
                opcode::GO_UNTIL | ((a as u8) << 3) | d.bit(),
                spd.min(SPEED_MAX),
                3,
            ),
            Command::ReleaseSw(a, d) => {
                Encoded::new(opcode::RELEASE_SW | ((a as u8) << 3) | d.bit(), 0, 0)
            }
            Command::GoHome => Encoded::new(opcode::GO_HOME, 0, 0),
            Command::GoMark => Encoded::new(opcode::GO_MARK, 0, 0),
            Command::ResetPos => Encoded::new(opcode::RESET_POS, 0, 0),
            Command::ResetDevice => Encoded::new(opcode::RESET_DEVICE, 0, 0),
            Command::SoftStop => Encoded::new(opcode::SOFT_STOP, 0, 0),
            Command::HardStop => Encoded::new(opcode::HARD_STOP, 0, 0),
            Command::SoftHiZ => Encoded::new(opcode::SOFT_HIZ, 0, 0),
            Command::HardHiZ => Encoded::new(opcode::HARD_HIZ, 0, 0),
            Command::GetStatus => Encoded::new(opcode::GET_STATUS, 0, 0),
        }
    }

    /// Parse one complete command (command byte + exactly its arguments).
    pub fn decode(bytes: &[u8]) -> Result<Command, DecodeError> {
        let (&cmd, args) = bytes.split_first().ok_or(DecodeError::Empty)?;
        let needed = match Command::classify(cmd) {
            CommandByte::Takes(n) => n,
            CommandByte::Invalid => {
                return Err(match Register::from_address(cmd & 0x1F) {
                    Some(r) if cmd & 0xE0 == 0 => DecodeError::ReadOnlyRegister(r),
                    _ => DecodeError::UnknownCommand(cmd),
                })
            }
        };
        let got = u8::try_from(args.len()).unwrap_or(u8::MAX);
        if got < needed {
            return Err(DecodeError::MissingArguments { needed, got });
        }
        if got > needed {
            return Err(DecodeError::TrailingBytes);
        }
        let value = args.iter().fold(0u32, |acc, b| (acc << 8) | u32::from(*b));
        let dir = Direction::from_bit(cmd);
        let act = if cmd & 0x08 != 0 {
            SwitchAction::CopyToMark
        } else {
            SwitchAction::ResetAbsPos
        };
        let pos = super::registers::sign_extend_22(value);
        Ok(match cmd {
            opcode::NOP => Command::Nop,
            0x01..=0x1F => match Register::from_address(cmd) {
                Some(r) => Command::SetParam(r, value & r.mask()),
                None => return Err(DecodeError::UnknownCommand(cmd)),
            },
            0x20..=0x3F => match Register::from_address(cmd & 0x1F) {
                Some(r) => Command::GetParam(r),
                None => return Err(DecodeError::UnknownCommand(cmd)),
            },
            0x50 | 0x51 => Command::Run(dir, value & SPEED_MAX),
            0x58 | 0x59 => Command::StepClock(dir),
            0x40 | 0x41 => Command::Move(dir, value & N_STEP_MAX),
            opcode::GO_TO => Command::GoTo(pos),
            0x68 | 0x69 => Command::GoToDir(dir, pos),
            0x82 | 0x83 | 0x8A | 0x8B => Command::GoUntil(act, dir, value & SPEED_MAX),
            0x92 | 0x93 | 0x9A | 0x9B => Command::ReleaseSw(act, dir),
            opcode::GO_HOME => Command::GoHome,
            opcode::GO_MARK => Command::GoMark,
            opcode::RESET_POS => Command::ResetPos,
            opcode::RESET_DEVICE => Command::ResetDevice,
            opcode::SOFT_STOP => Command::SoftStop,
            opcode::HARD_STOP => Command::HardStop,
            opcode::SOFT_HIZ => Command::SoftHiZ,
            opcode::HARD_HIZ => Command::HardHiZ,
            opcode::GET_STATUS => Command::GetStatus,
            other => return Err(DecodeError::UnknownCommand(other)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use Direction::{Forward, Reverse};

    fn bytes(c: Command) -> std::vec::Vec<u8> {
        c.encode().as_slice().to_vec()
    }

    extern crate std;

    #[test]
    fn nop_is_0x00_with_no_arguments() {
        assert_eq!(bytes(Command::Nop), [0x00]);
        assert_eq!(Command::Nop.response_len(), 0);
    }

    #[test]
    fn set_param_is_address_then_value_msb_first_with_register_width() {
        assert_eq!(
            bytes(Command::SetParam(Register::MaxSpeed, 0x041)),
            [0x07, 0x00, 0x41]
        );
        assert_eq!(
            bytes(Command::SetParam(Register::Config, 0x2C88)),
            [0x1A, 0x2C, 0x88]
        );
        assert_eq!(
            bytes(Command::SetParam(Register::Mark, 0x12_3456)),
            [0x03, 0x12, 0x34, 0x56]
        );
        assert_eq!(
            bytes(Command::SetParam(Register::KvalRun, 0x29)),
            [0x0A, 0x29]
        );
        // Unused high bits are sent as 0.
        assert_eq!(
            bytes(Command::SetParam(Register::Acc, 0xFFFF)),
            [0x05, 0x0F, 0xFF]
        );
        assert_eq!(Command::SetParam(Register::Acc, 1).response_len(), 0);
    }

    #[test]
    fn get_param_is_0x20_or_address_and_returns_register_bytes() {
        assert_eq!(bytes(Command::GetParam(Register::AbsPos)), [0x21]);
        assert_eq!(bytes(Command::GetParam(Register::Status)), [0x3B]);
        assert_eq!(Command::GetParam(Register::AbsPos).response_len(), 3);
        assert_eq!(Command::GetParam(Register::Status).response_len(), 2);
        assert_eq!(Command::GetParam(Register::KvalHold).response_len(), 1);
    }

    #[test]
    fn run_is_0x50_or_dir_with_20_bit_speed() {
        assert_eq!(
            bytes(Command::Run(Forward, 0x0F_1234)),
            [0x51, 0x0F, 0x12, 0x34]
        );
        assert_eq!(
            bytes(Command::Run(Reverse, 0x00_0100)),
            [0x50, 0x00, 0x01, 0x00]
        );
        assert_eq!(
            bytes(Command::Run(Forward, u32::MAX)),
            [0x51, 0x0F, 0xFF, 0xFF]
        );
    }

    #[test]
    fn step_clock_is_0x58_or_dir() {
        assert_eq!(bytes(Command::StepClock(Reverse)), [0x58]);
        assert_eq!(bytes(Command::StepClock(Forward)), [0x59]);
    }

    #[test]
    fn move_is_0x40_or_dir_with_22_bit_count() {
        assert_eq!(
            bytes(Command::Move(Forward, 0x3F_FFFF)),
            [0x41, 0x3F, 0xFF, 0xFF]
        );
        assert_eq!(bytes(Command::Move(Reverse, 200)), [0x40, 0x00, 0x00, 0xC8]);
        assert_eq!(
            bytes(Command::Move(Reverse, u32::MAX)),
            [0x40, 0x3F, 0xFF, 0xFF]
        );
    }

    #[test]
    fn go_to_is_0x60_with_22_bit_twos_complement() {
        assert_eq!(bytes(Command::GoTo(-1)), [0x60, 0x3F, 0xFF, 0xFF]);
        assert_eq!(bytes(Command::GoTo(1000)), [0x60, 0x00, 0x03, 0xE8]);
    }

    #[test]
    fn go_to_dir_is_0x68_or_dir() {
        assert_eq!(
            bytes(Command::GoToDir(Forward, 5)),
            [0x69, 0x00, 0x00, 0x05]
        );
        assert_eq!(
            bytes(Command::GoToDir(Reverse, -2_097_152)),
            [0x68, 0x20, 0x00, 0x00]
        );
    }

    #[test]
    fn go_until_is_0x82_or_act_or_dir_with_speed() {
        assert_eq!(
            bytes(Command::GoUntil(SwitchAction::ResetAbsPos, Reverse, 0x100)),
            [0x82, 0x00, 0x01, 0x00]
        );
        assert_eq!(
            bytes(Command::GoUntil(SwitchAction::CopyToMark, Forward, 0x100)),
            [0x8B, 0x00, 0x01, 0x00]
        );
    }

    #[test]
    fn release_sw_is_0x92_or_act_or_dir() {
        assert_eq!(
            bytes(Command::ReleaseSw(SwitchAction::ResetAbsPos, Reverse)),
            [0x92]
        );
        assert_eq!(
            bytes(Command::ReleaseSw(SwitchAction::CopyToMark, Forward)),
            [0x9B]
        );
    }

    #[test]
    fn go_home_is_0x70() {
        assert_eq!(bytes(Command::GoHome), [0x70]);
    }

    #[test]
    fn go_mark_is_0x78() {
        assert_eq!(bytes(Command::GoMark), [0x78]);
    }

    #[test]
    fn reset_pos_is_0xd8() {
        assert_eq!(bytes(Command::ResetPos), [0xD8]);
    }

    #[test]
    fn reset_device_is_0xc0() {
        assert_eq!(bytes(Command::ResetDevice), [0xC0]);
    }

    #[test]
    fn soft_stop_is_0xb0_not_get_status() {
        assert_eq!(bytes(Command::SoftStop), [0xB0]);
        assert_eq!(Command::SoftStop.response_len(), 0);
    }

    #[test]
    fn hard_stop_is_0xb8() {
        assert_eq!(bytes(Command::HardStop), [0xB8]);
    }

    #[test]
    fn soft_hiz_is_0xa0() {
        assert_eq!(bytes(Command::SoftHiZ), [0xA0]);
    }

    #[test]
    fn hard_hiz_is_0xa8() {
        assert_eq!(bytes(Command::HardHiZ), [0xA8]);
    }

    #[test]
    fn get_status_is_0xd0_and_returns_two_bytes() {
        assert_eq!(bytes(Command::GetStatus), [0xD0]);
        assert_eq!(Command::GetStatus.response_len(), 2);
    }

    #[test]
    fn reserved_and_unknown_bytes_are_invalid() {
        for b in [0xEB, 0xF8, 0x1C, 0x1F, 0x3C, 0x3F, 0x61, 0x80, 0xFF] {
            assert_eq!(Command::classify(b), CommandByte::Invalid, "{b:#04x}");
        }
    }

    #[test]
    fn set_param_to_read_only_register_is_refused_at_the_command_byte() {
        for r in [Register::Speed, Register::AdcOut, Register::Status] {
            assert_eq!(Command::classify(r.address()), CommandByte::Invalid);
            assert_eq!(
                Command::decode(&[r.address(), 0, 0]),
                Err(DecodeError::ReadOnlyRegister(r))
            );
        }
    }

    #[test]
    fn every_valid_command_byte_decodes_and_re_encodes_identically() {
        let mut valid = 0;
        for b in 0u8..=0xFF {
            if let CommandByte::Takes(n) = Command::classify(b) {
                valid += 1;
                let mut frame = std::vec![b];
                frame.extend((0..n).map(|i| 0x11 * (i + 1)));
                // Mask args to what the command can carry, then compare.
                let cmd = Command::decode(&frame).expect("decodes");
                assert_eq!(cmd.wire_len() as usize, frame.len());
                let re = cmd.encode();
                assert_eq!(re.as_slice()[0], b, "{b:#04x}");
            }
        }
        // NOP + 24 writable SetParams + 27 GetParams + 2 Run + 2 StepClock + 2 Move
        // + GoTo + 2 GoTo_DIR + 4 GoUntil + 4 ReleaseSW + 9 one-byte commands.
        assert_eq!(valid, 1 + 24 + 27 + 2 + 2 + 2 + 1 + 2 + 4 + 4 + 9);
    }

    #[test]
    fn decode_rejects_wrong_argument_counts() {
        assert_eq!(
            Command::decode(&[0x51, 1, 2]),
            Err(DecodeError::MissingArguments { needed: 3, got: 2 })
        );
        assert_eq!(Command::decode(&[0xD0, 0]), Err(DecodeError::TrailingBytes));
        assert_eq!(Command::decode(&[]), Err(DecodeError::Empty));
    }
}
