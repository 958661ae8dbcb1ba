//! Transfers: when they start, what they put on the wire, what comes back.

use super::*;

/// Write `tx` (first ⌈n/16⌉ words), run one transfer of `n` bits in `mode`
/// through 32 + 32 simulated chips whose inputs are `ins`; returns the
/// receive words read through the registers.
fn round_trip(n: u16, mode: SpiMode, ins: &WireBits, tx: &WireBits) -> (Rig, Vec<u16>) {
    let mut r = Rig::new();
    for i in 0..256 {
        r.chain.set_rx_bit(i, ins.get(i));
    }
    r.setup(n, mode, 0, 0);
    let words = usize::from(n).div_ceil(16);
    r.write(addr::TX, &tx.words()[..words]).unwrap();
    let p = r.tick().expect("a transfer");
    assert_eq!((p.bits, p.mode), (n, mode));
    let rx = r.read(addr::RX, words).unwrap();
    (r, rx)
}

#[test]
fn bit_counts_1_to_256_pack_tx_and_rx_msb_first_word_0_first() {
    for n in [1u16, 7, 8, 9, 31, 32, 33, 255, 256] {
        let (ins, tx) = (pattern(u32::from(n)), pattern(u32::from(n) + 7));
        let (r, rx) = round_trip(n, SpiMode::MODE0, &ins, &tx);
        let n = usize::from(n);
        // rx: input of receive bit i at wire bit i, the rest 0.
        let want = ins.truncated(n as u16);
        assert_eq!(rx, want.words()[..n.div_ceil(16)], "n {n}");
        // tx: exactly n clocks, bit i at stage n − 1 − i, nothing else moved.
        assert_eq!(r.chain.rising_edges(), n as u64);
        for i in 0..n {
            assert_eq!(r.chain.tx_bit_output(n, i), tx.get(i), "n {n} tx bit {i}");
        }
        for s in n..256 {
            assert!(!r.chain.stage(s), "n {n} stage {s}");
        }
    }
}

#[test]
fn one_bit_sends_bit_15_of_word_0_and_receives_into_it() {
    let mut ins = WireBits::ZERO;
    ins.set(0, true);
    let mut tx = WireBits::ZERO;
    tx.set(0, true);
    let (r, rx) = round_trip(1, SpiMode::MODE0, &ins, &tx);
    assert_eq!(tx.words()[0], 0x8000);
    assert_eq!(rx, [0x8000]);
    assert!(r.chain.stage(0));
}

#[test]
fn all_four_modes_at_bit_level_against_the_shift_registers() {
    let n = 16;
    let (ins, tx) = (pattern(11), pattern(12));
    for mode in SpiMode::ALL {
        let (r, rx) = round_trip(n, mode, &ins, &tx);
        let rx = WireBits::from_words({
            let mut w = [0; 16];
            w[0] = rx[0];
            w
        });
        for i in 0..16 {
            let (want_rx, want_out) = if mode == SpiMode::MODE1 {
                // One bit late: input i + 1 (0 past the chain's 16th input
                // is input 16, the next chip's H), outputs b0, b0, b1, ….
                (ins.get(i + 1), tx.get(i.saturating_sub(1)))
            } else {
                (ins.get(i), tx.get(i))
            };
            assert_eq!(rx.get(i), want_rx, "{mode:?} rx {i}");
            assert_eq!(r.chain.tx_bit_output(16, i), want_out, "{mode:?} out {i}");
        }
    }
}

#[test]
fn a_write_starts_exactly_one_transfer_at_the_next_tick() {
    let mut r = Rig::new();
    r.setup(8, SpiMode::MODE0, 0, 0);
    assert!(r.tick().is_none(), "nothing written yet");
    r.write(addr::TX, &[0x5500]).unwrap();
    assert!(r.tick().is_some());
    assert!(r.tick().is_none());
    assert!(r.tick().is_none());
    assert_eq!(r.io.diagnostics().transfers, 1);
}

