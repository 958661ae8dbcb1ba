//! Framing and timing of the RTU server against a recording target.

use super::*;
use crate::postep60::Current;

/// Two axes at ids 1 and 2, or every id if `greedy` (to prove the server
/// itself keeps ids outside 1..=247 silent).
#[derive(Debug, Default)]
struct Recorder {
    greedy: bool,
    requests: std::vec::Vec<(usize, Request)>,
    refuse: Option<CommandError>,
}

impl ModbusTarget for Recorder {
    fn axis_for_id(&self, id: u8) -> Option<usize> {
        match id {
            _ if self.greedy => Some(0),
            1 | 2 => Some(usize::from(id - 1)),
            _ => None,
        }
    }
    fn axes(&self) -> usize {
        2
    }
    fn request(&mut self, axis: usize, req: Request) -> Result<Effect, CommandError> {
        self.requests.push((axis, req));
        match self.refuse {
            Some(e) => Err(e),
            None => Ok(Effect::None),
        }
    }
    fn query(&mut self, axis: usize, q: Query) -> Option<Value> {
        Some(match q {
            Query::Position => Value::I32(-2),
            Query::FullScaleCurrent => Value::Current(Current { tq: 123, ai: 3 }),
            _ => Value::U8(axis as u8 + 4),
        })
    }
}

const T9600: Timing = Timing::for_serial(Serial::DEFAULT);
/// One 11-bit character at 9600 baud, µs (rounded up).
const CHAR: u64 = 1146;

/// Reference CRC-16/MODBUS, bitwise (independent of the `crc` crate).
fn crc_ref(bytes: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for b in bytes {
        crc ^= u16::from(*b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    crc
}

fn adu(body: &[u8]) -> std::vec::Vec<u8> {
    let mut v = body.to_vec();
    v.extend_from_slice(&crc_ref(body).to_le_bytes());
    v
}

/// Feed `bytes` back to back from `start` (first byte ends one character
/// later); returns the end of the last byte.
fn feed(s: &mut RtuServer, bytes: &[u8], start: u64) -> u64 {
    let mut t = start;
    for b in bytes {
        t += CHAR;
        s.on_byte(*b, t);
    }
    t
}

/// Feed a frame, then poll at its deadline.
fn transact(
    s: &mut RtuServer,
    r: &mut Recorder,
    bytes: &[u8],
    start: u64,
) -> (Option<std::vec::Vec<u8>>, u64) {
    let end = feed(s, bytes, start);
    let at = s.deadline().unwrap_or(end);
    (s.poll(at, r).map(<[u8]>::to_vec), at)
}

#[test]
fn timing_follows_the_serial_settings() {
    assert_eq!(
        T9600,
        Timing {
            t15_us: 1719,
            t35_us: 4011
        }
    );
    assert_eq!(T9600.character_us(), 1146);
    let s19200n = Serial {
        baud: 19200,
        parity: Parity::None,
    };
    assert_eq!(
        Timing::for_serial(s19200n),
        Timing {
            t15_us: 860,
            t35_us: 2006
        }
    );
    assert_eq!(stop_bits(s19200n), 2);
    assert_eq!(stop_bits(Serial::DEFAULT), 1);
    let fast = Serial {
        baud: 115_200,
        parity: Parity::Odd,
    };
    assert_eq!(
        Timing::for_serial(fast),
        Timing {
            t15_us: 750,
            t35_us: 1750
        }
    );
    let zero = Serial {
        baud: 0,
        parity: Parity::Even,
    };
    assert_eq!(Timing::for_serial(zero), T9600);
    let slow = Serial {
        baud: 1,
        parity: Parity::Even,
    };
    assert_eq!(Timing::for_serial(slow).t35_us, 38_500_000);
}

#[test]
fn the_crate_crc_matches_the_reference_and_pymodbus() {
    assert_eq!(crc16(b"123456789"), 0x4B37);
    let body = [0x02, 0x03, 0x00, 0x01, 0x00, 0x7D];
    assert_eq!(crc16(&body).to_le_bytes(), [0xD4, 0x18]);
    assert_eq!(crc_ref(&body), crc16(&body));
}

#[test]
fn a_frame_is_processed_only_after_t35_of_silence() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    assert_eq!(s.deadline(), None);
    let end = feed(&mut s, &adu(&[1, 0x06, 0x00, 0x5F, 0, 0]), 0);
    assert_eq!(s.deadline(), Some(end + 4011));
    assert_eq!(s.poll(end + 4010, &mut r), None);
    assert!(r.requests.is_empty());
    let resp = s.poll(end + 4011, &mut r).map(<[u8]>::to_vec);
    assert_eq!(resp, Some(adu(&[1, 0x06, 0x00, 0x5F, 0, 0])));
    assert_eq!(r.requests, [(0, Request::Stop)]);
    assert_eq!(s.deadline(), None);
    assert_eq!(s.poll(end + 10_000, &mut r), None, "processed once");
}

#[test]
fn silence_up_to_t15_inside_a_frame_is_tolerated() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let f = adu(&[2, 0x03, 0x00, 0x14, 0x00, 0x01]);
    let mut t = 0;
    for b in &f {
        // one character + exactly t1.5 of silence before every byte
        t += CHAR + 1719;
        s.on_byte(*b, t);
    }
    let resp = s.poll(t + 4011, &mut r).map(<[u8]>::to_vec);
    assert_eq!(resp, Some(adu(&[2, 0x03, 0x02, 0x00, 0x05])));
    assert_eq!(s.stats().gaps, 0);
}

