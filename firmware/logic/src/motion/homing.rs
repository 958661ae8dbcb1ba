//! Homing against the end switch on the chip's SW input: search at one
//! speed, back off at a slow speed, and make the point where the switch
//! releases position 0 — with the chip's own GoUntil / ReleaseSW, so the
//! zero is taken at the switch edge by the chip, not at a read-back two
//! milliseconds late.
//!
//! # The sequence
//!
//! With a normally open switch (closed = pressed, SW_F = 1):
//! 1. *Clear*: if the switch is already closed at the start, ReleaseSW away
//!    from it first (it then stands just off the switch).
//! 2. *Search*: GoUntil(copy to MARK, toward the switch, search speed). The
//!    chip stops itself on the switch's closing edge (SoftStop, CONFIG.SW_MODE
//!    = 1).
//! 3. *Release*: ReleaseSW(reset ABS_POS, away) at the release speed — the
//!    chip's ReleaseSW speed is MIN_SPEED, so the axis writes MIN_SPEED for
//!    this phase (stopped: WS) and 0 again afterwards. On the opening edge
//!    the chip resets ABS_POS and stops.
//!
//! A normally closed switch (pressed = open, SW_F = 0) has the opposite
//! edges: the search runs (Run) and the axis stops it when a STATUS read
//! shows the switch open (every 2 ms: the search speed times 2 ms is its
//! only imprecision); the release is GoUntil(reset ABS_POS, away, release
//! speed), which zeroes on the closing edge; *clear* is the same GoUntil.
//!
//! # Bounds: no phase runs for ever
//!
//! * **Max travel bounds every phase**, each measured from where the phase
//!   began: a search that travels farther fails as *not found*; a clear or
//!   release that travels farther without the switch letting go fails as
//!   *switch stuck* (a stuck contact, a broken normally closed wire, or a
//!   search direction that points away from the cam, so that clearing
//!   drives deeper into it).
//! * **The timeout bounds the whole sequence.**
//! * A sequence with neither bound (max travel 0 and timeout 0) is refused
//!   at the start ([`HomingError::Unbounded`]); the factory settings have a
//!   60 s timeout.
//! * The travel is checked on positions read before a STATUS that shows the
//!   chip still busy and healthy: a chip reset (UVLO, ABS_POS back to 0)
//!   ends homing as a *fault*, never as a travel error.
//! * Once a phase has seen its switch edge (the chip then decelerates or has
//!   stopped), its travel is no longer checked: the stop after a found
//!   switch never fails the search.
//!
//! Every phase starts only once STATUS says the chip is not busy; a Stop,
//! a fault or a chip reset ends homing. However it ends, the axis then rests
//! where the chip stopped until a new motion command (`super::axis`).

use crate::powerstep::commands::{Command, Direction, SwitchAction};

/// Homing parameters (logical steps of the axis's step mode).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HomingParams {
    /// Search toward the switch in this direction.
    pub toward: Direction,
    /// Search speed, chip SPEED register units (0.28 full steps/tick).
    pub search_speed: u32,
    /// Release speed as a MIN_SPEED register value (ReleaseSW's speed) and
    /// as a SPEED value (GoUntil for NC switches).
    pub release_min_speed: u32,
    pub release_speed: u32,
    /// Fail after this many physical microsteps of travel (0 = no limit).
    pub max_travel: u64,
    /// Fail after this many control ticks (0 = no limit).
    pub timeout_ticks: u64,
    /// The switch is normally closed.
    pub nc: bool,
}

/// Where homing is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingState {
    Idle,
    /// Moving off a switch that was pressed at the start.
    Clearing,
    Searching,
    Releasing,
    /// Position 0 is the switch edge; the axis is homed.
    Done,
    Failed(HomingError),
}

/// Why homing failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingError {
    /// The switch was not found within the maximum travel.
    NotFound,
    /// The timeout passed.
    Timeout,
    /// The end switch input is disabled in the settings.
    SwitchDisabled,
    /// A Stop (or another motion command) ended it.
    Aborted,
    /// A chip fault, reset or chain error ended it.
    Fault,
    /// The axis was moving, asleep or not configured.
    NotReady,
    /// A clear or release phase travelled the maximum travel without the
    /// switch letting go.
    SwitchStuck,
    /// Neither a maximum travel nor a timeout is set: refused at the start.
    Unbounded,
}

impl HomingError {
    /// The code the extension registers report.
    pub const fn code(self) -> u16 {
        match self {
            HomingError::NotFound => 1,
            HomingError::Timeout => 2,
            HomingError::SwitchDisabled => 3,
            HomingError::Aborted => 4,
            HomingError::Fault => 5,
            HomingError::NotReady => 6,
            HomingError::SwitchStuck => 7,
            HomingError::Unbounded => 8,
        }
    }
}

impl HomingState {
    /// The code the extension registers report.
    pub const fn code(self) -> u16 {
        match self {
            HomingState::Idle => 0,
            HomingState::Clearing => 1,
            HomingState::Searching => 2,
            HomingState::Releasing => 3,
            HomingState::Done => 4,
            HomingState::Failed(_) => 5,
        }
    }

    pub const fn is_running(self) -> bool {
        matches!(
            self,
            HomingState::Clearing | HomingState::Searching | HomingState::Releasing
        )
    }
}

/// What the chip must be told next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Step {
    /// Send these (in order) now.
    Send([Option<Command>; 2]),
    /// Wait for the chip.
    Wait,
    /// Finished: the chip stands still; ABS_POS is the home frame.
    Finished,
    /// Stop the chip (soft) and fail with this error.
    Fail(HomingError),
}

