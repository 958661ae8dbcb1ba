//! The chip model's own tests: one per rule of the strictness table and per
//! modelling choice, plus random byte streams and motion cross-checks.

extern crate std;

use std::vec;
use std::vec::Vec;

use powerstep01::Direction::{Forward, Reverse};
use powerstep01::MotorStatus;

use super::engine::dist_in_dir;
use super::*;
use crate::datasheet::wrap_22;

const MS: u64 = 1_000_000;
const TICK: u64 = TICK_NS;

fn send(d: &mut Powerstep01, bytes: &[u8]) -> Vec<u8> {
    bytes.iter().map(|b| d.exchange(*b)).collect()
}

/// Send `c` encoded by the model's own command table.
fn cmd(d: &mut Powerstep01, c: Command) -> Vec<u8> {
    send(d, datasheet::encode(&c).as_slice())
}

fn get_status(d: &mut Powerstep01) -> StatusWord {
    let rx = send(d, &[0xD0, 0, 0]);
    StatusWord::from_bytes(rx[1], rx[2])
}

fn get_param(d: &mut Powerstep01, r: Register) -> u32 {
    let a = vocab::address(r);
    let mut tx = vec![0x20 | a];
    let bytes = datasheet::register(a).expect("a register").bytes;
    tx.extend(core::iter::repeat_n(0u8, usize::from(bytes)));
    let rx = send(d, &tx);
    rx[1..].iter().fold(0u32, |a, b| (a << 8) | u32::from(*b))
}

/// Powered up, first GetStatus done (UVLO released), still in HiZ.
fn ready() -> Powerstep01 {
    let mut d = Powerstep01::new();
    get_status(&mut d);
    d.clear_log();
    d
}

/// Advance in `chunk` steps until BUSY is released (at most `limit_ms`).
fn settle(d: &mut Powerstep01, chunk: u64, limit_ms: u64) -> u64 {
    let mut t = 0;
    while d.is_busy() {
        assert!(t < limit_ms * MS, "still busy after {limit_ms} ms");
        d.advance(chunk);
        t += chunk;
    }
    t
}

fn error(d: &Powerstep01) -> bool {
    d.status_word().command_error()
}

// ------------------------------------------------------------ power-up

#[test]
fn power_up_registers_hold_their_table_reset_values() {
    let d = Powerstep01::new();
    for spec in REGISTERS.iter().filter(|r| r.address != addr::STATUS) {
        assert_eq!(d.register_at(spec.address), spec.reset, "{}", spec.name);
    }
    assert!(d.is_hiz());
    assert!(!d.is_busy());
    assert_eq!(d.abs_pos(), 0);
}

#[test]
fn uvlo_reads_asserted_after_power_up_until_the_first_get_status() {
    let mut d = Powerstep01::new();
    let p = StatusWord(get_param(&mut d, Register::Status) as u16);
    assert!(p.uvlo());
    assert_eq!(p.raw(), 0xE413, "HiZ, idle, forward, UVLO low");
    assert!(StatusWord(get_param(&mut d, Register::Status) as u16).uvlo());
    let s = get_status(&mut d);
    assert!(s.uvlo());
    let s = get_status(&mut d);
    assert!(!s.uvlo());
    assert_eq!(s.raw(), 0xE613);
}

// ------------------------------------------------------ failure flags

#[test]
fn set_param_to_a_read_only_register_is_refused_at_the_command_byte() {
    for reg in [Register::Speed, Register::AdcOut, Register::Status] {
        let mut d = ready();
        // SetParam(reg), then what would be its argument is a GetParam(KVAL_HOLD).
        let rx = send(&mut d, &[vocab::address(reg), 0x29, 0x00]);
        assert_eq!(rx, [0x00, 0x00, 0x29], "{reg:?}");
        assert!(error(&d));
        assert_eq!(d.command_errors(), 1);
        assert_eq!(
            d.received().last(),
            Some(&Command::GetParam(Register::KvalHold))
        );
    }
}

#[test]
fn set_param_to_a_non_existent_register_is_refused_at_the_command_byte() {
    for b in [0x1C, 0x1D, 0x1E, 0x1F] {
        let mut d = ready();
        let rx = send(&mut d, &[b, 0x29, 0x00]);
        assert_eq!(rx, [0x00, 0x00, 0x29], "{b:#04x}");
        assert!(error(&d));
        assert_eq!(d.received_count(), 1);
    }
}

#[test]
fn get_param_of_a_non_existent_register_is_an_unknown_command() {
    for b in [0x20, 0x3C, 0x3F] {
        let mut d = ready();
        assert_eq!(send(&mut d, &[b, 0x00]), [0, 0]);
        assert!(error(&d));
    }
}

#[test]
fn ws_register_written_while_moving_is_refused_after_the_last_argument() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 20_000));
    d.advance(MS);
    send(&mut d, &[0x05]); // SetParam(ACC)
    assert!(!error(&d));
    send(&mut d, &[0x01]);
    assert!(!error(&d));
    send(&mut d, &[0x23]);
    assert!(error(&d), "refused after the last argument byte");
    assert_eq!(d.register(Register::Acc), 0x08A);
    assert_eq!(d.command_errors(), 1);
    // Stopped: accepted.
    cmd(&mut d, Command::HardStop);
    get_status(&mut d);
    cmd(&mut d, Command::SetParam(Register::Acc, 0x123));
    assert!(!error(&d));
    assert_eq!(d.register(Register::Acc), 0x123);
}

