//! The 0xA0 stream through hidraw: its acknowledgement, cadence and fields,
//! a move and a command's reply while it runs, what hidraw queues for a
//! reader that stops reading, and 0xA2 turning it off.

use std::time::{Duration, Instant};

use super::{ask, be16, be32, out, settle, trajectory};
use crate::hid::{is_stream, Hid, In};
use crate::Checks;

pub(super) fn stream(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    let r = ask(c, hid, "0xA0 stream", &out(0xA0))?;
    c.eq(
        "0xA0: acknowledged (packet id, response 0)",
        (r[1], r[15], r[14]),
        (0x00, 0x00, 0),
    );
    // Reports as they come, read at once.
    let mut got = Vec::new();
    while got.len() < 101 {
        match hid.read(1000)? {
            Some((r, t)) if is_stream(&r) => got.push((r, t)),
            Some(_) => {}
            None => break,
        }
    }
    c.eq("0xA0: 101 stream reports in a row", got.len(), 101);
    stream_reports(c, &got);
    stream_during_a_move(c, hid)?;
    stream_queue_and_off(c, hid)
}

/// The 101 reports read as they came: their cadence, the gaps, and the
/// last one's fields (axis 0 at rest on 15000).
fn stream_reports(c: &mut Checks, got: &[In]) {
    if let (Some(first), Some(last)) = (got.first(), got.last()) {
        let span = last.1.duration_since(first.1).as_secs_f64() * 1000.0;
        let mean = span / (got.len() - 1) as f64;
        c.check(
            "0xA0: one report every 10 ms (mean of 100)",
            (9.5..=10.5).contains(&mean),
            format!("{mean:.2} ms"),
        );
        let gaps: Vec<f64> = got
            .windows(2)
            .map(|w| w[1].1.duration_since(w[0].1).as_secs_f64() * 1000.0)
            .collect();
        let mut sorted = gaps.clone();
        sorted.sort_by(f64::total_cmp);
        let pct = |p: usize| sorted.get(sorted.len() * p / 100).copied().unwrap_or(0.0);
        let max = sorted.last().copied().unwrap_or(0.0);
        // The guest's scheduler (TCG on a shared host) delays a report now
        // and then; the stream's due times then catch up. A stall would not.
        c.check(
            "0xA0: the stream never stalls (no gap above 100 ms)",
            max <= 100.0,
            format!(
                "gaps: median {:.1} ms, 90% {:.1} ms, largest {max:.1} ms",
                pct(50),
                pct(90)
            ),
        );
        let r = &last.0;
        c.eq(
            "0xA0: position [20..23] MSB first",
            be32(r, 20) as i32,
            15_000,
        );
        c.eq("0xA0: speed [24..27] at rest", be32(r, 24) as i32, 0);
        c.eq("0xA0: final position [28..31]", be32(r, 28) as i32, 15_000);
        let t = f64::from(be16(r, 44)) * 0.125;
        c.check(
            "0xA0: temperature [44..45]",
            (24.0..=26.0).contains(&t),
            format!("{t} °C"),
        );
        c.eq(
            "0xA0: status [46] ACTIVE, CONFIG_SET [47] trajectory",
            (r[46], r[47]),
            (2, 4),
        );
    }
}

/// A move while streaming: the reports follow it; a command's reply
/// comes between them.
fn stream_during_a_move(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    hid.write(&trajectory(0, 12_000, 16_000, 16_000, 16_000))?;
    let mut moving = None;
    let mut reply = None;
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(2) && (moving.is_none() || reply.is_none()) {
        let Some((r, _)) = hid.read(500)? else { break };
        if is_stream(&r) {
            let (pos, speed) = (be32(&r, 20) as i32, be32(&r, 24) as i32);
            if speed < 0 && pos < 15_000 && moving.is_none() {
                moving = Some((pos, speed));
                hid.write(&out(0x88))?;
            }
        } else if r[15] == 0x87 {
            reply = Some(r);
        }
    }
    c.check(
        "0xA0 during a 0xB1 move: position falls, speed negative",
        moving.is_some(),
        format!("{moving:?}"),
    );
    c.check(
        "0xA0 running: a command's reply (0x88) comes between stream reports",
        reply.as_ref().is_some_and(|r| r[1] == 0xCC),
        "0xCC/0x87",
    );
    Ok(())
}

/// A reader that stops reading: hidraw keeps what its queue holds and
/// drops what comes after. The stream is stopped before the queue is
/// read, so the count is the queue's (0xA2's own answer is dropped too).
/// Then 0xA2 turns the stream off.
fn stream_queue_and_off(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    std::thread::sleep(Duration::from_millis(1500));
    hid.write(&out(0xA2))?;
    std::thread::sleep(Duration::from_millis(300));
    let queued = hid.drain()?;
    let streamed = queued.iter().filter(|(r, _)| is_stream(r)).count();
    c.check(
        "hidraw: a reader that paused 1.5 s finds 63 reports (its 64-slot ring keeps one free), the rest dropped",
        streamed == 63 && queued.len() == 63,
        format!("{streamed} stream reports, {} in all", queued.len()),
    );
    settle(hid, 0, Some(12_000), Duration::from_secs(10))?;
    let r = ask(c, hid, "0xA2 stream off (extension)", &out(0xA2))?;
    c.eq(
        "0xA2: response 0xA2, done",
        (r[1], r[15], r[14]),
        (0x00, 0xA2, 0),
    );
    let after = hid.read(200)?;
    c.check(
        "0xA2: no stream report after it",
        after.is_none(),
        format!("{:?}", after.map(|r| r.0[15])),
    );
    Ok(())
}
