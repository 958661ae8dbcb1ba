//! Property tests: random register traffic and random transfers never panic
//! and keep the extension's invariants, checked against a small model of
//! the status bit and the transfer count.

use proptest::prelude::*;

use super::*;

#[derive(Clone, Debug)]
enum Op {
    Read(u16, usize),
    Write(u16, Vec<u16>),
    Tick(u8),
    Complete,
    Fail,
    Input(u8, bool),
}

fn address() -> impl Strategy<Value = u16> {
    prop_oneof![
        4 => 0x0200u16..=0x0280,
        1 => any::<u16>(),
    ]
}

fn word() -> impl Strategy<Value = u16> {
    prop_oneof![
        any::<u16>(),
        Just(0),
        Just(1),
        Just(0x1000),
        (0u16..256).prop_map(|v| 0x8000 | v),
    ]
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        3 => (address(), 0usize..20).prop_map(|(a, n)| Op::Read(a, n)),
        4 => (address(), proptest::collection::vec(word(), 0..20)).prop_map(|(a, d)| Op::Write(a, d)),
        4 => any::<u8>().prop_map(Op::Tick),
        3 => Just(Op::Complete),
        1 => Just(Op::Fail),
        2 => (any::<u8>(), any::<bool>()).prop_map(|(i, l)| Op::Input(i, l)),
        // Reach the deep states often: enable, valid configurations,
        // transmit data.
        3 => (0u16..4).prop_map(|v| Op::Write(addr::IO_OPTIONS, vec![0, v])),
        2 => (any::<u16>(), any::<u16>())
            .prop_map(|(h, l)| Op::Write(addr::CONFIG, vec![0x1000 | h, l])),
        2 => proptest::collection::vec(any::<u16>(), 1..17)
            .prop_map(|d| Op::Write(addr::TX, d)),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn random_traffic_keeps_the_invariants(ops in proptest::collection::vec(op(), 0..100)) {
        let mut io = IoExtension::new(IoSettings::FACTORY, Clocks::BOARD);
        let mut chain = ShiftChain::new(32, 32);
        let mut running: Option<TransferPlan> = None;
        // The model.
        let mut status = false;
        let mut transfers = 0u32;
        for op in ops {
            let before = io;
            match op {
                Op::Read(a, n) => {
                    let mut out = vec![0; n];
                    match io.read(a, &mut out) {
                        Ok(()) => {
                            let rx_end = addr::RX as usize + io.config().words();
                            let (first, last) = (a as usize, a as usize + n);
                            if first < rx_end && last > addr::RX as usize {
                                status = false;
                            }
                        }
                        Err(_) => prop_assert_eq!(io, before),
                    }
                }
                Op::Write(a, d) => {
                    if io.write(a, &d).is_err() {
                        prop_assert_eq!(io, before);
                    }
                }
                Op::Tick(l) => {
                    let outs = [AxisOutputs { moving: l & 1 != 0, fault: l & 2 != 0, idle: l & 4 != 0 }; 8];
                    match io.tick(&outs) {
                        Some(Action::Transfer(p)) => {
                            prop_assert!(running.is_none());
                            prop_assert_eq!(p.bits, io.config().bits());
                            prop_assert!(p.clock.period.at_least_ns(requested_period_ns(io.config().period_n())));
                            running = Some(p);
                        }
                        Some(Action::Disable) => prop_assert!(!io.enabled()),
                        None => {}
                    }
                }
                Op::Complete => {
                    if let Some(p) = running.take() {
                        let rx = run(&mut chain, &p);
                        prop_assert!(io.complete(&rx).is_ok());
                        status = true;
                        transfers += 1;
                        prop_assert_eq!(io.rx(), rx.truncated(p.bits));
                    } else {
                        prop_assert!(io.complete(&WireBits::ZERO).is_err());
                    }
                }
                Op::Fail => {
                    prop_assert_eq!(io.fail().is_ok(), running.take().is_some());
                }
                Op::Input(i, l) => chain.set_rx_bit(usize::from(i), l),
            }
            prop_assert_eq!(io.status(), status);
            prop_assert_eq!(io.diagnostics().transfers, transfers);
            prop_assert_eq!(io.is_running(), running.is_some());
            let c = io.config().register(io.status());
            prop_assert_eq!(c & !cfg::DOCUMENTED, 0);
            prop_assert!(c & cfg::SPI_MODE != 0);
            let s = io.settings();
            let mut img = [0u8; IMAGE_LEN];
            s.encode(&mut img);
            prop_assert_eq!(IoSettings::decode(&img), Ok(s));
        }
    }

}