#[test]
fn auto_restart_transfers_every_tick_with_the_latest_data() {
    let mut r = Rig::new();
    r.setup(16, SpiMode::MODE0, 0, cfg::AUTO_RESTART);
    for k in 0..20u16 {
        if k == 10 {
            r.write(addr::TX, &[0xF0F0]).unwrap();
        }
        let p = r.tick().expect("every tick");
        assert_eq!(p.tx.words()[0], if k < 10 { 0 } else { 0xF0F0 });
    }
    assert_eq!(r.io.diagnostics().transfers, 20);
    assert_eq!(r.chain.latches(), 20);
}

#[test]
fn no_transfer_starts_while_one_runs_and_restarts_are_counted() {
    let mut r = Rig::new();
    r.setup(256, SpiMode::MODE0, 255, cfg::AUTO_RESTART);
    let Some(Action::Transfer(p)) = r.io.tick(&[]) else {
        panic!()
    };
    // 6.5 ms at N = 255: the next six 1 ms ticks find it running.
    assert_eq!(p.nominal_ns().div_ceil(1_000_000), 7);
    for _ in 0..6 {
        assert_eq!(r.io.tick(&[]), None);
    }
    assert_eq!(r.io.diagnostics().skipped_restarts, 6);
    // Written data waits too (auto-restart picks it up).
    r.write(addr::TX, &[1]).unwrap();
    assert_eq!(r.io.tick(&[]), None);
    let rx = run(&mut r.chain, &p);
    r.io.complete(&rx).unwrap();
    let Some(Action::Transfer(next)) = r.io.tick(&[]) else {
        panic!()
    };
    assert_eq!(next.tx.words()[0], 1);
}

#[test]
fn a_written_transfer_waits_for_the_running_one_to_end() {
    let mut r = Rig::new();
    r.setup(8, SpiMode::MODE0, 0, 0);
    r.write(addr::TX, &[0x0100]).unwrap();
    let Some(Action::Transfer(_)) = r.io.tick(&[]) else {
        panic!()
    };
    r.write(addr::TX, &[0x0200]).unwrap();
    assert_eq!(r.io.tick(&[]), None);
    assert_eq!(
        r.io.diagnostics().skipped_restarts,
        0,
        "not an auto-restart"
    );
    r.io.complete(&WireBits::ZERO).unwrap();
    let Some(Action::Transfer(p)) = r.io.tick(&[]) else {
        panic!()
    };
    assert_eq!(p.tx.words()[0], 0x0200);
}

#[test]
fn status_is_set_by_a_completed_transfer_and_cleared_by_reading_rx() {
    let mut r = Rig::new();
    r.setup(16, SpiMode::MODE0, 0, cfg::AUTO_RESTART);
    assert_eq!(r.config_reg() & cfg::STATUS, 0);
    r.tick().unwrap();
    assert_ne!(r.config_reg() & cfg::STATUS, 0);
    // Other reads leave it.
    r.read(addr::TX, 16).unwrap();
    r.read(addr::IO_OPTIONS, 4).unwrap();
    assert!(r.io.status());
    // More transfers keep it set.
    r.tick().unwrap();
    assert!(r.io.status());
    r.read(addr::RX, 1).unwrap();
    assert!(!r.io.status());
    assert_eq!(r.config_reg() & cfg::STATUS, 0);
    // A read that spans tx and rx also clears it.
    r.tick().unwrap();
    r.read(addr::TX + 15, 2).unwrap();
    assert!(!r.io.status());
}

#[test]
fn a_refused_rx_read_does_not_clear_the_status() {
    let mut r = Rig::new();
    r.setup(16, SpiMode::MODE0, 0, cfg::AUTO_RESTART);
    r.tick().unwrap();
    assert_eq!(r.read(addr::RX, 2), Err(IoError::IllegalAddress));
    assert!(r.io.status());
}

