//! The driver's tables against the simulator's, entry by entry.
//!
//! `powerstep01` (the driver) and `stepbridge_sim::datasheet` (the model)
//! each state the powerSTEP01's command table, register table and STATUS
//! layout on their own. Neither reads the other's, so a slip in either one
//! shows up here as a disagreement instead of being copied into the model.
//! The comparisons take the driver's side as data (a table, or functions),
//! and the `a_slip_…` tests hand them deliberately mutated copies to prove
//! that every kind of slip is caught.

use bridge_logic::powerstep::commands::{opcode, CommandByte, DecodeError};
use bridge_logic::powerstep::fields::{Config, StepMode};
use bridge_logic::powerstep::registers::{Access, RegisterInfo, REGISTERS};
use bridge_logic::powerstep::status::bits;
use bridge_logic::powerstep::{Command, Direction, Register, Status, SwitchAction};
use stepbridge_sim::datasheet::{self, Op, StatusWord, Verdict};
use stepbridge_sim::{vocab, Powerstep01};

// ------------------------------------------------------------ registers ----

fn model_access(a: datasheet::Access) -> Access {
    match a {
        datasheet::Access::ReadOnly => Access::ReadOnly,
        datasheet::Access::Always => Access::Always,
        datasheet::Access::WhenStopped => Access::WhenStopped,
        datasheet::Access::WhenHiZ => Access::WhenHiZ,
    }
}

/// Every way `driver` (a copy of the driver's register table) differs from
/// the model's register table, one line per differing field.
fn register_disagreements(driver: &[RegisterInfo]) -> Vec<String> {
    let mut out = vec![];
    for info in driver {
        let a = info.address;
        let name = info.voltage_mode_name;
        let Some(spec) = datasheet::register(a) else {
            out.push(format!("{a:#04x} {name}: not a register of the model"));
            continue;
        };
        let mut field = |what: &str, d: String, m: String| {
            if d != m {
                out.push(format!("{a:#04x} {name}: {what}: driver {d}, model {m}"));
            }
        };
        field("name", name.into(), spec.name.into());
        field(
            "current-mode name",
            format!("{:?}", info.current_mode_name),
            format!("{:?}", spec.current_mode_name),
        );
        field("bits", info.bits.to_string(), spec.bits.to_string());
        field("SPI bytes", info.bytes.to_string(), spec.bytes.to_string());
        field(
            "reset",
            format!("{:#x}", info.reset),
            format!("{:#x}", spec.reset),
        );
        field(
            "access",
            format!("{:?}", info.access),
            format!("{:?}", model_access(spec.access)),
        );
        field(
            "variant's address",
            format!("{:#04x}", info.register.address()),
            format!("{:#04x}", vocab::address(info.register)),
        );
    }
    for spec in datasheet::REGISTERS.iter() {
        if !driver.iter().any(|i| i.address == spec.address) {
            out.push(format!(
                "{:#04x} {}: missing from the driver",
                spec.address, spec.name
            ));
        }
    }
    out
}

#[test]
fn the_driver_register_table_agrees_with_the_model_on_every_register() {
    assert_eq!(REGISTERS.len(), datasheet::REGISTERS.len());
    let d = register_disagreements(&REGISTERS);
    assert!(d.is_empty(), "{d:#?}");
    // The driver's own lookups, not only its table rows.
    for spec in datasheet::REGISTERS.iter() {
        let r = Register::from_address(spec.address).expect("the driver knows it");
        assert_eq!(Some(r), vocab::register(spec.address), "{}", spec.name);
        assert_eq!(r.bits(), spec.bits, "{}", spec.name);
        assert_eq!(r.bytes(), spec.bytes, "{}", spec.name);
        assert_eq!(r.mask(), spec.mask(), "{}", spec.name);
        assert_eq!(r.access(), model_access(spec.access), "{}", spec.name);
    }
    for a in (0..=0xFF).filter(|a| datasheet::register(*a).is_none()) {
        assert_eq!(Register::from_address(a), None, "{a:#04x}");
    }
}

