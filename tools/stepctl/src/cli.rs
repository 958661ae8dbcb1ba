//! Command line (clap). Values are range-checked here, before anything is
//! sent: clap refuses a position beyond i32, a speed beyond u16, a baud rate
//! the box does not have.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

use crate::modbus::Parity;

pub const DEFAULT_TCP: &str = "127.0.0.1:5020";

#[derive(Parser, Debug, PartialEq)]
#[command(
    name = "stepctl",
    version,
    about = "Commission and drive a stepbridge motion box (PoStep60 per axis) over Modbus RTU or USB",
    after_help = "AXIS is the Modbus id of the axis (factory: 1 = first axis); over USB 1 = first axis.\n\
                  With no --port/--tcp/--usb stepctl talks to `cargo qemu` at tcp 127.0.0.1:5020.\n\
                  Exit codes: 0 ok, 1 usage or value out of range, 2 communication, 3 device refused \
                  (Modbus exception / USB status), 4 fault or stop during a wait, 5 wait timed out, \
                  6 a doctor check failed."
)]
pub struct Cli {
    #[command(flatten)]
    pub conn: Connection,
    /// Print results as JSON (one object; `watch` prints one per line).
    #[arg(long, global = true)]
    pub json: bool,
    /// Print every frame sent and received on stderr.
    #[arg(short, long, global = true)]
    pub verbose: bool,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Args, Debug, PartialEq, Clone)]
pub struct Connection {
    /// Modbus RTU on a serial port (RS-485 adapter), e.g. /dev/ttyUSB0 or COM3.
    #[arg(long, global = true, group = "transport", value_name = "DEVICE")]
    pub port: Option<String>,
    /// Modbus RTU over TCP (raw RTU frames, as `cargo qemu` serves them).
    #[arg(long, global = true, group = "transport", value_name = "HOST:PORT")]
    pub tcp: Option<String>,
    /// USB HID (VID 0x1DC3, PID 0x0641).
    #[arg(long, global = true, group = "transport")]
    pub usb: bool,
    /// With --usb: the device's serial number, when several are plugged in.
    #[arg(long, global = true, value_name = "SERIAL")]
    pub usb_serial: Option<String>,
    /// Serial baud rate (the box's stored setting: 9600 or 19200).
    #[arg(long, global = true, default_value_t = 9600, value_parser = baud)]
    pub baud: u32,
    /// Serial parity (the box's stored setting; none means two stop bits).
    #[arg(long, global = true, value_enum, default_value_t = Parity::Even)]
    pub parity: Parity,
    /// Reply timeout per request, ms.
    #[arg(long, global = true, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..=60_000))]
    pub timeout_ms: u64,
    /// The box's first Modbus id (axis k answers FIRST + k; factory 1).
    #[arg(long, global = true, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=247))]
    pub first_id: u8,
}

fn baud(s: &str) -> Result<u32, String> {
    match s {
        "9600" => Ok(9600),
        "19200" => Ok(19200),
        _ => Err(format!("{s}: the box talks 9600 or 19200 baud")),
    }
}

/// A Modbus id: 1..=247.
fn axis(s: &str) -> Result<u8, String> {
    let v: u8 = s
        .parse()
        .map_err(|_| format!("{s:?}: an axis is a Modbus id 1..=247"))?;
    if (1..=247).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v}: an axis is a Modbus id 1..=247"))
    }
}

/// An inclusive range "1-16" or a single id.
fn id_range(s: &str) -> Result<(u8, u8), String> {
    let (a, b) = match s.split_once('-') {
        Some((a, b)) => (axis(a)?, axis(b)?),
        None => (axis(s)?, axis(s)?),
    };
    if a > b {
        return Err(format!("{s}: the range goes down"));
    }
    Ok((a, b))
}

fn register(s: &str) -> Result<u16, String> {
    crate::settings::parse_int(s)
        .ok()
        .and_then(|v| u16::try_from(v).ok())
        .ok_or_else(|| format!("{s:?}: a register address or value 0..=0xFFFF"))
}

fn speed(s: &str) -> Result<i32, String> {
    let v: i32 = s
        .parse()
        .map_err(|_| format!("{s:?}: steps/s, e.g. 1500 or -1500"))?;
    if v.unsigned_abs() > 65535 {
        return Err(format!(
            "{v}: out of range, the box runs at -65535..=65535 steps/s"
        ));
    }
    Ok(v)
}

