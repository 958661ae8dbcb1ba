//! Chain framing against the simulated daisy chain (issue: foundation).
//!
//! Random per-device command batches on chains of 1..=8 simulated
//! powerSTEP01s: every command must arrive at exactly the intended device
//! with exactly the intended bytes, and every response must be decoded for
//! the device that sent it.

#![allow(clippy::needless_range_loop)] // devices are addressed by chain index

use bridge_logic::powerstep::chain::{Batch, Chain, Plan, MAX_COMMANDS, MAX_DEVICES};
use bridge_logic::powerstep::commands::{Command, Direction, SwitchAction};
use bridge_logic::powerstep::registers::{Access, Register, REGISTERS};
use proptest::prelude::*;
use stepbridge_sim::SimChain;

fn register() -> impl Strategy<Value = Register> + Clone {
    (1u8..=27).prop_map(|a| Register::from_address(a).expect("1..=27 exist"))
}

fn writable_register() -> impl Strategy<Value = Register> + Clone {
    proptest::sample::select(
        REGISTERS
            .iter()
            .filter(|r| r.access != Access::ReadOnly)
            .map(|r| r.register)
            .collect::<Vec<_>>(),
    )
}

fn direction() -> impl Strategy<Value = Direction> + Clone {
    prop_oneof![Just(Direction::Forward), Just(Direction::Reverse)]
}

fn action() -> impl Strategy<Value = SwitchAction> + Clone {
    prop_oneof![
        Just(SwitchAction::ResetAbsPos),
        Just(SwitchAction::CopyToMark)
    ]
}

/// Any of the 19 commands with arguments in range.
fn command() -> impl Strategy<Value = Command> + Clone {
    prop_oneof![
        Just(Command::Nop),
        (writable_register(), any::<u32>()).prop_map(|(r, v)| Command::SetParam(r, v & r.mask())),
        register().prop_map(Command::GetParam),
        (direction(), 0u32..=0xF_FFFF).prop_map(|(d, s)| Command::Run(d, s)),
        direction().prop_map(Command::StepClock),
        (direction(), 0u32..=0x3F_FFFF).prop_map(|(d, n)| Command::Move(d, n)),
        (-(1i32 << 21)..(1 << 21)).prop_map(Command::GoTo),
        (direction(), -(1i32 << 21)..(1 << 21)).prop_map(|(d, p)| Command::GoToDir(d, p)),
        (action(), direction(), 0u32..=0xF_FFFF).prop_map(|(a, d, s)| Command::GoUntil(a, d, s)),
        (action(), direction()).prop_map(|(a, d)| Command::ReleaseSw(a, d)),
        Just(Command::GoHome),
        Just(Command::GoMark),
        Just(Command::ResetPos),
        Just(Command::ResetDevice),
        Just(Command::SoftStop),
        Just(Command::HardStop),
        Just(Command::SoftHiZ),
        Just(Command::HardHiZ),
        Just(Command::GetStatus),
    ]
}

/// Commands that change no register a read in the same batch could see.
fn read_or_nop() -> impl Strategy<Value = Command> + Clone {
    prop_oneof![
        Just(Command::Nop),
        register().prop_map(Command::GetParam),
        Just(Command::GetStatus),
    ]
}

fn batches(
    cmd: impl Strategy<Value = Command> + Clone,
) -> impl Strategy<Value = (usize, Vec<Vec<Command>>)> {
    (1usize..=MAX_DEVICES).prop_flat_map(move |n| {
        (
            Just(n),
            proptest::collection::vec(proptest::collection::vec(cmd.clone(), 0..=MAX_COMMANDS), n),
        )
    })
}

fn detected(n: usize) -> Chain<SimChain> {
    let mut chain = Chain::new(SimChain::new(n));
    assert_eq!(chain.detect(), Ok(n));
    chain
}