#[test]
fn a_slip_in_any_field_of_any_register_row_is_caught() {
    let others = [
        Access::ReadOnly,
        Access::Always,
        Access::WhenStopped,
        Access::WhenHiZ,
    ];
    for i in 0..REGISTERS.len() {
        let row = REGISTERS[i];
        let mut slips: Vec<(&str, RegisterInfo)> = vec![
            (
                "width one bit more",
                RegisterInfo {
                    bits: row.bits + 1,
                    ..row
                },
            ),
            (
                "width one bit less",
                RegisterInfo {
                    bits: row.bits - 1,
                    ..row
                },
            ),
            (
                "one SPI byte more",
                RegisterInfo {
                    bytes: row.bytes + 1,
                    ..row
                },
            ),
            (
                "reset value off by one bit",
                RegisterInfo {
                    reset: row.reset ^ 1,
                    ..row
                },
            ),
            (
                "another register's name",
                RegisterInfo {
                    voltage_mode_name: REGISTERS[(i + 1) % REGISTERS.len()].voltage_mode_name,
                    ..row
                },
            ),
        ];
        if row.bytes > 1 {
            slips.push((
                "one SPI byte less",
                RegisterInfo {
                    bytes: row.bytes - 1,
                    ..row
                },
            ));
        }
        for a in others.iter().filter(|a| **a != row.access) {
            slips.push(("another access class", RegisterInfo { access: *a, ..row }));
        }
        for (what, slipped) in slips {
            let mut table = REGISTERS;
            table[i] = slipped;
            let d = register_disagreements(&table);
            assert!(
                !d.is_empty(),
                "{} with {what} is not caught",
                row.voltage_mode_name
            );
            let tag = format!("{:#04x} ", row.address);
            assert!(
                d.iter().all(|line| line.starts_with(&tag)),
                "{what}: only {} is reported: {d:#?}",
                row.voltage_mode_name
            );
        }
    }
    // A row missing, or a row at the wrong address.
    let d = register_disagreements(&REGISTERS[1..]);
    assert_eq!(d, ["0x01 ABS_POS: missing from the driver"]);
    let mut table = REGISTERS;
    table[4].address = 0x1C;
    assert!(register_disagreements(&table).len() >= 2);
}

#[test]
fn the_model_powers_up_with_the_reset_values_of_the_driver_table() {
    let chip = Powerstep01::new();
    for info in REGISTERS.iter().filter(|i| i.register != Register::Status) {
        assert_eq!(
            chip.register(info.register),
            info.reset,
            "{}",
            info.voltage_mode_name
        );
    }
}

// ------------------------------------------------------------- commands ----

/// The driver's side of the command table, as functions (so that a test
/// can hand in a slipped copy).
struct DriverCodec {
    classify: fn(u8) -> CommandByte,
    encode: fn(&Command) -> Vec<u8>,
    decode: fn(&[u8]) -> Result<Command, DecodeError>,
    response_len: fn(&Command) -> u8,
}

const DRIVER: DriverCodec = DriverCodec {
    classify: Command::classify,
    encode: |c| c.encode().as_slice().to_vec(),
    decode: Command::decode,
    response_len: Command::response_len,
};

/// A spread of argument values: edges, past the edges, patterns.
const VALUES: [u32; 12] = [
    0,
    1,
    0x29,
    0xFF,
    0x100,
    0x0F_FFFF,
    0x10_0000,
    0x1F_FFFF,
    0x20_0000,
    0x3F_FFFF,
    0x40_0000,
    u32::MAX,
];

