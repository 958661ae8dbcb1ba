//! RTU framing on a multidrop line, after pymodbus
//! `test/framer/test_multidrop.py`, with time made explicit: pymodbus's
//! framer sees chunks of a byte stream, ours sees every byte with the time
//! its stop bit ended, and frame boundaries are silences (t3.5 = 4011 µs at
//! 9600 baud, 11-bit characters of 1146 µs). So each pymodbus case comes in
//! two timings where they differ: separated by t3.5 of silence (what a
//! compliant bus does), and glued together without silence (one frame, its
//! CRC fails, dropped — and the server is in sync again at the next frame).
//! The cases pymodbus marks "we should not respond" (a valid frame wrapped in
//! garbage) get no response here.

use bridge_logic::postep60::Settings;
use host_tests::modbus_bench::{adu, ModbusBench};

/// pymodbus `good_frame`: id 2, read 125 holding registers at address 1.
/// Our id 2 is axis 1, and address 1 (loopback) is I2C-only: exception 02.
const GOOD: [u8; 8] = [0x02, 0x03, 0x00, 0x01, 0x00, 0x7D, 0xD4, 0x18];
const GOOD_REPLY: [u8; 5] = [0x02, 0x83, 0x02, 0x30, 0xF1];
/// A request that reads something: driver mode of id 2.
const MODE: [u8; 8] = [0x02, 0x03, 0x00, 0x14, 0x00, 0x01, 0xC4, 0x3D];
const MODE_REPLY: [u8; 7] = [0x02, 0x03, 0x02, 0x00, 0x04, 0xFD, 0x87];

fn line() -> ModbusBench {
    ModbusBench::new(2, Settings::FACTORY)
}

/// Silence that ends a frame at 9600 baud, with margin.
const T35: u64 = 4100;

#[test]
fn ok_frame_is_answered() {
    let mut b = line();
    assert_eq!(b.transact(&GOOD), Some(GOOD_REPLY.to_vec()));
    assert_eq!(b.transact(&MODE), Some(MODE_REPLY.to_vec()));
}

#[test]
fn two_frames_separated_by_t35_are_both_answered() {
    let mut b = line();
    b.put(&MODE);
    b.pause(T35);
    b.put(&GOOD);
    // Without waiting for our reply the master sent on: both frames were
    // complete, each is answered in turn.
    assert_eq!(b.collect(), vec![MODE_REPLY.to_vec(), GOOD_REPLY.to_vec()]);
}

#[test]
fn two_frames_without_silence_are_one_frame_and_dropped() {
    let mut b = line();
    b.put(&MODE);
    b.put(&MODE);
    assert!(b.collect().is_empty());
    assert_eq!(b.server.stats().crc_errors, 1);
    assert_eq!(b.transact(&MODE), Some(MODE_REPLY.to_vec()));
}

#[test]
fn bad_crc_is_dropped_silently() {
    let mut b = line();
    // pymodbus's manually mangled CRC
    b.put(&[0x02, 0x03, 0x00, 0x01, 0x00, 0x7D, 0xD4, 0x19]);
    assert!(b.collect().is_empty());
    assert_eq!(b.server.stats().crc_errors, 1);
    assert_eq!(b.server.stats().exceptions, 0);
    assert_eq!(b.transact(&GOOD), Some(GOOD_REPLY.to_vec()));
}

#[test]
fn wrong_id_with_good_crc_is_ignored() {
    let mut b = line();
    assert_eq!(
        b.transact(&[0x07, 0x03, 0x00, 0x14, 0x00, 0x01, 0xC4, 0x68]),
        None
    );
    assert_eq!(b.server.stats().frames_ok, 1);
    assert_eq!(b.server.stats().other_ids, 1);
}