#[test]
fn wh_register_written_while_not_in_hiz_is_refused() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::StepMode, 0x04));
    assert!(!error(&d));
    assert_eq!(d.register(Register::StepMode), 0x04);
    cmd(&mut d, Command::HardStop); // bridges on, motor stopped
    assert!(!d.is_hiz());
    send(&mut d, &[0x16]);
    assert!(!error(&d));
    send(&mut d, &[0x02]);
    assert!(error(&d));
    assert_eq!(d.register(Register::StepMode), 0x04);
    cmd(&mut d, Command::SetParam(Register::Config, 0x2C98));
    assert_eq!(d.register(Register::Config), 0x2C88);
    assert_eq!(d.command_errors(), 2);
    cmd(&mut d, Command::HardHiZ);
    cmd(&mut d, Command::SetParam(Register::Config, 0x2C98));
    assert_eq!(d.register(Register::Config), 0x2C98);
}

#[test]
fn el_pos_is_writable_in_hiz_only() {
    // AN4290 Table 4 classes EL_POS "writable when in HiZ only" (the DS
    // access column says WS): stopped with the bridges on is not enough.
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::ElPos, 0x80));
    assert!(!error(&d));
    assert_eq!(d.register(Register::ElPos), 0x80);
    cmd(&mut d, Command::HardStop);
    assert!(d.is_stopped() && !d.is_hiz());
    cmd(&mut d, Command::SetParam(Register::ElPos, 0x100));
    assert!(error(&d), "stopped but not in HiZ: refused");
    assert_eq!(d.register(Register::ElPos), 0x80);
}

#[test]
fn a_response_producing_command_abandons_the_pending_response() {
    let mut d = ready();
    d.set_register_raw(Register::AbsPos, 0x12_3456);
    // GetParam(ABS_POS), then GetParam(KVAL_HOLD) before the first response is out.
    let rx = send(&mut d, &[0x21, 0x29, 0x00, 0x00]);
    assert_eq!(rx, [0x00, 0x12, 0x29, 0x00]);
}

#[test]
fn commands_without_response_do_not_disturb_a_pending_response() {
    let mut d = ready();
    d.set_register_raw(Register::AbsPos, 0x12_3456);
    let rx = send(&mut d, &[0x21, 0x51, 0x00, 0x10, 0x00, 0x00]);
    assert_eq!(rx, [0x00, 0x12, 0x34, 0x56, 0x00, 0x00]);
    assert_eq!(d.received().last(), Some(&Command::Run(Forward, 0x1000)));
}

#[test]
fn get_param_value_is_captured_when_the_command_byte_is_decoded() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 50_000));
    d.advance(100 * MS);
    let at_decode = d.abs_pos();
    assert!(at_decode > 0);
    send(&mut d, &[0x21]);
    d.advance(100 * MS);
    let rx = send(&mut d, &[0, 0, 0]);
    let v = rx.iter().fold(0u32, |a, b| (a << 8) | u32::from(*b));
    assert_eq!(sign_extend_22(v), at_decode);
    assert!(d.abs_pos() > at_decode);
}

#[test]
fn get_status_clears_latched_flags_but_get_param_status_does_not() {
    let mut d = ready();
    send(&mut d, &[0xEB]);
    d.set_switch(true);
    d.inject(Fault::Stall);
    d.inject(Fault::Overcurrent);
    d.inject(Fault::Uvlo);
    for _ in 0..2 {
        let p = StatusWord(get_param(&mut d, Register::Status) as u16);
        assert!(p.command_error() && p.switch_event() && p.stalled());
        assert!(p.overcurrent() && p.uvlo());
    }
    let s = get_status(&mut d);
    assert!(s.command_error() && s.switch_event() && s.stalled());
    assert!(s.overcurrent() && s.uvlo());
    let s = get_status(&mut d);
    assert!(!s.command_error() && !s.switch_event() && !s.stalled());
    assert!(!s.overcurrent() && !s.uvlo());
    assert!(s.switch_closed(), "SW_F is a level, not a latch");
}

#[test]
fn latched_thermal_status_stays_while_the_condition_persists() {
    let mut d = ready();
    d.inject(Fault::ThermalWarning);
    assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Warning);
    assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Warning);
    d.inject(Fault::ThermalNormal);
    assert_eq!(d.status_word().thermal(), ThermalStatus::Warning, "latched");
    assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Warning);
    assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Normal);
}

#[test]
fn move_while_moving_is_refused() {
    let mut d = ready();
    cmd(&mut d, Command::Move(Forward, 100_000));
    d.advance(10 * MS);
    let pos = d.abs_pos();
    cmd(&mut d, Command::Move(Reverse, 5));
    assert!(error(&d));
    assert!(d.is_busy());
    settle(&mut d, 10 * MS, 600_000);
    assert_eq!(d.abs_pos(), 100_000);
    assert!(pos > 0);
}

#[test]
fn move_while_running_at_constant_speed_is_refused() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 10_000));
    d.advance(500 * MS);
    assert!(!d.is_busy(), "Run at target speed releases BUSY");
    cmd(&mut d, Command::Move(Forward, 5));
    assert!(error(&d));
}

#[test]
fn goto_family_while_busy_is_refused() {
    let mut d = ready();
    cmd(&mut d, Command::Move(Forward, 100_000));
    d.advance(MS);
    for c in [
        Command::GoTo(5),
        Command::GoToDir(Reverse, 5),
        Command::GoHome,
        Command::GoMark,
    ] {
        let before = d.command_errors();
        cmd(&mut d, c);
        assert_eq!(d.command_errors(), before + 1, "{c:?}");
    }
    settle(&mut d, 10 * MS, 600_000);
    assert_eq!(d.abs_pos(), 100_000);
}

#[test]
fn unknown_byte_sets_cmd_error_and_consumes_no_arguments() {
    for b in [0xEB, 0xF8, 0xFF, 0x61, 0x80, 0xE0] {
        let mut d = ready();
        let rx = send(&mut d, &[b, 0x29, 0x00]);
        assert_eq!(rx, [0x00, 0x00, 0x29], "{b:#04x}");
        assert!(error(&d));
    }
}