/// Every command the vocabulary can express, over [`VALUES`].
fn every_command() -> Vec<Command> {
    let dirs = [Direction::Forward, Direction::Reverse];
    let acts = [SwitchAction::ResetAbsPos, SwitchAction::CopyToMark];
    let mut all = vec![
        Command::Nop,
        Command::GoHome,
        Command::GoMark,
        Command::ResetPos,
        Command::ResetDevice,
        Command::SoftStop,
        Command::HardStop,
        Command::SoftHiZ,
        Command::HardHiZ,
        Command::GetStatus,
    ];
    for spec in datasheet::REGISTERS.iter() {
        let r = vocab::register(spec.address).expect("named");
        all.push(Command::GetParam(r));
        if spec.access != datasheet::Access::ReadOnly {
            all.extend(VALUES.iter().map(|v| Command::SetParam(r, *v)));
        }
    }
    for d in dirs {
        all.push(Command::StepClock(d));
        for v in VALUES {
            all.push(Command::Run(d, v));
            all.push(Command::Move(d, v));
            all.push(Command::GoToDir(d, v as i32));
            all.push(Command::GoTo(v as i32));
        }
        for a in acts {
            all.push(Command::ReleaseSw(a, d));
            all.extend(VALUES.iter().map(|v| Command::GoUntil(a, d, *v)));
        }
    }
    all.push(Command::GoTo(-1));
    all.push(Command::GoTo(-2_097_152));
    all
}

/// Every way `driver` differs from the model's command table and codec.
fn command_disagreements(driver: &DriverCodec) -> Vec<String> {
    let mut out = vec![];
    // Every byte received as a command byte: refused, or how many
    // argument bytes the chip then waits for.
    for b in 0u8..=0xFF {
        let d = match (driver.classify)(b) {
            CommandByte::Takes(n) => Some(n),
            CommandByte::Invalid => None,
        };
        let m = match datasheet::command_byte(b) {
            Verdict::Takes(n) => Some(n),
            Verdict::Refused => None,
        };
        if d != m {
            out.push(format!(
                "byte {b:#04x}: driver takes {d:?} argument bytes, model {m:?}"
            ));
            continue;
        }
        // Every accepted byte, with argument bytes of several patterns:
        // both decode to the same command.
        if let Some(n) = m {
            for fill in [0x00u8, 0xFF, 0x5A, 0xA5] {
                let mut frame = vec![b];
                frame.extend((0..n).map(|i| fill.rotate_left(u32::from(i))));
                let dc = (driver.decode)(&frame).ok();
                let mc = datasheet::decode(&frame);
                if dc != mc {
                    out.push(format!(
                        "frame {frame:02x?}: driver decodes {dc:?}, model {mc:?}"
                    ));
                }
            }
        }
    }
    // Every command: the same bytes on the wire, the same response length.
    for c in every_command() {
        let d = (driver.encode)(&c);
        let m = datasheet::encode(&c).as_slice().to_vec();
        if d != m {
            out.push(format!(
                "{c:?}: driver sends {d:02x?}, model expects {m:02x?}"
            ));
        }
        let (dr, mr) = ((driver.response_len)(&c), datasheet::response_len(m[0]));
        if dr != mr {
            out.push(format!(
                "{c:?}: driver reads {dr} response bytes, model sends {mr}"
            ));
        }
    }
    out
}

#[test]
fn the_driver_command_codec_agrees_with_the_model_on_every_byte_and_command() {
    let d = command_disagreements(&DRIVER);
    assert!(d.is_empty(), "{d:#?}");
}

#[test]
fn the_driver_opcodes_are_the_model_command_table() {
    let pairs = [
        (opcode::NOP, Op::Nop),
        (opcode::SET_PARAM, Op::SetParam),
        (opcode::GET_PARAM, Op::GetParam),
        (opcode::RUN, Op::Run),
        (opcode::STEP_CLOCK, Op::StepClock),
        (opcode::MOVE, Op::Move),
        (opcode::GO_TO, Op::GoTo),
        (opcode::GO_TO_DIR, Op::GoToDir),
        (opcode::GO_UNTIL, Op::GoUntil),
        (opcode::RELEASE_SW, Op::ReleaseSw),
        (opcode::GO_HOME, Op::GoHome),
        (opcode::GO_MARK, Op::GoMark),
        (opcode::RESET_POS, Op::ResetPos),
        (opcode::RESET_DEVICE, Op::ResetDevice),
        (opcode::SOFT_STOP, Op::SoftStop),
        (opcode::HARD_STOP, Op::HardStop),
        (opcode::SOFT_HIZ, Op::SoftHiZ),
        (opcode::HARD_HIZ, Op::HardHiZ),
        (opcode::GET_STATUS, Op::GetStatus),
    ];
    assert_eq!(pairs.len(), datasheet::OPCODES.len());
    for (byte, op) in pairs {
        let row = datasheet::opcode_of(op);
        assert_eq!(byte, row.code, "{}", row.name);
    }
}