fn limit(s: &str) -> Result<u16, String> {
    let v: u32 = s
        .parse()
        .map_err(|_| format!("{s:?}: a number 1..=65535"))?;
    match u16::try_from(v) {
        Ok(v) if v >= 1 => Ok(v),
        _ => Err(format!("{v}: out of range 1..=65535")),
    }
}

#[derive(Args, Debug, PartialEq, Clone)]
pub struct Wait {
    /// Return at once instead of waiting.
    #[arg(long)]
    pub no_wait: bool,
    /// Give up waiting after this many seconds (exit 5).
    #[arg(long, default_value_t = 60.0)]
    pub timeout: f64,
}

#[derive(Args, Debug, PartialEq, Clone, Default)]
pub struct Limits {
    /// Max speed, steps/s, set before moving.
    #[arg(long, value_parser = limit)]
    pub speed: Option<u16>,
    /// Acceleration, steps/s², set before moving.
    #[arg(long, value_parser = limit)]
    pub acc: Option<u16>,
    /// Deceleration, steps/s², set before moving.
    #[arg(long, value_parser = limit)]
    pub dec: Option<u16>,
}

/// A coordinated move's path limits, in steps of the axis that travels
/// farthest (not stored: the axes' own limits stay as they are).
#[derive(Args, Debug, PartialEq, Clone, Default)]
pub struct PathLimits {
    /// Path max speed, steps/s (the axes' own max speeds cap it).
    #[arg(long)]
    pub speed: Option<u32>,
    /// Path acceleration, steps/s².
    #[arg(long)]
    pub acc: Option<u32>,
    /// Path deceleration, steps/s².
    #[arg(long)]
    pub dec: Option<u32>,
}

/// `move AXIS=POS …` is the coordinated `group-move`: the arguments with
/// `move` followed by an `AXIS=POS` rewritten so (`move AXIS POS` stays the
/// single-axis move).
pub fn group_move_args(args: Vec<String>) -> Vec<String> {
    let at = args.iter().position(|a| a == "move");
    match at {
        Some(i)
            if args
                .get(i.saturating_add(1))
                .is_some_and(|a| a.contains('=')) =>
        {
            let mut out = args;
            if let Some(cmd) = out.get_mut(i) {
                *cmd = "group-move".into();
            }
            out
        }
        _ => args,
    }
}