#[test]
fn a_half_received_command_swallows_the_next_bytes() {
    let mut d = ready();
    send(&mut d, &[0x51]); // Run forward: 3 argument bytes pending
    let rx = send(&mut d, &[0x29, 0xD0, 0x00]); // GetParam, GetStatus, NOP...
    assert_eq!(rx, [0, 0, 0], "no response: they were arguments");
    assert_eq!(d.received_count(), 1);
    assert_eq!(d.received().last(), Some(&Command::Run(Forward, 0x9_D000)));
    assert!(!d.received().any(|c| *c == Command::GetStatus));
    assert!(!error(&d));
}

#[test]
fn reset_device_outside_hiz_is_refused() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::KvalRun, 0x40));
    cmd(&mut d, Command::HardStop);
    cmd(&mut d, Command::ResetDevice);
    assert!(error(&d));
    assert_eq!(d.register(Register::KvalRun), 0x40);
    assert!(!d.status_word().uvlo());
}

#[test]
fn reset_device_in_hiz_restores_the_power_up_state() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::KvalRun, 0x40));
    cmd(&mut d, Command::Move(Forward, 1000));
    settle(&mut d, MS, 10_000);
    cmd(&mut d, Command::HardHiZ);
    cmd(&mut d, Command::ResetDevice);
    assert!(!error(&d));
    assert_eq!(d.register(Register::KvalRun), 0x29);
    assert_eq!(d.abs_pos(), 0);
    assert!(d.is_hiz());
    assert!(get_status(&mut d).uvlo());
}

#[test]
fn register_writes_are_masked_to_the_register_width() {
    let mut d = ready();
    send(&mut d, &[0x05, 0xFF, 0xFF]);
    assert_eq!(d.register(Register::Acc), 0xFFF);
    send(&mut d, &[0x03, 0xFF, 0xFF, 0xFF]);
    assert_eq!(d.register(Register::Mark), 0x3F_FFFF);
    send(&mut d, &[0x11, 0xFF]);
    assert_eq!(d.register(Register::KTherm), 0xF);
    assert!(!error(&d));
}

#[test]
fn receive_log_keeps_the_last_32_commands() {
    let mut d = ready();
    d.clear_log();
    for i in 0..40u32 {
        cmd(&mut d, Command::SetParam(Register::Mark, i));
    }
    assert_eq!(d.received_count(), 40);
    let log: Vec<_> = d.received().copied().collect();
    assert_eq!(log.len(), LOG_LEN);
    assert_eq!(log[0], Command::SetParam(Register::Mark, 8));
    assert_eq!(log[31], Command::SetParam(Register::Mark, 39));
}

#[test]
fn random_byte_streams_never_panic() {
    let mut rng = Rng(0x1234_5678_9ABC_DEF1);
    for _ in 0..20 {
        let mut d = Powerstep01::new();
        for i in 0..5_000u32 {
            let b = rng.next() as u8;
            d.exchange(b);
            if i % 7 == 0 {
                d.advance(rng.below(50 * MS));
            }
            if i % 97 == 0 {
                d.set_switch(rng.next() & 1 == 1);
            }
            if i % 131 == 0 {
                d.step_clock_pulse();
            }
        }
        d.advance(u64::MAX);
        d.advance(u64::MAX);
        let _ = d.status();
    }
}

// -------------------------------------------------------------- motion

/// Deterministic xorshift64*.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: u64) -> u64 {
        if n == 0 {
            0
        } else {
            self.next() % n
        }
    }
    fn range(&mut self, lo: u64, hi: u64) -> u64 {
        lo + self.below(hi - lo + 1)
    }
}

#[test]
fn run_reaches_speed_after_the_analytic_acceleration_time() {
    let mut d = ready();
    let spd = 33_554u32; // ≈ 500 step/s
    cmd(&mut d, Command::Run(Forward, spd));
    // Speed rises by ACC (2⁻⁴⁰ step/tick²) per tick; SPD is 2⁻²⁸ step/tick.
    let acc = 0x08Au64;
    let analytic = (u64::from(spd) << 12) as f64 / acc as f64; // ticks
    let whole = analytic.floor() as u64;
    d.advance((whole - 1) * TICK);
    assert!(d.is_busy());
    assert_eq!(d.status_word().motor_status(), MotorStatus::Accelerating);
    d.advance(2 * TICK);
    assert!(!d.is_busy());
    assert_eq!(d.speed_reg(), spd);
    assert_eq!(d.status_word().motor_status(), MotorStatus::ConstantSpeed);
    // The speed ramp itself is exact: v = k·ACC after k ticks.
    let mut e = ready();
    cmd(&mut e, Command::Run(Forward, spd));
    e.advance(1000 * TICK);
    assert_eq!(e.speed_internal(), 1000 * acc);
}

#[test]
fn run_speed_is_clamped_to_min_and_max_speed() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::MinSpeed, 0x100));
    cmd(&mut d, Command::Run(Forward, 0xF_FFFF));
    d.advance(2000 * MS);
    assert_eq!(d.speed_internal(), 0x041 << 22, "MAX_SPEED");
    cmd(&mut d, Command::Run(Forward, 1));
    d.advance(2000 * MS);
    assert_eq!(d.speed_internal(), 0x100 << 16, "MIN_SPEED");
}

#[test]
fn speeds_count_full_steps_and_positions_microsteps() {
    for ss in [0u32, 4, 7] {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::StepMode, ss));
        cmd(&mut d, Command::SetParam(Register::Acc, 0xFFF)); // infinite
                                                              // 0x10000 SPEED units = 2⁻¹² step/tick = 976.5625 step/s exactly.
        cmd(&mut d, Command::Run(Forward, 0x1_0000));
        d.advance(1_000 * MS); // 4 000 000 ticks
        assert_eq!(
            i64::from(d.abs_pos()),
            (4_000_000i64 << ss) >> 12,
            "STEP_SEL {ss}"
        );
    }
}