/// The driver's encoder with one command's bytes replaced.
macro_rules! slipped_encode {
    ($cmd:pat => $bytes:expr) => {
        DriverCodec {
            encode: |c| match c {
                $cmd => $bytes,
                other => other.encode().as_slice().to_vec(),
            },
            ..DRIVER
        }
    };
}

#[test]
fn a_slip_in_the_driver_command_codec_is_caught() {
    // AN4290's Table 5 error: GetStatus sent as 0xB0 (which is SoftStop).
    let d = command_disagreements(&slipped_encode!(Command::GetStatus => vec![0xB0]));
    assert!(
        d.iter()
            .any(|l| l.starts_with("GetStatus: driver sends [b0]")),
        "{d:#?}"
    );
    // ACT and the ReleaseSW bit swapped (0b100A101D instead of 0b1001A01D).
    let d = command_disagreements(&slipped_encode!(
        Command::ReleaseSw(SwitchAction::CopyToMark, Direction::Reverse) => vec![0x8A]
    ));
    assert_eq!(d.len(), 1, "{d:#?}");
    // A short argument: Run's speed in two bytes.
    let d = command_disagreements(
        &slipped_encode!(Command::Run(Direction::Forward, _) => vec![0x51, 0, 0]),
    );
    assert_eq!(d.len(), VALUES.len(), "{d:#?}");
    // SetParam of a read-only register thought writable (STATUS).
    let d = command_disagreements(&DriverCodec {
        classify: |b| match b {
            0x1B => CommandByte::Takes(2),
            b => Command::classify(b),
        },
        ..DRIVER
    });
    assert_eq!(
        d,
        ["byte 0x1b: driver takes Some(2) argument bytes, model None"]
    );
    // A wrong response length (GetStatus read as 3 bytes).
    let d = command_disagreements(&DriverCodec {
        response_len: |c| match c {
            Command::GetStatus => 3,
            c => c.response_len(),
        },
        ..DRIVER
    });
    assert_eq!(d.len(), 1, "{d:#?}");
    // A decoder that drops the DIR bit of Move.
    let d = command_disagreements(&DriverCodec {
        decode: |f| match Command::decode(f) {
            Ok(Command::Move(_, n)) => Ok(Command::Move(Direction::Forward, n)),
            other => other,
        },
        ..DRIVER
    });
    assert_eq!(d.len(), 4, "byte 0x40 with its 4 argument patterns: {d:#?}");
}

// --------------------------------------------------------------- STATUS ----

/// The driver's STATUS masks by name.
const DRIVER_BITS: [(&str, u16); 15] = [
    ("HIZ", bits::HIZ),
    ("BUSY", bits::BUSY),
    ("SW_F", bits::SW_F),
    ("SW_EVN", bits::SW_EVN),
    ("DIR", bits::DIR),
    ("MOT_STATUS", bits::MOT_STATUS),
    ("CMD_ERROR", bits::CMD_ERROR),
    ("STCK_MOD", bits::STCK_MOD),
    ("UVLO", bits::UVLO),
    ("UVLO_ADC", bits::UVLO_ADC),
    ("TH_STATUS", bits::TH_STATUS),
    ("OCD", bits::OCD),
    ("STALL_A", bits::STALL_A),
    ("STALL_B", bits::STALL_B),
    ("ACTIVE_LOW", bits::ACTIVE_LOW),
];