#[test]
fn a_gap_over_t15_drops_the_whole_frame_and_the_next_one_is_answered() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let f = adu(&[1, 0x06, 0x00, 0x50, 0, 0]);
    let t = feed(&mut s, &f[..3], 0);
    // 1 µs more than t1.5 of silence, still less than t3.5
    let t = feed(&mut s, &f[3..], t + 1720);
    assert_eq!(s.poll(t + 4011, &mut r), None);
    assert_eq!(s.stats().gaps, 1);
    assert!(r.requests.is_empty());
    let (resp, _) = transact(&mut s, &mut r, &adu(&[1, 0x06, 0x00, 0x5F, 0, 1]), t + 4011);
    assert_eq!(resp, Some(adu(&[1, 0x06, 0x00, 0x5F, 0, 1])));
}

#[test]
fn a_character_received_in_error_drops_the_frame_even_if_the_crc_still_matches() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    // A valid Set position frame, plus one character the UART flagged as bad:
    // the remaining bytes still carry a good CRC, but the frame must go.
    let f = adu(&[1, 0x06, 0x00, 0x5F, 0, 1]);
    let t = feed(&mut s, &f, 0);
    s.on_bad_byte(t + CHAR);
    let at = s.deadline().unwrap_or(t);
    assert_eq!(s.poll(at, &mut r), None);
    assert_eq!(s.stats().bad_characters, 1);
    assert!(r.requests.is_empty());
    let (resp, _) = transact(&mut s, &mut r, &f, at + 10_000);
    assert_eq!(resp, Some(f));
}

#[test]
fn the_tail_after_a_gap_is_not_taken_for_a_request() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    // garbage, a gap of 2 characters, then a complete valid frame: one frame
    let t = feed(&mut s, &[0x11, 0x22], 0);
    let t = feed(&mut s, &adu(&[1, 0x06, 0x00, 0x5F, 0, 0]), t + 2 * CHAR);
    assert_eq!(s.poll(t + 4011, &mut r), None);
    assert!(r.requests.is_empty());
    assert_eq!(s.stats().gaps, 1);
}

