//! Errors a user can act on, and the exit code of each kind.

use std::fmt;

/// Exit codes (docs/stepctl.md): a shell script tests these.
pub mod exit {
    pub const OK: i32 = 0;
    /// Bad arguments, a value out of range, a settings file that does not parse.
    pub const USAGE: i32 = 1;
    /// No connection, no reply, a corrupt reply, no USB device.
    pub const COMMUNICATION: i32 = 2;
    /// The device refused: a Modbus exception or a USB status other than done.
    pub const DEVICE: i32 = 3;
    /// The axis faulted or stopped before its target while stepctl waited.
    pub const FAULT: i32 = 4;
    /// A wait (move, home) did not end within its timeout.
    pub const TIMEOUT: i32 = 5;
    /// `stepctl doctor`: at least one check failed.
    pub const DOCTOR_FAIL: i32 = 6;
}

/// The meaning of a Modbus exception code (docs/modbus.md "Modbus register map").
pub fn exception_meaning(code: u8) -> &'static str {
    match code {
        1 => "illegal function",
        2 => "illegal data address: no such register, the wrong access or the wrong register count",
        3 => "illegal data value: a quantity or byte count out of range",
        4 => "server device failure: the axis cannot do it now (asleep, faulted, wrong driver mode, or busy)",
        _ => "unknown exception",
    }
}

/// The meaning of a USB outcome byte `InDATA[14]` (docs/usb.md).
pub fn usb_status_meaning(status: u8) -> &'static str {
    match status {
        0 => "done",
        1 => "wrong driver mode",
        2 => "axis is asleep",
        3 => "axis is faulted",
        4 => "value ignored",
        5 => "unsupported by this box",
        6 => "bad address",
        7 => "busy (an axis moves or settings are being saved)",
        8 => "the box is in boot mode",
        9 => "no such axis",
        10 => "illegal extension address",
        11 => "illegal extension value",
        12 => "refused now by the extension",
        13 => "the chip did not answer in time",
        14 => "the axis is in a coordinated move (stop it first)",
        _ => "unknown status",
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum Error {
    /// Bad arguments or values, refused before anything is sent.
    Usage(String),
    /// Transport failure: port, connection, timeout, corrupt frame.
    Comm(String),
    /// A Modbus exception: `what` was asked, `reason` what stepctl found out.
    Exception {
        code: u8,
        what: String,
        reason: Option<String>,
    },
    /// A USB command answered with a status other than done.
    Refused { status: u8, what: String },
    /// The axis faulted or stopped short during a wait.
    Fault(String),
    /// A wait ran out of time.
    Timeout(String),
}

impl Error {
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Usage(_) => exit::USAGE,
            Error::Comm(_) => exit::COMMUNICATION,
            Error::Exception { .. } | Error::Refused { .. } => exit::DEVICE,
            Error::Fault(_) => exit::FAULT,
            Error::Timeout(_) => exit::TIMEOUT,
        }
    }

    /// A short machine-readable kind for `--json`.
    pub fn kind(&self) -> &'static str {
        match self {
            Error::Usage(_) => "usage",
            Error::Comm(_) => "communication",
            Error::Exception { .. } => "exception",
            Error::Refused { .. } => "refused",
            Error::Fault(_) => "fault",
            Error::Timeout(_) => "timeout",
        }
    }

    /// The Modbus exception code, if this is one.
    pub fn exception_code(&self) -> Option<u8> {
        match self {
            Error::Exception { code, .. } => Some(*code),
            _ => None,
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Usage(m) | Error::Comm(m) | Error::Fault(m) | Error::Timeout(m) => {
                f.write_str(m)
            }
            Error::Exception { code, what, reason } => {
                write!(f, "{what}: exception {code:02}: ")?;
                match reason {
                    Some(r) => write!(f, "{r}"),
                    None => f.write_str(exception_meaning(*code)),
                }
            }
            Error::Refused { status, what } => {
                write!(
                    f,
                    "{what}: refused, status {status}: {}",
                    usb_status_meaning(*status)
                )
            }
        }
    }
}

impl std::error::Error for Error {}

pub type Result<T> = std::result::Result<T, Error>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_exception_names_its_code_and_meaning() {
        let e = Error::Exception {
            code: 4,
            what: "id 1: set position".into(),
            reason: Some("axis is asleep".into()),
        };
        assert_eq!(
            e.to_string(),
            "id 1: set position: exception 04: axis is asleep"
        );
        assert_eq!(e.exit_code(), exit::DEVICE);
    }

    #[test]
    fn an_exception_without_a_found_reason_gives_the_code_s_meaning() {
        let e = Error::Exception {
            code: 2,
            what: "id 1: read 0x0099".into(),
            reason: None,
        };
        assert!(e.to_string().contains("exception 02: illegal data address"));
    }

    #[test]
    fn every_kind_has_its_documented_exit_code() {
        assert_eq!(Error::Usage(String::new()).exit_code(), 1);
        assert_eq!(Error::Comm(String::new()).exit_code(), 2);
        assert_eq!(
            Error::Refused {
                status: 2,
                what: String::new()
            }
            .exit_code(),
            3
        );
        assert_eq!(Error::Fault(String::new()).exit_code(), 4);
        assert_eq!(Error::Timeout(String::new()).exit_code(), 5);
    }
}
