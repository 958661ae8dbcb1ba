//! The extension address space: one map of 16-bit registers, the same on
//! every bus — Modbus addresses with a high byte ≠ 0, I2C commands
//! 0x72/0x73 and USB commands 0xE0/0xE1 carry it. This module is its
//! address map and its error, below the transports (which encode them) and
//! the bridge (which executes accesses: `bridge::ext_space`). Everything here
//! is an extension of this bridge, not PoStep60 behaviour.
//!
//! | block | addresses | what | scope |
//! |---|---|---|---|
//! | chip | 0x01nn | powerSTEP01 register `nn` (0x01..=0x1B), right-aligned; 22/20-bit ones (ABS_POS, MARK, SPEED) in two registers, high word first | axis |
//! | I/O extension | 0x02nn | the Copley-style SPI extension (`crate::ioext::registers`) | bridge |
//! | diagnostics | 0x03nn | counters, timing, reset cause, versions ([`diag`]); a write of any value to 0x0300 clears the counters | bridge |
//! | homing | 0x04nn | start/abort, state, result, parameters ([`homing`]) | axis |
//! | watchdog | 0x05nn | communication watchdog per bus ([`watchdog`]) | bridge |
//! | axis | 0x06nn | signed speed, position, target, state ([`axis`]) | axis |
//! | configured | 0x07nn | what the bridge configures in chip register `nn`, and which registers it configures ([`configured`]) | axis |
//! | coordinated move | 0x08nn | members, targets and path limits of a straight-line move of several axes, start/stop, state, the path queue's waypoints and free space ([`coord`]) | bridge |
//!
//! With no chip detected the bridge still answers on its first address (axis
//! 0 of every bus): the bridge-scope blocks (I/O extension, diagnostics,
//! watchdog) read and write as usual, so a box whose chain is not found can
//! say so; everything of an axis is refused there.

/// Why an extension access was not done.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ExtError {
    /// No such register, a read-only one written, or a quantity that does
    /// not fit (Modbus 02).
    IllegalAddress,
    /// A value out of range (Modbus 03).
    IllegalValue,
    /// Not now: access class, homing not possible, busy (Modbus 04).
    Refused,
    /// The value is being read from the chip: ask again after the next tick.
    NotYet,
}

/// Block (high byte) numbers.
pub mod block {
    pub const CHIP: u8 = 0x01;
    pub const IOEXT: u8 = 0x02;
    pub const DIAG: u8 = 0x03;
    pub const HOMING: u8 = 0x04;
    pub const WATCHDOG: u8 = 0x05;
    pub const AXIS: u8 = 0x06;
    pub const CONFIGURED: u8 = 0x07;
    pub const COORD: u8 = 0x08;
}

/// The block of `address` is the bridge's, not an axis's (the table's
/// scope): a broadcast write to it is executed once, not once per axis (a
/// coordinated move started, a waypoint queued once).
pub fn is_bridge_wide(address: u16) -> bool {
    let [blk, _] = address.to_be_bytes();
    matches!(
        blk,
        block::IOEXT | block::DIAG | block::WATCHDOG | block::COORD
    )
}