#[test]
fn a_byte_after_t35_starts_a_new_frame_even_before_poll_ran() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let t = feed(&mut s, &adu(&[1, 0x03, 0x00, 0x14, 0x00, 0x01]), 0);
    // Poll is late: the next frame (another server's) starts right at t3.5.
    let t2 = feed(
        &mut s,
        &adu(&[9, 0x03, 0x00, 0x14, 0x00, 0x01]),
        t + 4011 - CHAR,
    );
    assert_eq!(s.deadline(), Some(t + 4011), "the ended frame waits");
    let resp = s.poll(t2, &mut r).map(<[u8]>::to_vec);
    assert_eq!(resp, Some(adu(&[1, 0x03, 0x02, 0x00, 0x04])));
    assert_eq!(s.deadline(), Some(t2 + 4011));
    assert_eq!(s.poll(t2 + 4011, &mut r), None);
    assert_eq!(s.stats().other_ids, 1);
    assert_eq!(s.stats().overruns, 0);
}

#[test]
fn of_two_ended_frames_waiting_for_poll_the_older_is_dropped() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let t = feed(&mut s, &adu(&[1, 0x06, 0x00, 0x5F, 0, 0]), 0);
    let t = feed(&mut s, &adu(&[2, 0x06, 0x00, 0x5E, 0, 0]), t + 5000);
    let t = feed(&mut s, &adu(&[1, 0x03, 0x00, 0x14, 0x00, 0x01]), t + 5000);
    assert_eq!(s.stats().overruns, 1);
    let resp = s.poll(t, &mut r).map(<[u8]>::to_vec);
    assert_eq!(resp, Some(adu(&[2, 0x06, 0x00, 0x5E, 0, 0])));
    assert_eq!(r.requests, [(1, Request::SetZero)]);
    let resp = s.poll(t + 4011, &mut r).map(<[u8]>::to_vec);
    assert_eq!(resp, Some(adu(&[1, 0x03, 0x02, 0x00, 0x04])));
}

#[test]
fn a_frame_ended_while_another_waits_replaces_it_at_poll() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let t = feed(&mut s, &adu(&[1, 0x06, 0x00, 0x5F, 0, 0]), 0);
    let t = feed(&mut s, &adu(&[2, 0x06, 0x00, 0x5E, 0, 0]), t + 5000);
    let resp = s.poll(t + 5000, &mut r).map(<[u8]>::to_vec);
    assert_eq!(resp, Some(adu(&[2, 0x06, 0x00, 0x5E, 0, 0])));
    assert_eq!(r.requests, [(1, Request::SetZero)]);
    assert_eq!(s.stats().overruns, 1);
    assert_eq!(s.deadline(), None);
}

#[test]
fn frames_of_256_bytes_pass_and_longer_ones_are_dropped() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let mut body = std::vec![0x09, 0x03, 0xFA];
    body.resize(ADU_MAX - 2, 0x11);
    let f = adu(&body);
    assert_eq!(f.len(), ADU_MAX);
    let (resp, t) = transact(&mut s, &mut r, &f, 0);
    assert_eq!(resp, None);
    assert_eq!((s.stats().frames_ok, s.stats().other_ids), (1, 1));
    let mut long = std::vec![0x01; ADU_MAX + 1];
    long.extend_from_slice(&adu(&[1, 0x06, 0x00, 0x5F, 0, 0]));
    let (resp, t) = transact(&mut s, &mut r, &long, t);
    assert_eq!(resp, None);
    assert_eq!(s.stats().overruns, 1);
    assert!(r.requests.is_empty());
    let (resp, _) = transact(&mut s, &mut r, &adu(&[1, 0x06, 0x00, 0x5F, 0, 0]), t);
    assert!(resp.is_some(), "in sync again after t3.5");
}