#[derive(Subcommand, Debug, PartialEq)]
pub enum Command {
    /// List the ids that answer on the bus (or the USB devices with --usb).
    Scan {
        /// Ids to try, e.g. 1-16 or 1-247.
        #[arg(long, default_value = "1-16", value_parser = id_range)]
        ids: (u8, u8),
        /// Reply timeout per id, ms.
        #[arg(long, default_value_t = 100)]
        probe_ms: u64,
    },
    /// The box: versions, axes, reset cause, settings source, uptime.
    Info,
    /// One table for every axis (or the given ones).
    Status {
        #[arg(value_parser = axis)]
        axes: Vec<u8>,
    },
    /// Move AXIS to POS (steps); waits with a progress bar.
    Move {
        #[arg(value_parser = axis)]
        axis: u8,
        #[arg(allow_negative_numbers = true)]
        position: i32,
        #[command(flatten)]
        limits: Limits,
        #[command(flatten)]
        wait: Wait,
    },
    /// Several axes in one coordinated move (`stepctl move 1=3000 2=-500`:
    /// `move` with AXIS=POS arguments comes here): one straight line, one
    /// start, one arrival (extension 0x08nn); waits.
    #[command(name = "group-move", hide = true)]
    GroupMove {
        /// AXIS=POS for each axis, e.g. 1=3000 2=-500.
        #[arg(required = true, allow_negative_numbers = true)]
        targets: Vec<String>,
        #[command(flatten)]
        limits: PathLimits,
        /// Give up waiting after this many seconds (exit 5).
        #[arg(long, default_value_t = 60.0)]
        timeout: f64,
        /// Return once the move is started instead of waiting.
        #[arg(long)]
        no_wait: bool,
    },
    /// Run a path of waypoints from a CSV file: a header row naming the
    /// axes (e.g. `1,2,3`), then one waypoint per row in their steps. A
    /// coordinated move to the first row, then the rows streamed into the
    /// box's path queue as it drains (extension 0x08nn); waits.
    Path {
        file: PathBuf,
        #[command(flatten)]
        limits: PathLimits,
        /// Give up waiting after this many seconds (exit 5).
        #[arg(long, default_value_t = 600.0)]
        timeout: f64,
        /// Write every axis's position at each poll as CSV (t_s,axis…).
        #[arg(long)]
        record: Option<PathBuf>,
        /// Draw the first two axes against each other (XY) into this SVG.
        #[arg(long)]
        plot: Option<PathBuf>,
    },
    /// Move AXIS by STEPS from where it is.
    Jog {
        #[arg(value_parser = axis)]
        axis: u8,
        #[arg(allow_negative_numbers = true)]
        steps: i32,
        #[command(flatten)]
        limits: Limits,
        #[command(flatten)]
        wait: Wait,
    },
    /// Run AXIS at SPEED steps/s (auto-run mode; negative = reverse; 0 stops with the ramp).
    Run {
        #[arg(value_parser = axis)]
        axis: u8,
        #[arg(allow_negative_numbers = true, value_parser = speed)]
        speed: i32,
    },
    /// Stop at once (no ramp) every axis, or the given ones.
    Stop {
        #[arg(value_parser = axis)]
        axes: Vec<u8>,
    },
    /// Make the current position of AXIS zero.
    Zero {
        #[arg(value_parser = axis)]
        axis: u8,
    },
    /// Home AXIS against its end switch (extension 0x0400); waits.
    Home {
        #[arg(value_parser = axis)]
        axis: u8,
        #[command(flatten)]
        wait: Wait,
    },
    /// Power the motor of AXIS (Run/Sleep: run).
    Wake {
        #[arg(value_parser = axis)]
        axis: u8,
    },
    /// Unpower the motor of AXIS (Run/Sleep: sleep); the position is kept.
    Sleep {
        #[arg(value_parser = axis)]
        axis: u8,
    },
    /// Clear the latched faults of AXIS (0x35).
    ResetFaults {
        #[arg(value_parser = axis)]
        axis: u8,
    },
    /// Settings: show, set, save, export, import.
    #[command(subcommand)]
    Settings(SettingsCmd),
    /// A live table of every axis (Ctrl-C ends it).
    Watch {
        #[arg(value_parser = axis)]
        axes: Vec<u8>,
        /// Refresh period, ms.
        #[arg(long, default_value_t = 200)]
        interval_ms: u64,
        /// Stop after this many refreshes (0: until Ctrl-C).
        #[arg(long, default_value_t = 0)]
        count: u64,
    },
    /// Record position and speed of AXIS; draw them (SVG) and/or write CSV.
    Record {
        #[arg(value_parser = axis)]
        axis: u8,
        /// How long, s.
        #[arg(long, default_value_t = 5.0)]
        seconds: f64,
        /// Draw position and speed vs time into this SVG file.
        #[arg(long)]
        plot: Option<PathBuf>,
        /// Write the samples as CSV (t_s,position,speed).
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Start a move to this position when recording starts.
        #[arg(long = "move", allow_negative_numbers = true, value_name = "POS")]
        move_to: Option<i32>,
        /// Also record this axis and draw the two against each other (XY:
        /// AXIS across, this one up) instead of against time.
        #[arg(long, value_parser = axis, value_name = "AXIS")]
        xy: Option<u8>,
    },
    /// Bring-up checks: chain, each chip's STATUS and registers against what
    /// the bridge wrote, supply, temperature, settings store, reset cause,
    /// bus errors, tick rate; OK / WARN / FAIL with what to check on the
    /// board. Exit 6 if any check fails.
    Doctor {
        /// Chips the chain should have (a different count fails).
        #[arg(long, value_parser = clap::value_parser!(u16).range(1..=8))]
        expect_axes: Option<u16>,
        /// The board's nominal motor supply, V (the reference board: 24).
        #[arg(long, default_value_t = 24.0)]
        supply: f64,
        /// Also run a transfer through the I/O extension and compare it
        /// (needs a MOSI → MISO jumper, PB15 → PB14, and no panel mapping).
        #[arg(long)]
        loopback: bool,
        /// Measure the tick rate over at least this long, s.
        #[arg(long, default_value_t = 1.0)]
        seconds: f64,
        /// How far the measured tick rate may be off, and which share of
        /// ticks may overrun, %, before the tick is a WARN (QEMU on a busy
        /// host loses ticks: the end-to-end test passes 50).
        #[arg(long, default_value_t = crate::doctor::TICK_TOLERANCE_PERCENT)]
        tick_tolerance: f64,
    },
    /// Send a raw PoStep60 command (register 0x00nn = command nn, or an
    /// extension address) and print the reply. No VALUES: read COUNT
    /// registers (the command's own count by default). Over USB: COMMAND is
    /// the USB command byte and VALUES the bytes from OutDATA[2].
    Raw {
        #[arg(value_parser = axis)]
        axis: u8,
        #[arg(value_parser = register)]
        command: u16,
        #[arg(value_parser = register)]
        values: Vec<u16>,
        /// Registers to read (default: the command's count, 1 in the extension space).
        #[arg(long)]
        count: Option<u16>,
    },
}