#[test]
fn abs_pos_wraps_at_22_bits() {
    let mut d = ready();
    cmd(
        &mut d,
        Command::SetParam(Register::AbsPos, wrap_22((1 << 21) - 10)),
    );
    cmd(&mut d, Command::Move(Forward, 20));
    settle(&mut d, MS, 10_000);
    assert_eq!(d.abs_pos(), -(1 << 21) + 10);
    assert_eq!(get_param(&mut d, Register::AbsPos), 0x20_000A);
    cmd(&mut d, Command::ResetPos);
    cmd(&mut d, Command::Move(Reverse, 1));
    settle(&mut d, MS, 10_000);
    assert_eq!(get_param(&mut d, Register::AbsPos), 0x3F_FFFF);
    assert_eq!(d.abs_pos(), -1);
}

/// Drive one positioning command to its end, checking it never passes
/// the target and never exceeds MAX_SPEED. Returns the time taken.
fn land(d: &mut Powerstep01, dir: Direction, target: u32, rng: &mut Rng) -> u64 {
    let vmax = d.vmax();
    let mut left = dist_in_dir(dir, d.abs_raw(), target);
    let mut t = 0u64;
    while d.is_busy() {
        let chunk = rng.range(MS, 60 * MS) + rng.below(250);
        d.advance(chunk);
        t += chunk;
        let now = dist_in_dir(dir, d.abs_raw(), target);
        assert!(now <= left, "passed the target: {left} -> {now}");
        assert!(d.speed_internal() <= vmax.max(d.floor()));
        left = now;
        assert!(t < 3_600_000 * MS, "move does not end");
    }
    assert_eq!(d.abs_raw(), target);
    assert_eq!(d.speed_reg(), 0);
    assert_eq!(d.status_word().motor_status(), MotorStatus::Stopped);
    assert!(!error(d));
    t
}

#[test]
fn go_to_and_move_land_exactly_on_random_targets() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    for _ in 0..300 {
        let mut d = ready();
        let ss = rng.below(8) as u32;
        cmd(&mut d, Command::SetParam(Register::StepMode, ss));
        cmd(
            &mut d,
            Command::SetParam(Register::MaxSpeed, rng.range(0x10, 0x3FF) as u32),
        );
        let acc = if rng.below(10) == 0 {
            0xFFF
        } else {
            rng.range(0x10, 0xFFE)
        };
        cmd(&mut d, Command::SetParam(Register::Acc, acc as u32));
        cmd(
            &mut d,
            Command::SetParam(Register::Dec, rng.range(0x10, 0xFFE) as u32),
        );
        let min = match rng.below(3) {
            0 => 0,
            1 => rng.below(0x100),
            _ => rng.below(0x2000), // with LSPD_OPT sometimes set
        };
        cmd(&mut d, Command::SetParam(Register::MinSpeed, min as u32));
        cmd(
            &mut d,
            Command::SetParam(Register::AbsPos, rng.next() as u32),
        );
        assert!(!error(&d));
        // At most ~20 000 full steps so the test stays fast.
        let span = (20_000u64 << ss).min(1 << 21);
        let dist = if rng.below(8) == 0 {
            rng.below(4)
        } else {
            rng.below(span)
        };
        let pos = d.abs_raw();
        let (c, dir, target) = match rng.below(3) {
            0 => {
                let dir = if rng.next() & 1 == 0 {
                    Forward
                } else {
                    Reverse
                };
                let t = match dir {
                    Forward => pos.wrapping_add(dist as u32),
                    Reverse => pos.wrapping_sub(dist as u32),
                } & POS_MASK;
                (Command::Move(dir, dist as u32), dir, t)
            }
            1 => {
                let delta = if rng.next() & 1 == 0 {
                    dist as i64
                } else {
                    -(dist as i64)
                };
                let t = wrap_22((i64::from(sign_extend_22(pos)) + delta) as i32);
                let dir = if delta >= 0 { Forward } else { Reverse };
                (Command::GoTo(sign_extend_22(t)), dir, t)
            }
            _ => {
                let t = (rng.next() as u32) & POS_MASK;
                let dir = if rng.next() & 1 == 0 {
                    Forward
                } else {
                    Reverse
                };
                // Keep the forced path short enough.
                let t = if dist_in_dir(dir, pos, t) > span {
                    match dir {
                        Forward => pos.wrapping_add(dist as u32) & POS_MASK,
                        Reverse => pos.wrapping_sub(dist as u32) & POS_MASK,
                    }
                } else {
                    t
                };
                (Command::GoToDir(dir, sign_extend_22(t)), dir, t)
            }
        };
        cmd(&mut d, c);
        assert!(!error(&d), "{c:?}");
        land(&mut d, dir, target, &mut rng);
    }
}

/// (ABS_POS, speed, STATUS, EL_POS) at a time.
fn snapshot(d: &Powerstep01) -> (i32, u64, u16, u32) {
    (
        d.abs_pos(),
        d.speed_internal(),
        d.status_word().raw(),
        d.register(Register::ElPos),
    )
}

/// A scenario with several phase changes, sampled every 7 ms; `chunk`
/// is how `advance` is sliced between samples.
fn scenario(chunk: u64) -> Vec<(i32, u64, u16, u32)> {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::StepMode, 4));
    cmd(&mut d, Command::SetParam(Register::MinSpeed, 0x40));
    cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x80));
    cmd(&mut d, Command::Move(Forward, 123_457));
    let mut out = Vec::new();
    for sample in 0..2_300u64 {
        let mut left = 7 * MS;
        while left > 0 {
            let c = chunk.min(left);
            d.advance(c);
            left -= c;
        }
        out.push(snapshot(&d));
        match sample {
            // Retarget, reverse, run, stop: commands at the same instants.
            800 => {
                cmd(&mut d, Command::GoTo(-5_000));
            }
            1_600 => {
                cmd(&mut d, Command::Run(Forward, 30_000));
            }
            1_800 => {
                cmd(&mut d, Command::GoTo(-77));
            }
            2_250 => {
                cmd(&mut d, Command::SoftStop);
            }
            _ => {}
        }
    }
    out
}