#[test]
fn big_split_response_from_another_id_is_ignored() {
    let mut b = line();
    // pymodbus's 255-byte response from server 1 to a read of 125 registers
    // (all 0x0011), arriving in 11 chunks plus a final one; we are ids 3, 4
    // here so that it is another server's. The chunks are separated by
    // silences shorter than t1.5 (1719 µs).
    let mut s = Settings::FACTORY;
    s.base_address = 3;
    let mut b3 = ModbusBench::new(2, s);
    let mut body = vec![0x01, 0x03, 0xFA];
    for _ in 0..125 {
        body.extend_from_slice(&[0x00, 0x11]);
    }
    let frame = adu(&body);
    assert_eq!(frame.len(), 255);
    assert_eq!(frame[253..], [0xA5, 0x8F], "pymodbus's CRC");
    let mut chunks = frame.chunks(23);
    for chunk in chunks.by_ref() {
        b3.put(chunk);
        b3.pause(1500);
    }
    assert!(b3.collect().is_empty());
    assert_eq!(b3.server.stats().other_ids, 1);
    assert_eq!(b3.server.stats().gaps, 0);
    assert_eq!(b3.read(3, 0x14, 1), Ok(vec![4]));
    // The same response with one silence over t1.5 is dropped as broken.
    let (head, tail) = frame.split_at(100);
    b.put(head);
    b.pause(1800);
    b.put(tail);
    assert!(b.collect().is_empty());
    assert_eq!(b.server.stats().gaps, 1);
}

#[test]
fn split_frame_with_a_short_pause_is_one_frame() {
    let mut b = line();
    b.put(&MODE[..5]);
    b.pause(1000); // less than t1.5
    b.put(&MODE[5..]);
    assert_eq!(b.collect(), vec![MODE_REPLY.to_vec()]);
}

#[test]
fn split_frame_with_a_pause_over_t15_is_dropped_whole() {
    let mut b = line();
    b.put(&MODE[..5]);
    b.pause(2000); // over t1.5, under t3.5
    b.put(&MODE[5..]);
    assert!(b.collect().is_empty());
    assert_eq!(b.server.stats().gaps, 1);
    // over t3.5: two fragments, both fail the CRC
    b.put(&MODE[..5]);
    b.pause(T35);
    b.put(&MODE[5..]);
    assert!(b.collect().is_empty());
    assert_eq!(b.server.stats().crc_errors, 2);
    assert_eq!(b.transact(&MODE), Some(MODE_REPLY.to_vec()));
}

#[test]
fn leading_garbage_without_id() {
    let mut b = line();
    let garbage = [0x05, 0x04, 0x03];
    // garbage, silence, frame: the frame is answered
    b.put(&garbage);
    b.pause(T35);
    b.put(&GOOD);
    assert_eq!(b.collect(), vec![GOOD_REPLY.to_vec()]);
    // glued: one bad frame, dropped
    b.put(&garbage);
    b.put(&GOOD);
    assert!(b.collect().is_empty());
    assert_eq!(b.server.stats().crc_errors, 2);
}

#[test]
fn leading_garbage_with_our_id() {
    let mut b = line();
    // garbage that contains both our ids and a 0
    let garbage = [0x05, 0x04, 0x03, 0x02, 0x01, 0x00];
    b.put(&garbage);
    b.pause(T35);
    b.put(&GOOD);
    assert_eq!(b.collect(), vec![GOOD_REPLY.to_vec()]);
    b.put(&garbage);
    b.put(&GOOD);
    assert!(b.collect().is_empty());
}

#[test]
fn split_frame_after_ascii_garbage() {
    let mut b = line();
    // "ABCDEF" then the frame, split after 11 bytes, with silence between
    // the garbage and the frame.
    let mut stream = b"ABCDEF".to_vec();
    stream.extend_from_slice(&GOOD);
    b.put(&stream[..6]);
    b.pause(T35);
    b.put(&stream[6..11]);
    b.pause(500);
    b.put(&stream[11..]);
    assert_eq!(b.collect(), vec![GOOD_REPLY.to_vec()]);
    assert_eq!(b.server.stats().crc_errors, 1);
}

#[test]
fn coincidental_prefixes_are_not_taken_for_frames() {
    // Fragments that start like an exception response (02 90 07) or a
    // FC 0x10 request for id 2 (02 10 07 …), then the real frame.
    for garbage in [
        &[0x02, 0x90, 0x07][..],
        &[0x02, 0x10, 0x07],
        &[0x02, 0x10, 0x07, 0x10],
    ] {
        let mut b = line();
        b.put(garbage);
        b.pause(T35);
        b.put(&GOOD);
        assert_eq!(b.collect(), vec![GOOD_REPLY.to_vec()], "{garbage:02X?}");
        b.put(garbage);
        b.put(&GOOD);
        assert!(b.collect().is_empty(), "glued {garbage:02X?}");
        assert_eq!(b.server.stats().crc_errors, 2);
        assert_eq!(b.server.stats().exceptions, 1, "only GOOD's 02");
    }
}