#[derive(Subcommand, Debug, PartialEq)]
pub enum SettingsCmd {
    /// Every setting of every axis (or the given ones), with units.
    Show {
        #[arg(value_parser = axis)]
        axes: Vec<u8>,
    },
    /// Change one setting: KEY is a file key or an alias (max-speed, acc,
    /// dec, step-mode, current, idle-current, overheat-current, temp-limit,
    /// mode, requested-speed, invert, homing.*, chip.NAME, watchdog.*).
    Set {
        #[arg(value_parser = axis)]
        axis: u8,
        key: String,
        #[arg(allow_negative_numbers = true)]
        value: String,
        /// Also save to the box's flash.
        #[arg(long)]
        save: bool,
    },
    /// Write the settings in use to the box's flash (kept across restarts).
    Save,
    /// Write every setting of every axis to a TOML file.
    Export {
        file: PathBuf,
        #[arg(value_parser = axis)]
        axes: Vec<u8>,
    },
    /// Apply a TOML file (only what differs is written).
    Import {
        file: PathBuf,
        /// Also save to the box's flash.
        #[arg(long)]
        save: bool,
    },
}

impl Cli {
    /// What the selector asks for.
    pub fn transport(&self) -> Transport {
        let c = &self.conn;
        if c.usb {
            Transport::Usb(c.usb_serial.clone())
        } else if let Some(p) = &c.port {
            Transport::Serial {
                path: p.clone(),
                baud: c.baud,
                parity: c.parity,
            }
        } else {
            Transport::Tcp(c.tcp.clone().unwrap_or_else(|| DEFAULT_TCP.to_string()))
        }
    }
}

#[derive(Debug, PartialEq, Clone)]
pub enum Transport {
    Tcp(String),
    Serial {
        path: String,
        baud: u32,
        parity: Parity,
    },
    Usb(Option<String>),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(args: &[&str]) -> Result<Cli, clap::Error> {
        Cli::try_parse_from(std::iter::once("stepctl").chain(args.iter().copied()))
    }

    #[test]
    fn with_no_selector_it_talks_to_the_qemu_image() {
        let c = parse(&["status"]).unwrap();
        assert_eq!(c.transport(), Transport::Tcp("127.0.0.1:5020".into()));
    }

    #[test]
    fn a_serial_port_takes_the_box_s_baud_and_parity() {
        let c = parse(&[
            "--port",
            "/dev/ttyUSB0",
            "--baud",
            "19200",
            "--parity",
            "none",
            "info",
        ])
        .unwrap();
        assert_eq!(
            c.transport(),
            Transport::Serial {
                path: "/dev/ttyUSB0".into(),
                baud: 19200,
                parity: Parity::None
            }
        );
    }

    #[test]
    fn a_baud_rate_the_box_does_not_have_is_refused() {
        assert!(parse(&["--port", "x", "--baud", "115200", "info"]).is_err());
    }

    #[test]
    fn only_one_transport_can_be_selected() {
        assert!(parse(&["--tcp", "h:1", "--usb", "info"]).is_err());
        assert!(parse(&["--port", "p", "--tcp", "h:1", "info"]).is_err());
    }

    #[test]
    fn options_may_follow_the_command() {
        let c = parse(&["status", "--tcp", "127.0.0.1:15020", "--json"]).unwrap();
        assert_eq!(c.transport(), Transport::Tcp("127.0.0.1:15020".into()));
        assert!(c.json);
    }