fn status_disagreements(driver: &[(&str, u16)]) -> Vec<String> {
    use datasheet::status as m;
    let model = [
        ("HIZ", m::HIZ),
        ("BUSY", m::BUSY),
        ("SW_F", m::SW_F),
        ("SW_EVN", m::SW_EVN),
        ("DIR", m::DIR),
        ("MOT_STATUS", m::MOT_STATUS),
        ("CMD_ERROR", m::CMD_ERROR),
        ("STCK_MOD", m::STCK_MOD),
        ("UVLO", m::UVLO),
        ("UVLO_ADC", m::UVLO_ADC),
        ("TH_STATUS", m::TH_STATUS),
        ("OCD", m::OCD),
        ("STALL_A", m::STALL_A),
        ("STALL_B", m::STALL_B),
        ("ACTIVE_LOW", m::ACTIVE_LOW),
    ];
    let mut out = vec![];
    for (name, mask) in model {
        match driver.iter().find(|(n, _)| *n == name) {
            Some((_, d)) if *d == mask => {}
            Some((_, d)) => out.push(format!("{name}: driver {d:#06x}, model {mask:#06x}")),
            None => out.push(format!("{name}: missing from the driver")),
        }
    }
    out
}

#[test]
fn the_driver_status_layout_agrees_with_the_model() {
    let d = status_disagreements(&DRIVER_BITS);
    assert!(d.is_empty(), "{d:#?}");
    // And the readers: every 16-bit value reads the same through both.
    for raw in 0..=u16::MAX {
        let (d, m) = (Status(raw), StatusWord(raw));
        assert_eq!(
            (
                d.hiz(),
                d.busy(),
                d.switch_closed(),
                d.switch_event(),
                d.direction(),
                d.motor_status(),
                d.command_error(),
                d.step_clock_mode(),
            ),
            (
                m.hiz(),
                m.busy(),
                m.switch_closed(),
                m.switch_event(),
                m.direction(),
                m.motor_status(),
                m.command_error(),
                m.step_clock_mode(),
            ),
            "{raw:#06x}"
        );
        assert_eq!(
            (
                d.uvlo(),
                d.uvlo_adc(),
                d.thermal(),
                d.overcurrent(),
                d.stall_a(),
                d.stall_b(),
            ),
            (
                m.uvlo(),
                m.uvlo_adc(),
                m.thermal(),
                m.overcurrent(),
                m.stall_a(),
                m.stall_b(),
            ),
            "{raw:#06x}"
        );
    }
}

#[test]
fn a_slip_in_the_driver_status_layout_is_caught() {
    // The disputed pair swapped (STALL_A at bit 15, STALL_B at bit 14).
    let mut swapped = DRIVER_BITS;
    swapped[12].1 = bits::STALL_B;
    swapped[13].1 = bits::STALL_A;
    assert_eq!(status_disagreements(&swapped).len(), 2);
    // BUSY one bit off.
    let mut off = DRIVER_BITS;
    off[1].1 = bits::BUSY << 1;
    assert_eq!(
        status_disagreements(&off),
        ["BUSY: driver 0x0004, model 0x0002"]
    );
}

// ----------------------------------------------------------- bit fields ----

#[test]
fn the_driver_config_and_step_mode_fields_agree_with_the_model() {
    use datasheet::{config, fields};
    assert_eq!(u32::from(Config::SW_MODE), config::SW_MODE);
    for v in 0..=u16::MAX {
        let c = Config::from_reg(v);
        assert_eq!(c.sw_user, u32::from(v) & config::SW_MODE != 0, "{v:#06x}");
        assert_eq!(c.oc_shutdown, u32::from(v) & config::OC_SD != 0, "{v:#06x}");
    }
    for v in 0..=u8::MAX {
        assert_eq!(
            StepMode::from_reg(v).step.shift(),
            u32::from(v) & fields::STEP_SEL,
            "{v:#04x}"
        );
    }
}