#[test]
fn a_frame_wrapped_in_garbage_gets_no_response() {
    let mut b = line();
    let garbage = [0x05, 0x04, 0x03, 0x02, 0x01, 0x00];
    let mut stream = garbage.to_vec();
    stream.extend_from_slice(&MODE);
    stream.extend_from_slice(&garbage);
    b.put(&stream);
    assert!(b.collect().is_empty());
    assert_eq!(b.transact(&MODE), Some(MODE_REPLY.to_vec()));
}

#[test]
fn a_frame_with_trailing_data_gets_no_response() {
    let mut b = line();
    let mut stream = MODE.to_vec();
    stream.extend_from_slice(&[0x05, 0x04, 0x03, 0x02, 0x01, 0x00]);
    b.put(&stream);
    assert!(b.collect().is_empty());
    // but with t3.5 before the trailing bytes, the frame is answered and
    // the trailing bytes dropped
    b.put(&MODE);
    b.pause(T35);
    b.put(&[0x05, 0x04, 0x03, 0x02, 0x01, 0x00]);
    assert_eq!(b.collect(), vec![MODE_REPLY.to_vec()]);
}

#[test]
fn a_motion_command_in_a_bad_frame_never_moves_anything() {
    let mut b = line();
    let set = [
        0x01, 0x10, 0x00, 0x50, 0x00, 0x02, 0x04, 0x00, 0x00, 0x27, 0x10, 0xEC, 0xAF,
    ];
    // every single-bit error, anywhere in the frame: CRC-16 catches them all
    for i in 0..set.len() {
        for bit in 0..8 {
            let mut bad = set;
            bad[i] ^= 1 << bit;
            b.put(&bad);
            assert!(b.collect().is_empty(), "{bad:02X?}");
        }
    }
    b.run(300);
    assert_eq!(b.chip(0).abs_pos(), 0);
    assert_eq!(b.chip(1).abs_pos(), 0);
    assert_eq!(b.server.stats().frames_ok, 0);
    // … whereas the intact frame moves axis 0.
    assert_eq!(
        b.transact(&set),
        Some([0x01, 0x10, 0x00, 0x50, 0x00, 0x02, 0x41, 0xD9].to_vec())
    );
    b.run(300);
    assert!(b.chip(0).abs_pos() > 0);
}

#[test]
fn silence_boundaries_at_9600_baud() {
    let mut b = line();
    // exactly one character + t1.5 between byte ends: still one frame
    for &byte in &MODE {
        b.pause(1719);
        b.put(&[byte]);
    }
    assert_eq!(b.collect(), vec![MODE_REPLY.to_vec()]);
    // one µs more: a gap
    for &byte in &MODE {
        b.pause(1720);
        b.put(&[byte]);
    }
    assert!(b.collect().is_empty());
    assert_eq!(b.server.stats().gaps, 1);
}

#[test]
fn a_reply_goes_out_t35_after_the_request() {
    let mut b = line();
    b.put(&MODE);
    let end = b.now_us;
    b.pause(T35);
    assert_eq!(b.sent.len(), 1);
    assert_eq!(b.sent[0].0, end + 4011);
}

#[test]
fn joining_a_busy_line_mid_frame_resynchronises_at_the_next_silence() {
    let mut b = line();
    // We power up in the middle of another server's response.
    let other = [0x09, 0x03, 0x04, 0x02, 0x01, 0x00, 0x7D, 0xE3, 0xAA];
    b.put(&other[3..]);
    b.pause(T35);
    assert_eq!(b.transact(&MODE), Some(MODE_REPLY.to_vec()));
}

#[test]
fn nineteen_thousand_two_hundred_baud_uses_its_own_t15_and_t35() {
    let mut s = Settings::FACTORY;
    s.serial = bridge_logic::postep60::settings::Serial::from_code(4).unwrap(); // 19200 odd
    let mut b = ModbusBench::new(2, s);
    assert_eq!((b.timing.t15_us, b.timing.t35_us), (860, 2006));
    // a 1 ms silence inside a frame is tolerated at 9600 but not at 19200
    b.put(&MODE[..4]);
    b.pause(1000);
    b.put(&MODE[4..]);
    assert!(b.collect().is_empty());
    assert_eq!(b.server.stats().gaps, 1);
    b.put(&MODE[..4]);
    b.pause(800);
    b.put(&MODE[4..]);
    assert_eq!(b.collect(), vec![MODE_REPLY.to_vec()]);
}