    #[test]
    fn move_takes_negative_positions_and_waits_by_default() {
        let c = parse(&["move", "2", "-2000"]).unwrap();
        match c.command {
            Command::Move {
                axis,
                position,
                wait,
                ..
            } => {
                assert_eq!((axis, position), (2, -2000));
                assert!(!wait.no_wait);
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn move_with_axis_equals_position_is_the_coordinated_move() {
        let args = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let a = group_move_args(args(&[
            "stepctl", "--tcp", "h:1", "move", "1=3000", "2=-500",
        ]));
        assert_eq!(a[3], "group-move");
        let c = Cli::try_parse_from(a).unwrap();
        match c.command {
            Command::GroupMove { targets, .. } => assert_eq!(targets, ["1=3000", "2=-500"]),
            other => panic!("{other:?}"),
        }
        // The single-axis move stays as it is.
        let a = group_move_args(args(&["stepctl", "move", "1", "-3000"]));
        assert_eq!(a[1], "move");
        let c = Cli::try_parse_from(args(&["stepctl", "path", "p.csv", "--speed", "70000"]));
        assert!(matches!(c.unwrap().command, Command::Path { .. }));
    }

    #[test]
    fn positions_beyond_32_bits_are_refused() {
        assert!(parse(&["move", "1", "3000000000"]).is_err());
    }

    #[test]
    fn axis_0_and_ids_beyond_247_are_refused() {
        assert!(parse(&["move", "0", "10"]).is_err());
        assert!(parse(&["zero", "248"]).is_err());
    }

    #[test]
    fn run_speeds_beyond_16_bits_are_refused() {
        assert!(parse(&["run", "1", "70000"]).is_err());
        assert!(parse(&["run", "1", "-1500"]).is_ok());
    }

    #[test]
    fn move_limits_must_be_1_to_65535() {
        assert!(parse(&["move", "1", "5", "--speed", "0"]).is_err());
        assert!(parse(&["move", "1", "5", "--acc", "65536"]).is_err());
        assert!(parse(&["move", "1", "5", "--speed", "2000"]).is_ok());
    }

    #[test]
    fn scan_takes_an_id_range() {
        match parse(&["scan", "--ids", "1-247"]).unwrap().command {
            Command::Scan { ids, .. } => assert_eq!(ids, (1, 247)),
            other => panic!("{other:?}"),
        }
        assert!(parse(&["scan", "--ids", "9-3"]).is_err());
    }

    #[test]
    fn raw_takes_hex_commands_and_values() {
        match parse(&["raw", "1", "0x51", "0x07D0"]).unwrap().command {
            Command::Raw {
                command, values, ..
            } => assert_eq!((command, values), (0x51, vec![2000])),
            other => panic!("{other:?}"),
        }
        assert!(parse(&["raw", "1", "0x10000"]).is_err());
    }

    #[test]
    fn settings_subcommands_parse() {
        assert!(matches!(
            parse(&["settings", "import", "a.toml", "--save"])
                .unwrap()
                .command,
            Command::Settings(SettingsCmd::Import { save: true, .. })
        ));
        assert!(matches!(
            parse(&["settings", "set", "1", "max-speed", "2500"])
                .unwrap()
                .command,
            Command::Settings(SettingsCmd::Set { axis: 1, .. })
        ));
    }

    #[test]
    fn doctor_takes_the_expected_axes_a_nominal_supply_and_the_loopback() {
        match parse(&[
            "doctor",
            "--expect-axes",
            "4",
            "--loopback",
            "--supply",
            "48",
            "--json",
        ])
        .unwrap()
        .command
        {
            Command::Doctor {
                expect_axes,
                supply,
                loopback,
                seconds,
                tick_tolerance,
            } => {
                assert_eq!((expect_axes, supply, loopback), (Some(4), 48.0, true));
                assert_eq!((seconds, tick_tolerance), (1.0, 2.0));
            }
            other => panic!("{other:?}"),
        }
        assert!(
            parse(&["doctor", "--expect-axes", "9"]).is_err(),
            "at most 8 chips"
        );
        assert!(parse(&["doctor", "--expect-axes", "0"]).is_err());
    }

    #[test]
    fn record_needs_an_axis_and_takes_seconds_and_a_plot() {
        match parse(&["record", "1", "--seconds", "2", "--plot", "out.svg"])
            .unwrap()
            .command
        {
            Command::Record {
                axis,
                seconds,
                plot,
                ..
            } => {
                assert_eq!((axis, seconds), (1, 2.0));
                assert_eq!(plot, Some(PathBuf::from("out.svg")));
            }
            other => panic!("{other:?}"),
        }
    }
}