#[test]
fn short_frames_and_bad_crcs_are_dropped_silently() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let mut t = 0;
    for f in [&[0x01][..], &[0x01, 0x03], &[0x01, 0x03, 0x00]] {
        let (resp, at) = transact(&mut s, &mut r, f, t);
        assert_eq!(resp, None);
        t = at;
    }
    let mut bad = adu(&[1, 0x06, 0x00, 0x5F, 0, 0]);
    if let Some(last) = bad.last_mut() {
        *last ^= 1;
    }
    let (resp, _) = transact(&mut s, &mut r, &bad, t);
    assert_eq!(resp, None);
    assert_eq!(s.stats().crc_errors, 4);
    assert_eq!(s.stats().frames_ok, 0);
    assert!(r.requests.is_empty());
}

#[test]
fn a_four_byte_frame_for_us_gets_an_exception() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let (resp, _) = transact(&mut s, &mut r, &adu(&[1, 0x03]), 0);
    assert_eq!(resp, Some(adu(&[1, 0x83, 0x03])));
    let (resp, _) = transact(&mut s, &mut r, &adu(&[1, 0x2B]), 10_000);
    assert_eq!(resp, Some(adu(&[1, 0xAB, 0x01])));
}

#[test]
fn time_going_backwards_or_wrapping_does_not_panic() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    s.on_byte(1, u64::MAX);
    s.on_byte(2, 0);
    s.on_byte(3, u64::MAX - 1);
    assert_eq!(s.deadline(), Some(4011), "[1, 2] ended when 3 came");
    assert_eq!(s.poll(u64::MAX, &mut r), None);
    assert_eq!(s.stats().overruns, 1);
    assert_eq!(s.stats().crc_errors, 1);
    let mut s = RtuServer::new(Timing {
        t15_us: u32::MAX,
        t35_us: 0,
    });
    s.on_byte(1, 5);
    s.on_byte(1, 5);
    assert_eq!(s.poll(5, &mut r), None);
}

#[test]
fn ids_outside_1_to_247_are_never_answered() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder {
        greedy: true,
        ..Recorder::default()
    };
    let mut t = 0;
    for id in 248..=255u8 {
        let (resp, at) = transact(&mut s, &mut r, &adu(&[id, 0x06, 0x00, 0x5F, 0, 0]), t);
        assert_eq!(resp, None, "id {id}");
        t = at;
    }
    assert!(r.requests.is_empty());
    assert_eq!(s.stats().other_ids, 8);
    let (resp, _) = transact(&mut s, &mut r, &adu(&[247, 0x06, 0x00, 0x5F, 0, 0]), t);
    assert!(resp.is_some());
}

#[test]
fn broadcast_writes_run_on_every_axis_and_are_never_answered() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let (resp, t) = transact(&mut s, &mut r, &adu(&[0, 0x06, 0x00, 0x5F, 0, 0]), 0);
    assert_eq!(resp, None);
    assert_eq!(r.requests, [(0, Request::Stop), (1, Request::Stop)]);
    // malformed and read broadcasts: nothing, not even an exception
    let mut t = t;
    for body in [
        &[0, 0x03, 0x00, 0x14, 0x00, 0x01][..],
        &[0, 0x03, 0x00, 0x14, 0x00, 0x00],
        &[0, 0x2B, 0x0E],
        &[0, 0x06, 0x00, 0x40, 0, 0],
        &[0, 0x06, 0x01, 0x5F, 0, 0],
    ] {
        let (resp, at) = transact(&mut s, &mut r, &adu(body), t);
        assert_eq!(resp, None);
        t = at;
    }
    assert_eq!(r.requests.len(), 2);
    assert_eq!(s.stats().broadcasts, 6);
    assert_eq!(s.stats().exceptions, 0);
    // refused or ignored on the axes: still silent
    r.refuse = Some(CommandError::Ignored);
    let (resp, _) = transact(&mut s, &mut r, &adu(&[0, 0x06, 0x00, 0x33, 0, 9]), t);
    assert_eq!(resp, None);
    assert_eq!(s.stats().ignored_values, 2);
}