fn encoded(cmds: impl Iterator<Item = Command>) -> Vec<Vec<u8>> {
    cmds.filter(|c| *c != Command::Nop)
        .map(|c| c.encode().as_slice().to_vec())
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 5_000, ..ProptestConfig::default() })]

    #[test]
    fn every_command_arrives_at_exactly_its_device_with_exactly_its_bytes(
        (n, per_device) in batches(command())
    ) {
        let mut chain = detected(n);
        let mut batch = Batch::new(n);
        for (d, cmds) in per_device.iter().enumerate() {
            for c in cmds {
                batch.push(d, *c).unwrap();
            }
        }
        for dev in chain.bus_mut().devices_mut() {
            dev.clear_log();
        }
        chain.execute(&batch).unwrap();
        for (d, cmds) in per_device.iter().enumerate() {
            let got = encoded(chain.bus().device(d).unwrap().received().copied());
            let want = encoded(cmds.iter().copied());
            prop_assert_eq!(got, want, "device {} of {}", d, n);
        }
    }

    /// A batch under a window budget: what it accepts is laid out within
    /// the budget (and within the bound it reports), what it refuses
    /// would have made it longer, and the accepted commands still arrive.
    #[test]
    fn a_window_budget_holds_and_refuses_only_what_would_break_it(
        (n, per_device) in batches(command()), budget in 5usize..bridge_logic::powerstep::chain::MAX_WINDOWS
    ) {
        let mut batch = Batch::new(n);
        batch.set_window_budget(budget);
        // The same commands under a budget no batch reaches.
        let mut unbounded = Batch::new(n);
        unbounded.set_window_budget(bridge_logic::powerstep::chain::MAX_WINDOWS - 1);
        for (d, cmds) in per_device.iter().enumerate() {
            for c in cmds {
                let mut trial = unbounded.clone();
                let fits = trial.push(d, *c).is_ok();
                match batch.push(d, *c) {
                    Ok(()) => unbounded = trial,
                    Err(e) => {
                        prop_assert_eq!(e, bridge_logic::powerstep::chain::ScheduleError::TooManyWindows);
                        prop_assert!(!fits || trial.windows_at_most().unwrap() > budget);
                    }
                }
            }
        }
        let plan = Plan::new(&batch).unwrap();
        prop_assert!(plan.windows() <= batch.windows_at_most().unwrap());
        prop_assert!(plan.windows() <= budget, "{} windows > {}", plan.windows(), budget);
        let mut chain = detected(n);
        for dev in chain.bus_mut().devices_mut() {
            dev.clear_log();
        }
        chain.execute(&batch).unwrap();
        for d in 0..n {
            let got = encoded(chain.bus().device(d).unwrap().received().copied());
            let want = encoded(batch.commands(d).iter().copied());
            prop_assert_eq!(got, want, "device {} of {}", d, n);
        }
    }

    #[test]
    fn every_response_is_decoded_for_the_device_that_sent_it(
        (n, per_device) in batches(read_or_nop()), seed in any::<u32>()
    ) {
        let mut chain = detected(n);
        // Give every device distinct register contents.
        for d in 0..n {
            let dev = chain.bus_mut().device_mut(d).unwrap();
            for info in REGISTERS.iter() {
                if info.register == Register::Status {
                    continue;
                }
                let v = seed.rotate_left(d as u32 * 5 + u32::from(info.address)) ^ (d as u32 * 0x01_0101);
                dev.set_register_raw(info.register, v & info.register.mask());
            }
        }
        let expected: Vec<_> = (0..n)
            .map(|d| {
                let dev = chain.bus().device(d).unwrap();
                (
                    REGISTERS.iter().map(|i| dev.register(i.register)).collect::<Vec<_>>(),
                    dev.status(),
                )
            })
            .collect();
        let mut batch = Batch::new(n);
        for (d, cmds) in per_device.iter().enumerate() {
            for c in cmds {
                batch.push(d, *c).unwrap();
            }
        }
        let replies = chain.execute(&batch).unwrap();
        for (d, cmds) in per_device.iter().enumerate() {
            let (regs, status) = &expected[d];
            let mut first_status = true;
            for (i, c) in cmds.iter().enumerate() {
                match *c {
                    Command::GetParam(Register::Status) => {
                        // Before any GetStatus of this batch, STATUS is what it was.
                        if first_status {
                            prop_assert_eq!(
                                replies.get(d, i),
                                Some(bridge_logic::powerstep::Reply::Param(Register::Status, u32::from(status.raw())))
                            );
                        }
                    }
                    Command::GetParam(r) => {
                        let want = regs[usize::from(r.address()) - 1];
                        prop_assert_eq!(replies.get(d, i), Some(bridge_logic::powerstep::Reply::Param(r, want)), "device {} of {}", d, n);
                    }
                    Command::GetStatus => {
                        // The first GetStatus sees the status before any clearing.
                        if first_status {
                            prop_assert_eq!(replies.get(d, i), Some(bridge_logic::powerstep::Reply::Status(*status)));
                        }
                        first_status = false;
                    }
                    _ => prop_assert_eq!(replies.get(d, i), None),
                }
            }
        }
    }
}

/// Every device with a command that is not a read; a device that only
/// reads is not aligned (it starts in window 0).
#[test]
fn all_devices_execute_their_last_command_in_the_same_window() {
    let n = 4;
    let mut batch = Batch::new(n);
    batch.push(0, Command::GetParam(Register::AbsPos)).unwrap();
    batch
        .push(0, Command::Run(Direction::Forward, 1000))
        .unwrap();
    batch.push(1, Command::HardStop).unwrap();
    batch.push(2, Command::Run(Direction::Reverse, 5)).unwrap();
    batch.push(3, Command::GetStatus).unwrap();
    let plan = Plan::new(&batch).unwrap();
    let mut chain = detected(n);
    let mut completed_in = vec![None; n];
    // Clock the plan window by window and watch each device's log grow.
    for w in 0..plan.windows() {
        let tx = plan.window(w).unwrap();
        let mut rx = vec![0; n];
        chain.bus_mut().transfer(tx, &mut rx);
        for d in 0..n {
            let last = chain.bus().device(d).unwrap().received().last().copied();
            if last == batch.commands(d).last().copied() && completed_in[d].is_none() {
                completed_in[d] = Some(w);
            }
        }
    }
    let sync = Some(plan.sync_window());
    assert_eq!(completed_in, vec![sync, sync, sync, Some(0)]);
}

#[test]
fn chain_length_is_detected_for_every_length() {
    for n in 1..=MAX_DEVICES {
        let mut chain = Chain::new(SimChain::new(n));
        assert_eq!(chain.detect(), Ok(n));
    }
}

#[test]
fn status_poll_reads_each_device_its_own_status() {
    let mut chain = detected(5);
    let first = chain.poll_status().unwrap(); // power-up UVLO is read and cleared
    assert!((0..5).all(|d| first.status(d).unwrap().uvlo()));
    chain
        .bus_mut()
        .device_mut(2)
        .unwrap()
        .inject(stepbridge_sim::Fault::Overcurrent);
    let replies = chain.poll_status().unwrap();
    for d in 0..5 {
        let s = replies.status(d).unwrap();
        assert!(!s.uvlo(), "device {d}");
        assert_eq!(s.overcurrent(), d == 2, "device {d}");
    }
}