#[test]
fn slicing_advance_in_1_ms_or_7_ms_chunks_gives_the_same_motion() {
    let a = scenario(MS);
    let b = scenario(7 * MS);
    let c = scenario(333_333);
    assert_eq!(a, b);
    assert_eq!(a, c);
    // The scenario really moved and landed.
    assert!(a.iter().any(|s| s.0 == 123_457));
    assert!(a.iter().any(|s| s.0 == -5_000));
    assert_eq!(a.last().map(|s| (s.0, s.1)), Some((-77, 0)));
}

#[test]
fn long_runs_at_full_speed_do_not_overflow_or_depend_on_slicing() {
    let mut a = ready();
    let mut b = ready();
    for d in [&mut a, &mut b] {
        cmd(d, Command::SetParam(Register::MaxSpeed, 0x3FF));
        cmd(d, Command::Run(Reverse, 0xF_FFFF));
    }
    a.advance(3_600_000 * MS);
    for _ in 0..3_600 {
        b.advance(1_000 * MS);
    }
    assert_eq!(snapshot(&a), snapshot(&b));
    assert_eq!(a.speed_internal(), 0x3FF << 22);
}

#[test]
fn soft_stop_decelerates_with_dec() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::Dec, 0x100));
    cmd(&mut d, Command::Run(Forward, 40_000));
    settle(&mut d, MS, 10_000);
    let v0 = d.speed_internal();
    cmd(&mut d, Command::SoftStop);
    assert!(d.is_busy());
    d.advance(1_000 * TICK);
    assert_eq!(d.speed_internal(), v0 - 1_000 * 0x100);
    assert_eq!(d.status_word().motor_status(), MotorStatus::Decelerating);
    let n = v0 / 0x100; // ticks until below one DEC step
    d.advance((n - 1_000 - 1) * TICK);
    assert!(d.is_busy());
    d.advance(TICK);
    assert!(!d.is_busy());
    assert_eq!(d.speed_reg(), 0);
    assert!(!d.is_hiz(), "SoftStop holds");
    let p = d.abs_pos();
    d.advance(100 * MS);
    assert_eq!(d.abs_pos(), p);
}

#[test]
fn soft_hiz_decelerates_then_releases_the_bridges() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    settle(&mut d, MS, 10_000);
    cmd(&mut d, Command::SoftHiZ);
    assert!(!d.is_hiz());
    settle(&mut d, MS, 10_000);
    assert!(d.is_hiz());
    assert_eq!(d.speed_reg(), 0);
}

#[test]
fn hard_stop_stops_at_once() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(300 * MS);
    assert!(d.speed_reg() > 0);
    cmd(&mut d, Command::HardStop);
    assert_eq!(d.speed_reg(), 0);
    assert!(!d.is_busy());
    assert!(!d.is_hiz());
    let p = d.abs_pos();
    d.advance(100 * MS);
    assert_eq!(d.abs_pos(), p);
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(MS);
    cmd(&mut d, Command::HardHiZ);
    assert_eq!(d.speed_reg(), 0);
    assert!(d.is_hiz());
}

#[test]
fn stop_commands_in_hiz_enable_the_bridges_without_moving() {
    let mut d = ready();
    cmd(&mut d, Command::SoftStop);
    assert!(!d.is_hiz());
    assert!(!d.is_busy());
    cmd(&mut d, Command::HardHiZ);
    cmd(&mut d, Command::HardStop);
    assert!(!d.is_hiz());
    assert_eq!(d.abs_pos(), 0);
}

#[test]
fn a_wh_register_write_after_a_wake_in_the_same_batch_is_refused() {
    // In one control tick's batch a chip executes its commands in order:
    // a HardStop that ends HiZ, then a WH write, is the write to a chip
    // whose bridges are on.
    let mut d = ready();
    assert!(d.is_hiz());
    let mut chain = crate::SimChain::new(1);
    *chain.device_mut(0).expect("chip") = d.clone();
    for c in [
        Command::HardStop,
        Command::SetParam(Register::GateCfg1, 0x111),
    ] {
        for b in datasheet::encode(&c).as_slice() {
            let mut rx = [0u8];
            chain.transfer(&[*b], &mut rx);
        }
    }
    d = chain.device(0).expect("chip").clone();
    assert!(error(&d), "CMD_ERROR");
    assert_eq!(d.register(Register::GateCfg1), 0, "the value is not taken");
}

fn sw_user_mode(d: &mut Powerstep01) {
    cmd(
        d,
        Command::SetParam(Register::Config, 0x2C88 | config::SW_MODE),
    );
}

#[test]
fn go_until_resets_abs_pos_on_switch_closing_then_soft_stops() {
    let mut d = ready();
    sw_user_mode(&mut d);
    cmd(
        &mut d,
        Command::GoUntil(SwitchAction::ResetAbsPos, Forward, 20_000),
    );
    d.advance(500 * MS);
    assert!(d.is_busy(), "GoUntil keeps BUSY low while searching");
    assert!(d.abs_pos() > 0);
    let v = d.speed_internal();
    d.set_switch(true);
    assert_eq!(d.abs_pos(), 0);
    assert_eq!(d.speed_internal(), v, "soft stop: no speed jump");
    assert!(d.status_word().switch_event());
    settle(&mut d, MS, 10_000);
    assert_eq!(d.speed_reg(), 0);
    assert!(d.abs_pos() > 0, "decelerated past the switch");
    assert!(!d.is_hiz());
}