#[test]
fn status_stays_clear_until_the_transfer_ends() {
    let mut r = Rig::new();
    r.setup(8, SpiMode::MODE0, 0, 0);
    r.write(addr::TX, &[0]).unwrap();
    let Some(Action::Transfer(_)) = r.io.tick(&[]) else {
        panic!()
    };
    assert!(!r.io.status());
    let mut rx = WireBits::ZERO;
    rx.words_mut()[0] = 0xABFF;
    r.io.complete(&rx).unwrap();
    assert!(r.io.status());
    assert_eq!(
        r.read(addr::RX, 1).unwrap(),
        [0xAB00],
        "bits past the count read 0"
    );
}

#[test]
fn a_failed_transfer_keeps_rx_and_status_and_is_counted() {
    let mut r = Rig::new();
    r.chain.set_rx_bit(0, true);
    r.setup(8, SpiMode::MODE0, 0, cfg::AUTO_RESTART);
    r.tick().unwrap();
    r.read(addr::RX, 1).unwrap();
    let Some(Action::Transfer(_)) = r.io.tick(&[]) else {
        panic!()
    };
    r.io.fail().unwrap();
    assert!(!r.io.status());
    assert_eq!(r.io.rx().words()[0], 0x8000);
    assert_eq!(r.io.diagnostics().failures, 1);
    assert_eq!(r.read(addr::FAILURES, 1).unwrap(), [1]);
    assert!(r.tick().is_some(), "the next tick starts again");
}

#[test]
fn completions_without_a_transfer_are_refused_and_counted() {
    let mut r = Rig::new();
    assert_eq!(r.io.complete(&WireBits::ZERO), Err(NotRunning));
    assert_eq!(r.io.fail(), Err(NotRunning));
    assert_eq!(r.io.diagnostics().stray_completions, 2);
    assert!(!r.io.status());
}

#[test]
fn cs_hold_keeps_cs_low_into_the_next_transfer() {
    let mut r = Rig::new();
    let ins = pattern(21);
    for i in 0..32 {
        r.chain.set_rx_bit(i, ins.get(i));
    }
    r.setup(16, SpiMode::MODE0, 0, cfg::CS_HOLD);
    r.write(addr::TX, &[0x1234]).unwrap();
    let p1 = r.tick().unwrap();
    assert!(!p1.cs_low_before && p1.cs_hold && r.io.cs_low());
    assert_eq!(r.chain.latches(), 0);
    // Second half without hold: CS rises at its end.
    r.set_config(Config::new(16, SpiMode::MODE0, 0).unwrap().register(false))
        .unwrap();
    r.write(addr::TX, &[0x5678]).unwrap();
    let p2 = r.tick().unwrap();
    assert!(p2.cs_low_before && !p2.cs_hold && !r.io.cs_low());
    assert_eq!(r.chain.latches(), 1);
    // One 32-bit transfer for the slaves: inputs 16..32 came second.
    assert_eq!(r.read(addr::RX, 1).unwrap()[0], ins.words()[1]);
    let tx = WireBits::from_words({
        let mut w = [0; 16];
        w[0] = 0x1234;
        w[1] = 0x5678;
        w
    });
    for i in 0..32 {
        assert_eq!(r.chain.tx_bit_output(32, i), tx.get(i), "bit {i}");
    }
}

#[test]
fn cs_hold_with_auto_restart_never_raises_cs() {
    let mut r = Rig::new();
    r.setup(8, SpiMode::MODE3, 0, cfg::CS_HOLD | cfg::AUTO_RESTART);
    for k in 0..5 {
        let p = r.tick().unwrap();
        assert_eq!(p.cs_low_before, k > 0);
    }
    assert_eq!(r.chain.latches(), 0);
}

#[test]
fn a_cpol_change_while_cs_is_held_is_busy() {
    let mut r = Rig::new();
    r.setup(8, SpiMode::MODE0, 0, cfg::CS_HOLD);
    r.write(addr::TX, &[0]).unwrap();
    r.tick().unwrap();
    let mode2 = Config::new(8, SpiMode::MODE2, 0).unwrap().register(false);
    assert_eq!(r.set_config(mode2), Err(IoError::Busy));
    // CPHA, N, bit count may change.
    let mode1 = Config::new(24, SpiMode::MODE1, 9).unwrap().register(false);
    r.set_config(mode1).unwrap();
    // Once CS is released (a transfer without hold), CPOL may change.
    r.write(addr::TX, &[0]).unwrap();
    r.tick().unwrap();
    assert!(!r.io.cs_low());
    r.set_config(mode2).unwrap();
}