/// Diagnostics (0x03nn): u32 counters in two registers, high word first.
pub mod diag {
    pub const MODBUS_FRAMES: u8 = 0x00;
    pub const MODBUS_CRC_ERRORS: u8 = 0x02;
    /// Gaps, bad characters and overruns.
    pub const MODBUS_FRAMING_ERRORS: u8 = 0x04;
    pub const MODBUS_EXCEPTIONS: u8 = 0x06;
    /// Exceptions 01, 02, 03, 04.
    pub const MODBUS_EXCEPTION_01: u8 = 0x08;
    pub const I2C_UNKNOWN: u8 = 0x10;
    pub const I2C_SHORT: u8 = 0x12;
    pub const USB_REPORTS: u8 = 0x14;
    pub const USB_BAD: u8 = 0x16;
    pub const USB_UNKNOWN: u8 = 0x18;
    pub const CHAIN_ERRORS: u8 = 0x1A;
    pub const REFUSED: u8 = 0x1C;
    pub const SAVES: u8 = 0x1E;
    pub const SAVE_ERRORS: u8 = 0x20;
    pub const LIMIT_CLAMPS: u8 = 0x22;
    pub const CHIP_RESETS: u8 = 0x24;
    pub const WATCHDOG_TRIPS: u8 = 0x26;
    pub const UPTIME_S: u8 = 0x28;
    pub const TICK_LAST_US: u8 = 0x2A;
    pub const TICK_MAX_US: u8 = 0x2C;
    pub const TICK_OVERRUNS: u8 = 0x2E;
    /// Chip resets of axis 0..7, one register each.
    pub const CHIP_RESETS_AXIS0: u8 = 0x30;
    pub const CHAIN_LENGTH: u8 = 0x40;
    /// 0 unknown, 1 power-on, 2 reset pin, 3 watchdog, 4 software, 5 brown-out,
    /// 6 low-power.
    pub const RESET_CAUSE: u8 = 0x41;
    /// 0 loaded from the store, 1 store empty, 2 store unreadable.
    pub const SETTINGS_SOURCE: u8 = 0x42;
    /// major · 256 + minor.
    pub const FIRMWARE_VERSION: u8 = 0x43;
    /// u32.
    pub const BUILD_ID: u8 = 0x44;
    /// 0 no save yet, 1 the last save succeeded, 2 it failed, 3 a save is
    /// pending (accepted, written once every axis rests).
    pub const LAST_SAVE: u8 = 0x46;
    /// I2C writes longer than their command (refused), u32.
    pub const I2C_LONG: u8 = 0x47;
    /// The last refused request: axis · 256 + reason (1 wrong mode, 2
    /// asleep, 3 faulted, 4 ignored, 5 unsupported, 6 bad address, 7 busy,
    /// 8 boot mode, 14 in a coordinated move); 0 none since the counters
    /// were cleared.
    pub const LAST_REFUSAL: u8 = 0x49;
    /// 0 the chain works, 1 its last control tick's batch failed, 2 dead
    /// (failed for `bridge::CHAIN_DEAD_TICKS` ticks in a row: STBY held
    /// low until the MCU resets), 3 not detected at boot (no axis).
    pub const CHAIN_STATE: u8 = 0x4A;
    /// The control tick's period in use, µs (the build's rate, or slower
    /// when the chain does not fit it).
    pub const TICK_PERIOD_US: u8 = 0x4B;
    /// Control ticks run since the counters were cleared, u32 (with a host
    /// clock: the measured tick rate).
    pub const TICKS: u8 = 0x4C;
    /// The motor supply as measured, in 0x10's units (72 mV); bridge-wide,
    /// so it reads with no chip too.
    pub const SUPPLY: u8 = 0x4E;
    /// The temperature as measured, in 0x11's units (0.125 °C).
    pub const TEMPERATURE: u8 = 0x4F;
    pub const LEN: usize = 0x50;
}

/// Homing (0x04nn, per axis).
pub mod homing {
    /// Write 1 start, 0 abort; reads the state (0 idle, 1 clearing the
    /// switch, 2 searching, 3 releasing, 4 done, 5 failed).
    pub const COMMAND: u8 = 0x00;
    /// 0 none, 1 switch not found, 2 timeout, 3 switch disabled, 4 aborted,
    /// 5 fault, 6 not ready (moving, asleep, faulted), 7 switch stuck (a
    /// clear or release phase travelled the max travel without the switch
    /// letting go), 8 unbounded (neither max travel nor timeout set).
    pub const RESULT: u8 = 0x01;
    /// 1 while position 0 is the switch edge.
    pub const HOMED: u8 = 0x02;
    /// 0 reverse, 1 forward.
    pub const DIRECTION: u8 = 0x03;
    /// u32 logical steps/s.
    pub const SEARCH_SPEED: u8 = 0x04;
    pub const RELEASE_SPEED: u8 = 0x06;
    /// u32 logical steps per phase (search, clear, release), 0 = no limit.
    pub const MAX_TRAVEL: u8 = 0x08;
    /// s for the whole sequence, 0 = no limit (homing refuses to start with
    /// both 0).
    pub const TIMEOUT_S: u8 = 0x0A;
    /// The PoStep60 end-switch settings of the axis (otherwise only USB
    /// 0x88 / 0xB1 set them): bit 0 enabled, bit 1 normally closed.
    pub const END_SWITCH: u8 = 0x0B;
    pub const LEN: usize = 0x0C;
}

/// Communication watchdog (0x05nn, bridge-wide).
pub mod watchdog {
    /// Timeout ms (0 = off) and action (0 hold, 1 soft stop, 2 bridges
    /// off) of Modbus, I2C, USB: 0x00/0x01, 0x02/0x03, 0x04/0x05.
    pub const MODBUS_TIMEOUT_MS: u8 = 0x00;
    /// Trips of Modbus, I2C, USB (read).
    pub const TRIPS: u8 = 0x06;
    /// Bit per bus: tripped and not heard from since (read).
    pub const TRIPPED: u8 = 0x09;
    pub const LEN: usize = 0x0A;
}