#[test]
fn go_until_copies_abs_pos_to_mark_with_act_1() {
    let mut d = ready();
    sw_user_mode(&mut d);
    cmd(
        &mut d,
        Command::GoUntil(SwitchAction::CopyToMark, Reverse, 20_000),
    );
    d.advance(500 * MS);
    let p = d.abs_pos();
    assert!(p < 0);
    d.set_switch(true);
    assert_eq!(sign_extend_22(d.register(Register::Mark)), p);
    settle(&mut d, MS, 10_000);
    assert!(d.abs_pos() < p);
}

#[test]
fn go_until_hard_stops_when_sw_mode_is_0() {
    let mut d = ready();
    cmd(
        &mut d,
        Command::GoUntil(SwitchAction::ResetAbsPos, Forward, 20_000),
    );
    d.advance(500 * MS);
    d.set_switch(true);
    assert_eq!(d.abs_pos(), 0);
    assert_eq!(d.speed_reg(), 0);
    assert!(!d.is_busy());
}

#[test]
fn release_sw_runs_slowly_until_the_switch_opens_then_hard_stops() {
    let mut d = ready();
    sw_user_mode(&mut d);
    d.set_switch(true);
    cmd(
        &mut d,
        Command::ReleaseSw(SwitchAction::CopyToMark, Reverse),
    );
    d.advance(1_000 * MS);
    assert!(d.is_busy());
    assert_eq!(d.speed_reg(), 335, "5 step/s");
    let p = d.abs_pos();
    // 5 step/s · 128 microsteps for ~1 s (acceleration takes ~2.5 ms).
    assert!((-640..=-630).contains(&p), "{p}");
    d.set_switch(false);
    assert_eq!(sign_extend_22(d.register(Register::Mark)), p);
    assert_eq!(d.speed_reg(), 0);
    assert!(!d.is_busy());
    d.advance(100 * MS);
    assert_eq!(d.abs_pos(), p);
}

#[test]
fn release_sw_uses_min_speed_when_it_is_faster() {
    let mut d = ready();
    sw_user_mode(&mut d);
    cmd(&mut d, Command::SetParam(Register::MinSpeed, 0x200)); // ≈ 122 step/s
    d.set_switch(true);
    cmd(
        &mut d,
        Command::ReleaseSw(SwitchAction::ResetAbsPos, Forward),
    );
    d.advance(100 * MS);
    assert_eq!(d.speed_internal(), 0x200 << 16);
    d.set_switch(false);
    assert_eq!(d.abs_pos(), 0);
}

#[test]
fn switch_closing_hard_stops_the_motor_when_sw_mode_is_0() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(300 * MS);
    d.set_switch(true);
    assert_eq!(d.speed_reg(), 0);
    assert!(!d.is_busy());
    let s = d.status();
    assert!(s.switch_event() && s.switch_closed());
}

#[test]
fn switch_closing_only_latches_the_event_when_sw_mode_is_1() {
    let mut d = ready();
    sw_user_mode(&mut d);
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(300 * MS);
    let v = d.speed_internal();
    d.set_switch(true);
    assert_eq!(d.speed_internal(), v);
    assert!(d.status_word().switch_event());
    d.set_switch(false);
    assert!(!d.status_word().switch_closed());
    assert!(d.status_word().switch_event(), "latched");
}

#[test]
fn run_in_the_opposite_direction_decelerates_then_reverses() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    settle(&mut d, MS, 10_000);
    let v0 = d.speed_internal();
    cmd(&mut d, Command::Run(Reverse, 40_000));
    assert!(d.is_busy());
    assert_eq!(d.status_word().direction(), Forward);
    assert_eq!(d.status_word().motor_status(), MotorStatus::Decelerating);
    d.advance(1_000 * TICK);
    assert_eq!(d.speed_internal(), v0 - 1_000 * 0x08A);
    let peak = d.abs_pos();
    settle(&mut d, MS, 10_000);
    assert_eq!(d.status_word().direction(), Reverse);
    assert_eq!(d.speed_internal(), v0);
    let p = d.abs_pos();
    assert!(p < peak + 10_000);
    d.advance(100 * MS);
    assert!(d.abs_pos() < p);
}

#[test]
fn go_to_takes_the_shortest_path_across_the_wrap() {
    let mut d = ready();
    cmd(
        &mut d,
        Command::SetParam(Register::AbsPos, wrap_22((1 << 21) - 100)),
    );
    cmd(&mut d, Command::GoTo(-(1 << 21) + 100));
    assert_eq!(d.status_word().direction(), Forward);
    let mut rng = Rng(7);
    land(&mut d, Forward, wrap_22(-(1 << 21) + 100), &mut rng);
    cmd(&mut d, Command::GoTo((1 << 21) - 100));
    assert_eq!(d.status_word().direction(), Reverse);
    land(&mut d, Reverse, wrap_22((1 << 21) - 100), &mut rng);
}

#[test]
fn go_to_dir_forces_the_direction() {
    let mut d = ready();
    cmd(&mut d, Command::GoToDir(Reverse, 10)); // 2²² − 10 microsteps the long way
    assert_eq!(d.status_word().direction(), Reverse);
    let mut rng = Rng(11);
    land(&mut d, Reverse, 10, &mut rng);
}

#[test]
fn go_home_and_go_mark_go_to_zero_and_mark() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::Mark, wrap_22(-3_000)));
    cmd(&mut d, Command::GoMark);
    let mut rng = Rng(3);
    land(&mut d, Reverse, wrap_22(-3_000), &mut rng);
    cmd(&mut d, Command::GoHome);
    land(&mut d, Forward, 0, &mut rng);
}

