use super::*;

fn axis() -> Axis {
    let cfg = AxisConfig {
        tick_us: 1000,
        logical_shift: 4,
        step: StepSel::OneTwentyEighth,
        drive: DriveMode::Voltage,
    };
    Axis::new(
        cfg,
        Limits {
            max_speed: 16_000,
            acc: 160_000,
            dec: 160_000,
        },
    )
}

#[test]
fn the_image_writes_step_mode_and_config_first() {
    let mut a = axis().with_chip_config(0x2C98);
    a.set_currents(40, 50);
    let order: heapless::Vec<Register, 8> = core::iter::from_fn(|| {
        let (r, _) = a.image.next(|_| true)?;
        a.image.written(r);
        Some(r)
    })
    .collect();
    assert_eq!(
        &order[..],
        &[
            Register::StepMode,
            Register::Config,
            Register::MinSpeed,
            Register::KvalHold,
            Register::KvalRun,
            Register::KvalAcc,
            Register::KvalDec
        ]
    );
}

#[test]
fn a_chip_reset_makes_every_owned_register_dirty_again() {
    let mut a = axis();
    a.set_currents(40, 50);
    while let Some((r, _)) = a.image.next(|_| true) {
        a.image.written(r);
    }
    assert!(a.image.is_clean());
    a.set_currents(40, 50);
    assert!(a.image.is_clean(), "the same values are not written again");
    a.image.on_reset();
    assert_eq!(a.image.get(Register::KvalHold), Some(40));
    assert!(a.image.next(|r| r == Register::KvalDec).is_some());
}

#[test]
fn motion_registers_are_not_writable_through_the_image() {
    let mut a = axis();
    for r in [
        Register::AbsPos,
        Register::StepMode,
        Register::MaxSpeed,
        Register::Acc,
        Register::Dec,
        Register::Speed,
        Register::Status,
    ] {
        assert!(!a.set_register(r, 1), "{r:?}");
    }
    assert!(a.set_register(Register::OcdTh, 12));
    assert_eq!(a.chip_image().get(Register::OcdTh), Some(12));
}

#[test]
fn a_write_is_done_only_once_the_next_status_shows_no_command_error() {
    let mut a = axis();
    a.set_register(Register::OcdTh, 12);
    let (r, _) = a.image.next(|_| true).expect("dirty");
    assert_eq!(r, Register::StepMode);
    while let Some((r, _)) = a.image.next(|_| true) {
        a.image.written(r);
    }
    assert!(a.image.is_clean());
    // The GetStatus after the writes comes back with CMD_ERROR: the
    // chip refused a command since the last one, maybe one of them.
    a.image.status_requested();
    a.image.status_seen(true);
    assert_eq!(
        a.image.next(|r| r == Register::OcdTh),
        Some((Register::OcdTh, 12)),
        "written again"
    );
    // A clean STATUS confirms them.
    while let Some((r, _)) = a.image.next(|_| true) {
        a.image.written(r);
    }
    a.image.status_requested();
    a.image.status_seen(false);
    assert!(a.image.is_clean());
    // Writes after the GetStatus went out are not what it is about.
    a.set_register(Register::OcdTh, 13);
    a.image.status_requested();
    a.image.written(Register::OcdTh);
    a.image.status_seen(true);
    assert!(a.image.is_clean(), "the next STATUS decides about that one");
}

#[test]
fn set_zero_reads_zero_at_once() {
    let mut a = axis();
    a.state = AxisState::Idle;
    a.rb.chip_pos = 12_345;
    a.set_zero();
    assert_eq!(a.actual_position(), 0);
    assert_eq!(a.required_position(), 0);
}

#[test]
fn limits_beyond_the_chip_are_clamped_for_the_profile() {
    let mut a = axis();
    a.set_logical_shift(0);
    a.set_limits(Limits {
        max_speed: 65_535,
        acc: 65_535,
        dec: 65_535,
    });
    assert_eq!(a.requested_limits().max_speed, 65_535);
    assert_eq!(a.profile().limits(), a.limit_cap());
}

fn sent(tick: u64, read: Option<Read>, commands: bool) -> Sent {
    Sent {
        tick,
        read,
        commands,
        expected_valid: true,
        ..Sent::NONE
    }
}

#[test]
fn batches_in_flight_come_back_oldest_first() {
    let mut q = InFlight::EMPTY;
    assert_eq!(q.pop(), None);
    for round in 0..3u64 {
        q.push(sent(2 * round, Some(Read::Position), false));
        q.push(sent(2 * round + 1, Some(Read::Status), true));
        assert!(q.commands());
        assert_eq!(q.pop().map(|s| s.tick), Some(2 * round));
        assert!(q.commands(), "the second still carries commands");
        assert_eq!(q.pop().map(|s| s.tick), Some(2 * round + 1));
        assert_eq!(q.pop(), None);
        assert!(!q.commands());
    }
}

#[test]
fn a_third_batch_in_flight_drops_the_oldest() {
    let mut q = InFlight::EMPTY;
    for t in 1..=3 {
        q.push(sent(t, None, false));
    }
    assert_eq!(q.pop().map(|s| s.tick), Some(2));
    assert_eq!(q.pop().map(|s| s.tick), Some(3));
    assert_eq!(q.pop(), None);
}

#[test]
fn reads_and_expectations_in_flight_can_be_voided() {
    let mut q = InFlight::EMPTY;
    q.push(sent(1, Some(Read::Position), false));
    q.push(sent(2, Some(Read::Status), false));
    q.drop_reads(Some(Read::Position));
    q.void_expected();
    let (a, b) = (q.pop().unwrap(), q.pop().unwrap());
    assert_eq!((a.read, b.read), (None, Some(Read::Status)));
    assert!(!a.expected_valid && !b.expected_valid);
    q.push(sent(3, Some(Read::Status), false));
    q.drop_reads(None);
    assert_eq!(q.pop().unwrap().read, None);
}
