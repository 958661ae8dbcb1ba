//! The firmware's USART2 + DE driver (`drivers_core::rs485`, the code the
//! board runs) against the RM0090 §30 model (`host_tests::rm0090::usart`),
//! bit time by bit time: one test per rule of the model's table (U1–U9).
//! The interrupt is served when the model's line is up, after
//! `latency` bit times (0: at once).

use bridge_logic::postep60::settings::{Parity, Serial};
use bridge_logic::transport::modbus::ADU_MAX;
use drivers_core::rs485::bits::*;
use drivers_core::rs485::{Rs485, Rx};
use host_tests::rm0090::usart::{RxFault, UsartModel, PCLK1_HZ};

const SETTINGS: [Serial; 6] = [
    Serial {
        baud: 9600,
        parity: Parity::Even,
    },
    Serial {
        baud: 9600,
        parity: Parity::Odd,
    },
    Serial {
        baud: 9600,
        parity: Parity::None,
    },
    Serial {
        baud: 19200,
        parity: Parity::Even,
    },
    Serial {
        baud: 19200,
        parity: Parity::Odd,
    },
    Serial {
        baud: 19200,
        parity: Parity::None,
    },
];

const FRAME: [u8; 8] = [0x01, 0x03, 0x00, 0x0A, 0x00, 0x03, 0x25, 0xC9];

struct Line {
    d: Rs485<UsartModel>,
    got: Vec<Rx>,
    latency: u64,
    pending_since: Option<u64>,
}

impl Line {
    fn new(serial: Serial) -> Line {
        Self::on(UsartModel::new(), serial)
    }

    fn on(model: UsartModel, serial: Serial) -> Line {
        Line {
            d: Rs485::new(model, PCLK1_HZ, serial),
            got: Vec::new(),
            latency: 0,
            pending_since: None,
        }
    }

    fn m(&self) -> &UsartModel {
        self.d.port()
    }

    /// Serve the interrupt until its line is down (panics on a storm).
    fn serve(&mut self) {
        let mut n = 0;
        while self.m().irq() {
            let got = &mut self.got;
            self.d.on_interrupt(|rx| got.push(rx));
            n += 1;
            assert!(n < 8, "interrupt storm: {:?}", self.m());
        }
        self.pending_since = None;
    }

    fn tick(&mut self) {
        self.d.port_mut().tick();
        if self.m().irq() {
            let now = self.m().now();
            let since = *self.pending_since.get_or_insert(now);
            if now - since >= self.latency {
                self.serve();
            }
        } else {
            self.pending_since = None;
        }
    }

    /// Bit times until nothing is sent or pending any more (at most `cap`).
    fn run_idle(&mut self, cap: u64) {
        for _ in 0..cap {
            let m = self.m();
            if !self.d.is_sending() && !m.transmitting() && !m.receiving() && !m.irq() {
                return;
            }
            self.tick();
        }
        panic!("still sending after {cap} bit times: {:?}", self.m());
    }

    fn clean(&self) {
        assert_eq!(self.m().violations(), &[] as &[String]);
        assert!(!self.m().irq(), "interrupt left pending: {:?}", self.m());
        assert_eq!(self.m().cr1() & (CR1_TXEIE | CR1_TCIE), 0);
    }
}

// ---------------------------------------------------- U1, U2 config --

#[test]
fn u1_u2_every_serial_setting_is_an_11_bit_character_at_its_baud_rate() {
    for serial in SETTINGS {
        let line = Line::new(serial);
        assert!(line.d.is_configured());
        assert_eq!(line.m().frame_bits(), 11, "{serial:?}");
        let baud = line.m().baud();
        assert!(
            baud.abs_diff(serial.baud) * 200 <= serial.baud,
            "{serial:?}: {baud}"
        );
        let format = line.m().cr1() & (CR1_M | CR1_PCE | CR1_PS);
        let want = match serial.parity {
            Parity::Even => CR1_M | CR1_PCE,
            Parity::Odd => CR1_M | CR1_PCE | CR1_PS,
            Parity::None => 0,
        };
        assert_eq!(format, want, "{serial:?}");
        let on = CR1_UE | CR1_TE | CR1_RE | CR1_RXNEIE;
        assert_eq!(line.m().cr1() & on, on);
        line.clean();
    }
}

#[test]
fn u1_a_baud_rate_out_of_reach_leaves_the_usart_off_and_silent() {
    let mut d = Rs485::new(UsartModel::new(), 100_000, Serial::DEFAULT);
    assert!(!d.is_configured());
    assert!(!d.send(&FRAME));
    assert_eq!(d.port().cr1(), 0);
}

// ----------------------------------------------------- U3, U4 sending --

#[test]
fn u3_u4_a_response_goes_out_byte_for_byte_for_every_length() {
    for len in [1, 2, 8, ADU_MAX] {
        let mut line = Line::new(Serial::DEFAULT);
        let adu: Vec<u8> = (0..len).map(|k| k as u8 ^ 0x5A).collect();
        assert!(line.d.send(&adu));
        line.run_idle(12 * (len as u64 + 2));
        assert_eq!(line.m().sent(), adu, "{len} bytes");
        line.clean();
    }
}