#[test]
fn go_to_while_running_away_brakes_reverses_and_lands_exactly() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    settle(&mut d, MS, 10_000);
    let p = d.abs_pos();
    cmd(&mut d, Command::GoTo(p - 1_000));
    assert!(!error(&d), "accepted: BUSY was released");
    assert!(d.is_busy());
    let mut max = p;
    while d.is_busy() {
        d.advance(MS);
        max = max.max(d.abs_pos());
    }
    assert!(max > p, "kept going forward while braking");
    assert_eq!(d.abs_pos(), p - 1_000);
    assert_eq!(d.speed_reg(), 0);
}

#[test]
fn go_to_too_close_ahead_while_running_stops_on_the_target() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    settle(&mut d, MS, 10_000);
    let p = d.abs_pos();
    cmd(&mut d, Command::GoTo(p + 10));
    settle(&mut d, MS, 10_000);
    assert_eq!(d.abs_pos(), p + 10);
}

#[test]
fn positioning_arrives_slowly_and_brakes_with_dec() {
    for (min, dec) in [(0u32, 0x08Au64), (0x100, 0x08A), (0, 0xFFE), (0x40, 0x200)] {
        let mut d = ready();
        cmd(&mut d, Command::SetParam(Register::MinSpeed, min));
        cmd(&mut d, Command::SetParam(Register::Dec, dec as u32));
        cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x3FF));
        cmd(&mut d, Command::Move(Forward, 400_000));
        while d.status_word().motor_status() != MotorStatus::Decelerating {
            d.advance(MS);
        }
        // Tick by tick while braking: speed falls by exactly DEC per tick.
        let mut last = d.speed_internal();
        while d.is_busy() {
            d.advance(TICK);
            let v = d.speed_internal();
            if v > 0 && v > d.floor() {
                assert_eq!(last - v, dec);
            }
            if v > 0 {
                last = v;
            }
        }
        assert_eq!(d.abs_pos(), 400_000);
        // Arrival speed: the floor, or a few step/s above it (the
        // braking start is rounded to whole ticks).
        let few_steps_per_s = 20 * 1_099_512; // 20 step/s in 2⁻⁴⁰ step/tick
        assert!(
            last <= d.floor() + few_steps_per_s,
            "min {min:#x} dec {dec:#x}: {last}"
        );
    }
}

#[test]
fn min_speed_is_the_start_speed_and_moves_still_land_exactly() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::MinSpeed, 0x300));
    cmd(&mut d, Command::Move(Forward, 50_000));
    assert_eq!(d.speed_internal(), 0x300 << 16, "starts at MIN_SPEED");
    let mut rng = Rng(5);
    land(&mut d, Forward, 50_000, &mut rng);
}

#[test]
fn lowering_max_speed_while_running_decelerates_to_it() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x80));
    cmd(&mut d, Command::Move(Forward, 1_000_000));
    d.advance(2_000 * MS);
    cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x20));
    assert!(!error(&d), "MAX_SPEED is writable any time");
    assert_eq!(d.status_word().motor_status(), MotorStatus::Decelerating);
    d.advance(2_000 * MS);
    assert_eq!(d.speed_internal(), 0x20 << 22);
    let mut rng = Rng(9);
    land(&mut d, Forward, 1_000_000, &mut rng);
}

#[test]
fn step_clock_pulses_move_one_microstep_each() {
    let mut d = ready();
    cmd(&mut d, Command::StepClock(Reverse));
    assert!(d.status_word().step_clock_mode());
    assert!(!d.is_hiz());
    for _ in 0..5 {
        d.step_clock_pulse();
    }
    assert_eq!(d.abs_pos(), -5);
    cmd(&mut d, Command::HardStop);
    assert!(!d.status_word().step_clock_mode());
    d.step_clock_pulse();
    assert_eq!(d.abs_pos(), -5);
}

#[test]
fn step_clock_while_moving_is_refused() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 1000));
    d.advance(MS);
    cmd(&mut d, Command::StepClock(Forward));
    assert!(error(&d));
    assert!(!d.status_word().step_clock_mode());
}

#[test]
fn el_pos_follows_the_microsteps() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::StepMode, 2)); // 1/4: 32/128 per microstep
    cmd(&mut d, Command::Move(Forward, 5));
    settle(&mut d, MS, 10_000);
    assert_eq!(d.register(Register::ElPos), 5 * 32);
}

// -------------------------------------------------------------- faults

#[test]
fn uvlo_fault_stops_motion_and_puts_bridges_in_hiz() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(100 * MS);
    d.inject(Fault::Uvlo);
    assert!(d.is_hiz());
    assert_eq!(d.speed_reg(), 0);
    assert!(get_status(&mut d).uvlo());
    assert!(!get_status(&mut d).uvlo());
}

#[test]
fn overcurrent_with_oc_sd_goes_hiz_and_locks_the_bridges_until_get_status() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(100 * MS);
    d.inject(Fault::Overcurrent);
    assert!(d.is_hiz());
    assert!(d.status_word().overcurrent());
    cmd(&mut d, Command::Run(Forward, 40_000));
    assert!(error(&d));
    assert!(d.is_hiz());
    assert!(get_status(&mut d).overcurrent());
    cmd(&mut d, Command::Run(Forward, 40_000));
    assert!(!error(&d));
    assert!(!d.is_hiz());
}

#[test]
fn overcurrent_without_oc_sd_only_latches_the_flag() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::Config, 0x2C08));
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(100 * MS);
    d.inject(Fault::Overcurrent);
    assert!(!d.is_hiz());
    assert!(d.speed_reg() > 0);
    assert!(d.status_word().overcurrent());
}

#[test]
fn thermal_shutdown_puts_bridges_in_hiz_until_the_condition_clears() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(100 * MS);
    d.inject(Fault::ThermalShutdown);
    assert!(d.is_hiz());
    assert_eq!(get_status(&mut d).thermal(), ThermalStatus::BridgeShutdown);
    cmd(&mut d, Command::HardStop);
    assert!(error(&d));
    d.inject(Fault::ThermalNormal);
    assert_eq!(get_status(&mut d).thermal(), ThermalStatus::BridgeShutdown);
    assert_eq!(get_status(&mut d).thermal(), ThermalStatus::Normal);
    cmd(&mut d, Command::HardStop);
    assert!(!d.is_hiz());
}