#[test]
fn disabling_raises_cs_once_and_stops_transfers() {
    let mut r = Rig::new();
    r.setup(8, SpiMode::MODE0, 0, cfg::AUTO_RESTART | cfg::CS_HOLD);
    r.tick().unwrap();
    assert!(r.io.cs_low());
    r.write(addr::IO_OPTIONS, &[0, 0]).unwrap();
    assert_eq!(r.io.tick(&[]), Some(Action::Disable));
    assert!(!r.io.cs_low());
    assert_eq!(r.io.tick(&[]), None);
    assert_eq!(r.io.tick(&[]), None);
    // Never enabled: nothing to release.
    let mut fresh = Rig::new();
    assert_eq!(fresh.io.tick(&[]), None);
}

#[test]
fn a_transfer_running_when_disabled_completes_then_the_port_is_released() {
    let mut r = Rig::new();
    r.setup(8, SpiMode::MODE0, 0, cfg::AUTO_RESTART);
    let Some(Action::Transfer(_)) = r.io.tick(&[]) else {
        panic!()
    };
    r.write(addr::IO_OPTIONS, &[0, 0]).unwrap();
    assert_eq!(r.io.tick(&[]), None, "still running");
    r.io.complete(&WireBits::ZERO).unwrap();
    assert!(r.io.status());
    assert_eq!(r.io.tick(&[]), Some(Action::Disable));
}

#[test]
fn an_enabled_extension_sends_its_stored_data_at_power_up() {
    let mut s = IoSettings::FACTORY;
    s.enabled = true;
    s.tx.words_mut()[0] = 0xC300;
    let mut r = Rig::with(s);
    let p = r.tick().unwrap();
    assert_eq!(p.tx.words()[0], 0xC300);
    assert!(r.tick().is_none(), "once, without auto-restart");
    assert!(Rig::new().tick().is_none(), "a disabled one stays silent");
}

#[test]
fn every_configuration_field_reaches_the_plan() {
    let mut r = Rig::new();
    let v = cfg::SPI_MODE | 32 | cfg::CS_HOLD | cfg::CPOL | cfg::CPHA | 3 << 16;
    r.set_config(v).unwrap();
    r.enable();
    r.write(addr::TX, &[0xFFFF, 0xFFFF, 0xFFFF]).unwrap();
    let Some(Action::Transfer(p)) = r.io.tick(&[]) else {
        panic!()
    };
    assert_eq!(p.bits, 33);
    assert_eq!(p.mode, SpiMode::MODE3);
    assert!(p.cs_hold);
    // 33 bits: timer engine, N = 3 (320 ns) → its 1 µs floor.
    assert_eq!(
        p.clock.engine,
        Engine::Timer {
            psc: 0,
            period: 168
        }
    );
    assert_eq!(p.tx.words()[..3], [0xFFFF, 0xFFFF, 0x8000]);
    // Auto-restart off: nothing at the next tick.
    r.io.complete(&WireBits::ZERO).unwrap();
    assert_eq!(r.io.tick(&[]), None);
}

#[test]
fn the_period_never_gets_shorter_than_the_field_asks_in_any_plan() {
    let mut r = Rig::new();
    r.enable();
    for n in 0..=255u8 {
        for bits in [1u16, 8, 9, 256] {
            let c = Config::new(bits, SpiMode::MODE0, n)
                .unwrap()
                .register(false)
                | cfg::AUTO_RESTART;
            r.set_config(c).unwrap();
            let p = r.tick().unwrap();
            assert!(
                p.clock.period.at_least_ns(requested_period_ns(n)),
                "N {n} bits {bits}"
            );
        }
    }
}