#[test]
fn broadcast_address_change_goes_only_to_the_axis_at_byte0() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let (resp, t) = transact(&mut s, &mut r, &adu(&[0, 0x06, 0x00, 0x04, 0x10, 0x02]), 0);
    assert_eq!(resp, None);
    assert_eq!(
        r.requests,
        [(
            1,
            Request::SetAddress {
                current: 2,
                new: 0x10
            }
        )]
    );
    let (_, _) = transact(&mut s, &mut r, &adu(&[0, 0x06, 0x00, 0x04, 0x10, 0x07]), t);
    assert_eq!(r.requests.len(), 1, "no axis at 7");
}

#[test]
fn refusals_are_exception_04_and_ignored_values_answer_normally() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder {
        refuse: Some(CommandError::Faulted),
        ..Recorder::default()
    };
    let (resp, t) = transact(
        &mut s,
        &mut r,
        &adu(&[1, 0x10, 0x00, 0x50, 0, 2, 4, 0, 0, 1, 0]),
        0,
    );
    assert_eq!(resp, Some(adu(&[1, 0x90, 0x04])));
    r.refuse = Some(CommandError::Ignored);
    let (resp, _) = transact(&mut s, &mut r, &adu(&[1, 0x06, 0x00, 0x33, 0, 9]), t);
    assert_eq!(resp, Some(adu(&[1, 0x06, 0x00, 0x33, 0, 9])));
    assert_eq!(s.stats().ignored_values, 1);
    assert_eq!(s.stats().exceptions, 1);
    assert_eq!(s.stats().responses, 1);
}

#[test]
fn parse_checks_function_then_structure() {
    assert_eq!(parse(&[]), Err(Exception::IllegalFunction));
    assert_eq!(parse(&[0x04, 0, 0, 0, 0]), Err(Exception::IllegalFunction));
    assert_eq!(
        parse(&[0x03, 0, 0x40, 0, 126]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        parse(&[0x03, 0, 0x40, 0, 2, 0]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        parse(&[0x03, 0, 0x40, 0, 125]),
        Ok(Pdu::Read {
            address: 0x40,
            quantity: 125
        })
    );
    assert_eq!(parse(&[0x06, 0, 0x5F, 0]), Err(Exception::IllegalDataValue));
    assert_eq!(
        parse(&[0x10, 0, 0x50, 0, 2, 4, 0, 0, 0]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        parse(&[0x10, 0, 0x50, 0, 2, 3, 0, 0, 0]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        parse(&[0x10, 0, 0x50, 0, 124, 248]),
        Err(Exception::IllegalDataValue)
    );
    assert_eq!(
        parse(&[0x10, 0, 0x50, 0, 2, 4, 1, 2, 3, 4]),
        Ok(Pdu::WriteMultiple {
            address: 0x50,
            quantity: 2,
            data: &[1, 2, 3, 4]
        })
    );
}

#[test]
fn reads_encode_registers_big_endian() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    let (resp, t) = transact(&mut s, &mut r, &adu(&[1, 0x03, 0x00, 0x40, 0x00, 0x02]), 0);
    assert_eq!(resp, Some(adu(&[1, 0x03, 0x04, 0xFF, 0xFF, 0xFF, 0xFE])));
    let (resp, _) = transact(&mut s, &mut r, &adu(&[1, 0x03, 0x00, 0x20, 0x00, 0x01]), t);
    assert_eq!(resp, Some(adu(&[1, 0x03, 0x02, 3, 123])));
}

#[test]
fn a_value_of_the_wrong_size_is_a_device_failure_not_a_panic() {
    let mut s = RtuServer::new(T9600);
    let mut r = Recorder::default();
    // The recorder answers HW/FW info with a U8: not 3 registers.
    let (resp, _) = transact(&mut s, &mut r, &adu(&[1, 0x03, 0x00, 0x0A, 0x00, 0x03]), 0);
    assert_eq!(resp, Some(adu(&[1, 0x83, 0x04])));
}