/// Axis state (0x06nn, per axis, read-only).
pub mod axis {
    /// i32 steps/s, signed (0x44 is its magnitude).
    pub const SPEED: u8 = 0x00;
    /// i32 logical steps.
    pub const POSITION: u8 = 0x02;
    pub const TARGET: u8 = 0x04;
    /// 0 setup, 1 idle, 2 streaming, 3 stopping, 4 landing, 5 homing.
    pub const STATE: u8 = 0x06;
    /// i16 microsteps.
    pub const FOLLOWING_ERROR: u8 = 0x07;
    /// The 0x25 fault bits.
    pub const FAULTS: u8 = 0x08;
    /// The chip's STATUS as last read.
    pub const CHIP_STATUS: u8 = 0x09;
    pub const LEN: usize = 0x0A;
}

/// What the bridge configures on the chip of the addressed axis (0x07nn,
/// per axis, read-only): the value it writes, not what the chip holds
/// (0x01nn reads that), so the two can be compared.
pub mod configured {
    /// 0x07nn, nn = 0x01..=0x1B: the value the bridge configures for chip
    /// register nn, right-aligned (every register the bridge configures is
    /// at most 16 bits wide); 0 where it configures none ([`MASK`] says
    /// which). STEP_MODE, CONFIG, the KVAL/TVAL currents, MIN_SPEED and the
    /// tuning registers as the bridge's chip image holds them; MAX_SPEED,
    /// ACC, DEC as last written to the chip (0 before the axis's set-up
    /// wrote them).
    pub const FIRST: u8 = 0x01;
    pub const LAST: u8 = 0x1B;
    /// u32, bit nn set: the bridge configures register nn.
    pub const MASK: u8 = 0x20;
    /// Configured registers the bridge has not yet written since the
    /// chip's last reset or their last change (0: the chip should hold
    /// every value of this block).
    pub const PENDING: u8 = 0x22;
    /// 1 once the axis's set-up is done (MAX_SPEED, ACC, DEC written).
    pub const SET_UP: u8 = 0x23;
    pub const LEN: usize = 0x24;
}

/// A coordinated move (0x08nn, bridge-wide: the axes are named by their
/// chain index, whichever address the access came to).
pub mod coord {
    /// Write 1 to start the move the block describes, 0 to stop it along
    /// its line; reads the state (0 idle, 1 starting, 2 running, 3
    /// stopping, 4 settling, 5 done, 6 aborted).
    pub const COMMAND: u8 = 0x00;
    /// Why the last move ended early: the member's chain index · 256 +
    /// the reason (1 stopped: the group's stop or a member's soft stop,
    /// index 0xFF for the group's; 2 a member stopped at once: a Stop, an
    /// end switch, sleep; 3 overcurrent; 4 thermal shutdown; 5 chip reset;
    /// 6 chain error); 0 none.
    pub const ABORT: u8 = 0x01;
    /// Bit k: chain axis k is a member.
    pub const MEMBERS: u8 = 0x02;
    /// Why the last start or waypoint was refused: 0 none, 1 a move is
    /// under way, 2 a member past the chain or no member, 3 a member not
    /// ready (not at rest, asleep, faulted, homing, or not in position
    /// mode; chain index · 256 + 3), 4 a component longer than 2³² steps,
    /// 5 the queue is full, 6 no move starts or runs.
    pub const REFUSAL: u8 = 0x03;
    /// u32 each: the path's max speed, acceleration, deceleration, in steps
    /// of the member that travels farthest (per s, per s²); 0 = none (the
    /// members' own limits alone set the pace).
    pub const PATH_SPEED: u8 = 0x04;
    pub const PATH_ACC: u8 = 0x06;
    pub const PATH_DEC: u8 = 0x08;
    /// u32: control ticks the line has run (its duration once over).
    pub const TICKS: u8 = 0x0A;
    /// Read-only: waypoints that can still be queued behind the move (a
    /// path, [`WAYPOINT`]; 0 when no move starts or runs).
    pub const QUEUE_FREE: u8 = 0x0C;
    /// Read-only: waypoints the path has passed without stopping (up to
    /// 65 535).
    pub const PASSED: u8 = 0x0D;
    /// i32 each, high word first: the target of chain axis k at 0x10 + 2k,
    /// in that axis's logical steps.
    pub const TARGETS: u8 = 0x10;
    /// Write 1: queue the waypoint written at [`WAYPOINT`] (for a bus that
    /// cannot write every member's pair at once: I2C carries three
    /// registers a write).
    pub const QUEUE: u8 = 0x0E;
    /// i32 each, high word first, chain axis k at 0x20 + 2k: the next
    /// waypoint. One write that holds every member's pair (from the lowest
    /// member's to the highest's; other axes' pairs are kept, not used)
    /// queues it behind the move while it starts or runs, and the path
    /// goes on to it from the last one; a write of fewer pairs keeps them
    /// for [`QUEUE`]. Reads the waypoint written (the last queued one once
    /// it is).
    pub const WAYPOINT: u8 = 0x20;
    pub const LEN: usize = 0x30;
}