#[test]
fn u4_a_response_with_slow_interrupts_still_goes_out_whole() {
    for latency in [1, 5, 10] {
        let mut line = Line::new(Serial::DEFAULT);
        line.latency = latency;
        assert!(line.d.send(&FRAME));
        line.run_idle(12 * 20);
        assert_eq!(line.m().sent(), FRAME, "latency {latency}");
        line.clean();
    }
}

// ------------------------------------------------------ U5, U9 TC / DE --

#[test]
fn u5_u9_de_stays_high_until_the_last_stop_bit_and_drops_at_tc() {
    for latency in [0, 3] {
        let mut line = Line::new(Serial {
            baud: 19200,
            parity: Parity::Even,
        });
        line.latency = latency;
        line.run_idle(20); // the idle frame after TE
        assert!(line.d.send(&FRAME));
        assert!(line.d.driver_enabled());
        line.run_idle(12 * 20);
        assert!(!line.d.driver_enabled());
        let (end, low) = (
            line.m().last_stop_end().unwrap(),
            line.m().de_low_at().unwrap(),
        );
        assert!(low >= end, "DE low at {low}, last stop bit ended at {end}");
        assert!(
            low - end <= latency + 1,
            "DE low {} bit times after TC",
            low - end
        );
        line.clean(); // U9: no bit went out with DE low
    }
}

#[test]
fn u5_a_response_refused_while_the_previous_one_goes_out() {
    let mut line = Line::new(Serial::DEFAULT);
    assert!(line.d.send(&FRAME));
    assert!(!line.d.send(&FRAME));
    assert_eq!(line.d.errors().busy, 1);
    line.run_idle(12 * 20);
    assert!(line.d.send(&FRAME), "free again after the frame");
    line.run_idle(12 * 20);
    assert_eq!(line.m().sent().len(), 2 * FRAME.len());
    line.clean();
}

// ------------------------------------------------------ U6, U7 receive --

#[test]
fn u6_received_bytes_are_handed_over_in_order() {
    let mut line = Line::new(Serial::DEFAULT);
    for b in FRAME {
        line.d.port_mut().receive(b, None);
    }
    line.run_idle(12 * 10);
    let want: Vec<Rx> = FRAME.iter().map(|&b| Rx::Byte(b)).collect();
    assert_eq!(line.got, want);
    line.clean();
}

#[test]
fn u7_an_overrun_is_handed_over_as_bad_and_cleared() {
    let mut line = Line::new(Serial::DEFAULT);
    line.latency = 15; // longer than a character: the second one overruns
    line.d.port_mut().receive(0x11, None);
    line.d.port_mut().receive(0x22, None);
    line.run_idle(12 * 4);
    assert_eq!(line.got, [Rx::Bad]);
    assert_eq!(line.d.errors().overrun, 1);
    assert_eq!(line.m().sr() & (SR_ORE | SR_RXNE), 0);
    line.clean();
}

#[test]
fn u7_parity_framing_and_noise_errors_are_handed_over_as_bad_and_cleared() {
    for fault in [RxFault::Parity, RxFault::Framing, RxFault::Noise] {
        let mut line = Line::new(Serial::DEFAULT);
        line.d.port_mut().receive(0x33, Some(fault));
        line.d.port_mut().receive(0x44, None);
        line.run_idle(12 * 4);
        assert_eq!(line.got, [Rx::Bad, Rx::Byte(0x44)], "{fault:?}");
        let e = line.d.errors();
        assert_eq!(
            (e.parity, e.framing, e.noise),
            match fault {
                RxFault::Parity => (1, 0, 0),
                RxFault::Framing => (0, 1, 0),
                RxFault::Noise => (0, 0, 1),
            }
        );
        assert_eq!(line.m().sr() & SR_RX_ERRORS, 0);
        line.clean();
    }
}

#[test]
fn u7_a_byte_received_while_sending_is_counted_not_handed_over() {
    let mut line = Line::new(Serial::DEFAULT);
    assert!(line.d.send(&FRAME));
    line.d.port_mut().receive(0x55, None);
    line.run_idle(12 * 20);
    assert!(line.got.is_empty());
    assert_eq!(line.d.errors().while_sending, 1);
    line.clean();
}

// --------------------------------------------------------- U8 interrupts --

#[test]
fn u8_only_rxne_stays_enabled_at_rest() {
    let mut line = Line::new(Serial::DEFAULT);
    assert!(line.d.send(&FRAME));
    line.run_idle(12 * 20);
    assert_eq!(
        line.m().cr1() & (CR1_TXEIE | CR1_TCIE | CR1_RXNEIE),
        CR1_RXNEIE
    );
    line.clean();
}

// ------------------------------------------------------------------ QEMU --

#[test]
fn on_qemus_usart_send_writes_the_whole_response_and_releases_de_at_once() {
    let mut line = Line::on(UsartModel::qemu_7_2(), Serial::DEFAULT);
    assert!(line.d.send(&FRAME));
    assert_eq!(line.m().sent(), FRAME);
    assert!(!line.d.driver_enabled());
    assert!(!line.d.is_sending());
    assert_eq!(line.m().violations(), &[] as &[String]);
}
