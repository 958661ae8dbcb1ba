//! `stepctl`: see docs/stepctl.md and `stepctl --help`.

use std::time::Duration;

use clap::Parser;
use serde_json::json;

use stepctl::app::{self, Ctx};
use stepctl::bus::Bus;
use stepctl::cli::{Cli, Command, Transport};
use stepctl::error::{exit, Error, Result};
use stepctl::modbus::{Rtu, SerialLink, TcpLink};
use stepctl::usb::{HidapiDevice, UsbBus};

fn open(cli: &Cli) -> Result<Box<dyn Bus>> {
    let timeout = Duration::from_millis(cli.conn.timeout_ms);
    let mut bus: Box<dyn Bus> = match cli.transport() {
        Transport::Tcp(addr) => {
            let mut m = Rtu::new(
                TcpLink::connect(&addr, timeout.max(Duration::from_secs(2)))?,
                timeout,
            );
            m.trace = cli.verbose;
            Box::new(m)
        }
        Transport::Serial { path, baud, parity } => {
            let mut m = Rtu::new(SerialLink::open(&path, baud, parity)?, timeout);
            m.trace = cli.verbose;
            Box::new(m)
        }
        Transport::Usb(serial) => {
            let mut u = UsbBus::new(HidapiDevice::open(serial.as_deref())?, timeout);
            u.trace = cli.verbose;
            Box::new(u)
        }
    };
    bus.set_timeout_ms(cli.conn.timeout_ms);
    Ok(bus)
}

fn execute(cli: &Cli) -> Result<app::Output> {
    if let (Command::Scan { .. }, Transport::Usb(_)) = (&cli.command, cli.transport()) {
        return app::scan_usb(&stepctl::usb::list()?);
    }
    let mut bus = open(cli)?;
    let mut ctx = Ctx {
        bus: bus.as_mut(),
        first_id: cli.conn.first_id,
        json: cli.json,
        interactive: app::is_terminal(),
        poll: Duration::from_millis(50),
    };
    app::run(&mut ctx, &cli.command)
}

fn main() {
    let cli = match Cli::try_parse_from(stepctl::cli::group_move_args(std::env::args().collect())) {
        Ok(c) => c,
        Err(e) => {
            // Help and version are not errors; every usage error exits 1.
            let code = if e.use_stderr() {
                exit::USAGE
            } else {
                exit::OK
            };
            let _ = e.print();
            std::process::exit(code);
        }
    };
    match execute(&cli) {
        Ok(out) => {
            let printed = out.json.get("printed").is_some();
            if cli.json {
                if !printed {
                    println!("{}", out.json);
                }
            } else if !out.text.is_empty() {
                println!("{}", out.text);
            }
            if out.code != 0 {
                std::process::exit(out.code);
            }
        }
        Err(e) => {
            eprintln!("stepctl: error: {e}");
            if cli.json {
                println!("{}", error_json(&e));
            }
            std::process::exit(e.exit_code());
        }
    }
}

fn error_json(e: &Error) -> serde_json::Value {
    json!({ "error": {
        "kind": e.kind(),
        "exit_code": e.exit_code(),
        "exception": e.exception_code(),
        "message": e.to_string(),
    }})
}