#[test]
fn stall_latches_stall_a_without_stopping() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(100 * MS);
    d.inject(Fault::Stall);
    let s = d.status();
    assert!(s.stall_a() && !s.stall_b());
    assert!(d.speed_reg() > 0);
}

#[test]
fn power_cycle_restores_reset_registers_and_asserts_uvlo() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::Acc, 0x200));
    cmd(&mut d, Command::Run(Forward, 40_000));
    d.advance(100 * MS);
    d.inject(Fault::PowerCycle);
    assert_eq!(d.register(Register::Acc), 0x08A);
    assert_eq!(d.abs_pos(), 0);
    assert_eq!(d.speed_reg(), 0);
    assert!(d.is_hiz());
    assert!(get_status(&mut d).uvlo());
}

#[test]
fn dead_device_drives_its_stuck_byte_and_ignores_input_until_revived() {
    for stuck in [0xFF, 0x00] {
        let mut d = ready();
        cmd(&mut d, Command::Run(Forward, 40_000));
        d.advance(100 * MS);
        d.inject(Fault::Dead(stuck));
        assert!(d.is_dead());
        assert_eq!(send(&mut d, &[0xD0, 0x00, 0x00]), [stuck; 3]);
        assert_eq!(d.speed_reg(), 0);
        let n = d.received_count();
        cmd(&mut d, Command::Run(Forward, 40_000));
        assert_eq!(d.received_count(), n);
        d.inject(Fault::Revive);
        assert!(!d.is_dead());
        let s = get_status(&mut d);
        assert!(
            s.hiz() && s.raw() != 0xFFFF && s.raw() != 0x0000,
            "not stuck"
        );
    }
}

#[test]
fn a_slower_run_decelerates_with_dec_not_at_once() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::MaxSpeed, 0x3FF));
    cmd(&mut d, Command::Run(Forward, 60_000));
    d.advance(2000 * MS);
    assert_eq!(d.speed_reg(), 60_000);
    cmd(&mut d, Command::Run(Forward, 20_000));
    d.advance(1000 * TICK);
    // DEC (0x08A) per tick, never a jump to the new speed.
    assert_eq!(d.speed_internal(), (60_000u64 << 12) - 1000 * 0x08A);
    assert!(d.is_busy());
    assert_eq!(d.status_word().motor_status(), MotorStatus::Decelerating);
}

#[test]
fn a_faster_run_accelerates_with_acc_up_to_max_speed_only() {
    let mut d = ready();
    cmd(&mut d, Command::SetParam(Register::Acc, 0x20));
    cmd(&mut d, Command::Run(Reverse, 0xF_FFFF));
    d.advance(100 * TICK);
    assert_eq!(d.speed_internal(), 100 * 0x20);
    d.advance(10_000 * MS);
    assert_eq!(d.speed_internal(), 0x041 << 22, "clamped to MAX_SPEED");
}

#[test]
fn power_cycle_restores_every_register_including_the_currents() {
    let mut d = ready();
    for (r, v) in [
        (Register::KvalHold, 0x10),
        (Register::KvalRun, 0x80),
        (Register::KvalAcc, 0x80),
        (Register::KvalDec, 0x80),
        (Register::StepMode, 0x04),
        (Register::Config, 0x2C98),
        (Register::OcdTh, 0x1F),
        (Register::MaxSpeed, 0x200),
        (Register::Dec, 0x300),
    ] {
        d.set_register_raw(r, v);
        assert_eq!(d.register(r), v);
    }
    d.inject(Fault::PowerCycle);
    for spec in REGISTERS.iter().filter(|r| r.address != addr::STATUS) {
        assert_eq!(d.register_at(spec.address), spec.reset, "{}", spec.name);
    }
}

#[test]
fn move_is_refused_while_a_run_is_still_accelerating() {
    let mut d = ready();
    cmd(&mut d, Command::Run(Forward, 20_000));
    d.advance(MS);
    assert!(d.is_busy());
    let before = d.command_errors();
    cmd(&mut d, Command::Move(Forward, 100));
    cmd(&mut d, Command::GoTo(100));
    assert_eq!(d.command_errors(), before + 2);
}

#[test]
fn an_oscillator_5_percent_fast_lives_5_percent_more_chip_time() {
    // The same command and caller time: 1 000 000 ticks of 250 ns at 16 MHz,
    // 1 050 000 with the oscillator 5 % fast.
    let mut exact = ready();
    let mut fast = ready();
    fast.set_clock_error_ppm(50_000);
    for d in [&mut exact, &mut fast] {
        cmd(d, Command::SetParam(Register::Acc, 0xFFF));
        cmd(d, Command::Run(Forward, 1 << 20 >> 1));
    }
    exact.advance(1_000_000 * TICK);
    fast.advance(1_000_000 * TICK);
    // Past the (infinite) ramp both run at the same speed: positions scale.
    let (e, f) = (i64::from(exact.abs_pos()), i64::from(fast.abs_pos()));
    let d = |x: i64| x.rem_euclid(1 << 22);
    assert!(e > 0);
    assert!((d(f) * 100 - d(e) * 105).abs() <= 105 * 2, "{e} vs {f}");
}

#[test]
fn the_oscillator_error_is_clamped_to_50_percent() {
    let mut d = ready();
    d.set_clock_error_ppm(i32::MIN);
    cmd(&mut d, Command::SetParam(Register::Acc, 0xFFF));
    cmd(&mut d, Command::Run(Forward, 1 << 16));
    d.advance(1000 * TICK);
    assert!(d.abs_pos() > 0, "time still runs at half speed");
}