/// The homing sequence of one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Homing {
    pub(super) params: HomingParams,
    pub(super) state: HomingState,
    /// A phase command was sent and the chip not yet seen idle after it.
    sent: bool,
    /// Chip position (physical microsteps) when the current phase began.
    phase_start: i64,
    started_tick: u64,
}

fn away(d: Direction) -> Direction {
    match d {
        Direction::Forward => Direction::Reverse,
        Direction::Reverse => Direction::Forward,
    }
}

/// What the chip reported, as [`Homing::step`] needs it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Seen {
    /// The last STATUS says BUSY.
    pub busy: bool,
    /// The switch is pressed (NO/NC applied).
    pub pressed: bool,
    /// A STATUS and a position read came after the last command.
    pub fresh: bool,
    /// The position read before that STATUS (physical microsteps).
    pub pos: i64,
}

impl Homing {
    /// Begin at `tick` with the switch `pressed` (as the pin reads, NO/NC
    /// already applied) and the chip at `pos`.
    pub(super) fn start(params: HomingParams, pressed: bool, pos: i64, tick: u64) -> Homing {
        Homing {
            params,
            state: if pressed {
                HomingState::Clearing
            } else {
                HomingState::Searching
            },
            sent: false,
            phase_start: pos,
            started_tick: tick,
        }
    }

    fn clear_cmds(&self) -> [Option<Command>; 2] {
        let p = &self.params;
        let dir = away(p.toward);
        if p.nc {
            [
                Some(Command::GoUntil(
                    SwitchAction::CopyToMark,
                    dir,
                    p.release_speed,
                )),
                None,
            ]
        } else {
            [
                Some(Command::SetParam(
                    crate::powerstep::registers::Register::MinSpeed,
                    p.release_min_speed,
                )),
                Some(Command::ReleaseSw(SwitchAction::CopyToMark, dir)),
            ]
        }
    }

    fn search_cmds(&self) -> [Option<Command>; 2] {
        let p = &self.params;
        let restore_min = Some(Command::SetParam(
            crate::powerstep::registers::Register::MinSpeed,
            0,
        ));
        if p.nc {
            [restore_min, Some(Command::Run(p.toward, p.search_speed))]
        } else {
            [
                restore_min,
                Some(Command::GoUntil(
                    SwitchAction::CopyToMark,
                    p.toward,
                    p.search_speed,
                )),
            ]
        }
    }

    fn release_cmds(&self) -> [Option<Command>; 2] {
        let p = &self.params;
        let dir = away(p.toward);
        if p.nc {
            [
                Some(Command::GoUntil(
                    SwitchAction::ResetAbsPos,
                    dir,
                    p.release_speed,
                )),
                None,
            ]
        } else {
            [
                Some(Command::SetParam(
                    crate::powerstep::registers::Register::MinSpeed,
                    p.release_min_speed,
                )),
                Some(Command::ReleaseSw(SwitchAction::ResetAbsPos, dir)),
            ]
        }
    }

    /// The phase has seen the switch edge it waits for.
    fn edge_seen(&self, pressed: bool) -> bool {
        match self.state {
            HomingState::Searching => pressed,
            _ => !pressed,
        }
    }

    /// One tick: what the chip reported (`seen`), and its position now
    /// (`pos_now`, where a phase that starts now begins), at `tick`.
    pub(super) fn step(&mut self, seen: Seen, pos_now: i64, tick: u64) -> Step {
        let p = self.params;
        if p.timeout_ticks > 0 && tick.saturating_sub(self.started_tick) > p.timeout_ticks {
            return Step::Fail(HomingError::Timeout);
        }
        let cmds = match self.state {
            HomingState::Clearing => self.clear_cmds(),
            HomingState::Searching => self.search_cmds(),
            HomingState::Releasing => self.release_cmds(),
            _ => return Step::Wait,
        };
        if !self.sent {
            self.sent = true;
            self.phase_start = pos_now;
            return Step::Send(cmds);
        }
        if !seen.fresh {
            return Step::Wait;
        }
        let edge = self.edge_seen(seen.pressed);
        if self.state == HomingState::Searching && p.nc && edge {
            // The NC search is a Run (busy only while it accelerates): the
            // axis stops it when the switch opens.
            self.state = HomingState::Releasing;
            self.sent = false;
            return Step::Send([Some(Command::HardStop), None]);
        }
        // Still on the way (a NC search's Run reads not busy at constant
        // speed): bounded by the maximum travel.
        let running = seen.busy || (self.state == HomingState::Searching && p.nc);
        if running {
            let travel = seen.pos.abs_diff(self.phase_start);
            if !edge && p.max_travel > 0 && travel > p.max_travel {
                return Step::Fail(match self.state {
                    HomingState::Searching => HomingError::NotFound,
                    _ => HomingError::SwitchStuck,
                });
            }
            return Step::Wait;
        }
        // The chip finished the phase.
        match self.state {
            HomingState::Clearing if edge => {
                self.state = HomingState::Searching;
                self.sent = false;
                Step::Wait
            }
            HomingState::Searching if edge => {
                self.state = HomingState::Releasing;
                self.sent = false;
                Step::Wait
            }
            // Stopped without the switch (e.g. by a limit).
            HomingState::Searching => Step::Fail(HomingError::NotFound),
            HomingState::Releasing if edge => {
                self.state = HomingState::Done;
                Step::Finished
            }
            // Stopped on the switch.
            _ => Step::Fail(HomingError::SwitchStuck),
        }
    }
}
