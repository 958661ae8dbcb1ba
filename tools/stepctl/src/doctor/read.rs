//! The doctor's reads: the diagnostics block, each axis (state, STATUS, what
//! the bridge configured and what the chip holds), the tick counter twice and
//! the I/O extension's loopback.

use std::time::{Duration, Instant};

use bridge_logic::ext_space::{block, configured, diag};
use bridge_logic::powerstep::registers::Register;

use super::{configured_registers, word, AxisReading, Loopback, Options, Reading, TickRate, CHUNK};
use crate::bus::{deadline, u32_of, Bus};
use crate::error::Result;
use crate::ops::ext;

fn read_block(bus: &mut dyn Bus, unit: u8, address: u16, len: u16) -> Result<Vec<u16>> {
    let mut out = Vec::with_capacity(usize::from(len));
    let mut at = 0;
    while at < len {
        let n = CHUNK.min(len.saturating_sub(at));
        out.extend(bus.read(unit, address.saturating_add(at), n)?);
        at = at.saturating_add(n);
    }
    Ok(out)
}

/// The tick counter and the host time halfway through its read.
fn ticks_now(bus: &mut dyn Bus, unit: u8) -> Result<(u32, Instant)> {
    let t0 = Instant::now();
    let r = bus.read(unit, ext(block::DIAG, diag::TICKS), 2)?;
    let t1 = Instant::now();
    let half = t1.duration_since(t0).checked_div(2).unwrap_or_default();
    Ok((u32_of(&r), t0.checked_add(half).unwrap_or(t1)))
}

fn read_chip(bus: &mut dyn Bus, unit: u8, reg: Register) -> std::result::Result<u32, String> {
    let width = if reg.bytes() == 3 { 2 } else { 1 };
    bus.read(unit, 0x0100 | u16::from(reg.address()), width)
        .map(|r| u32_of(&r))
        .map_err(|e| e.to_string())
}

fn read_axis(bus: &mut dyn Bus, unit: u8) -> AxisReading {
    let block = read_block(bus, unit, ext(block::AXIS, 0), 10).map_err(|e| e.to_string());
    let status = read_chip(bus, unit, Register::Status).map(|v| v as u16);
    let configured = read_block(bus, unit, ext(block::CONFIGURED, 0), configured::LEN as u16)
        .map_err(|e| e.to_string());
    let chip = match &configured {
        Ok(c) => configured_registers(c)
            .into_iter()
            .map(|(r, _)| (r, read_chip(bus, unit, r)))
            .collect(),
        Err(_) => Vec::new(),
    };
    AxisReading {
        unit,
        block,
        status,
        configured,
        chip,
    }
}

/// Read everything [`judge`] needs. Only a box that does not answer at all
/// ends it early (`diag` then holds why).
pub fn read(bus: &mut dyn Bus, opts: &Options) -> Reading {
    let unit = opts.first_id;
    let mut r = Reading {
        bus: bus.name(),
        diag: Err(String::new()),
        axes: Vec::new(),
        tick: None,
        loopback: Loopback::NotRun,
    };
    r.diag =
        read_block(bus, unit, ext(block::DIAG, 0), diag::LEN as u16).map_err(|e| e.to_string());
    let Ok(d) = &r.diag else {
        return r;
    };
    let start = ticks_now(bus, unit);
    let n = word(d, diag::CHAIN_LENGTH);
    for k in 0..n {
        let Some(u) = u16::from(unit)
            .checked_add(k)
            .and_then(|u| u8::try_from(u).ok())
        else {
            break;
        };
        r.axes.push(read_axis(bus, u));
    }
    if opts.loopback {
        r.loopback = loopback(bus, unit, n);
    }
    if let Ok((t0, at0)) = start {
        let rest = Duration::from_secs_f64(opts.seconds.max(0.0)).saturating_sub(at0.elapsed());
        std::thread::sleep(rest);
        if let Ok((t1, at1)) = ticks_now(bus, unit) {
            if let Some(ticks) = t1.checked_sub(t0) {
                r.tick = Some(TickRate {
                    ticks,
                    seconds: at1.saturating_duration_since(at0).as_secs_f64(),
                });
            }
        }
    }
    r
}

/// I/O extension registers (`docs/ioext.md`).
pub(super) mod io {
    pub const OPTIONS: u16 = 0x0200;
    pub const CONFIG: u16 = 0x0202;
    pub const TX: u16 = 0x0210;
    pub const RX: u16 = 0x0220;
    pub const MAPPING: u16 = 0x0240;
    /// Bit 11 of the configuration: a transfer ended.
    pub const DONE: u32 = 1 << 11;
    /// 32 bits, mode 0, N = 10 (1.02 µs a bit), CS released, no restart.
    pub const LOOPBACK_CONFIG: u32 = 1 << 28 | 10 << 16 | 31;
    pub const PATTERN: u32 = 0xA55A_0FF0;
}

/// One 32-bit transfer with a MOSI → MISO jumper: what comes back must be
/// what went out. The port's options, configuration and transmit words are
/// put back after it; refused while the box mapping uses the port.
fn loopback(bus: &mut dyn Bus, unit: u8, axes: u16) -> Loopback {
    match run_loopback(bus, unit, axes) {
        Ok(l) => l,
        Err(e) => Loopback::Skipped(e.to_string()),
    }
}

fn run_loopback(bus: &mut dyn Bus, unit: u8, axes: u16) -> Result<Loopback> {
    for k in 0..axes {
        let Some(u) = u16::from(unit)
            .checked_add(k)
            .and_then(|u| u8::try_from(u).ok())
        else {
            break;
        };
        let at = io::MAPPING.saturating_add(k.saturating_mul(8));
        let m = bus.read(u, at, 7)?;
        if m.iter().any(|e| e & 0x8000 != 0) {
            return Ok(Loopback::Skipped(format!(
                "the I/O extension drives the box panel (axis {u} has mapped inputs or lamps, \
                 0x{at:04X}): unmap them first"
            )));
        }
    }
    let options = bus.read(unit, io::OPTIONS, 2)?;
    let config = bus.read(unit, io::CONFIG, 2)?;
    let tx = bus.read(unit, io::TX, 2)?;
    let words = |v: u32| [(v >> 16) as u16, v as u16];
    bus.write(unit, io::CONFIG, &words(io::LOOPBACK_CONFIG))?;
    bus.write(unit, io::OPTIONS, &[0, 1])?;
    // Reading the receive words clears the status bit; writing the
    // transmit words starts the transfer at the next control tick.
    bus.read(unit, io::RX, 2)?;
    bus.write(unit, io::TX, &words(io::PATTERN))?;
    let deadline = deadline(Duration::from_secs(2));
    let received = loop {
        let c = u32_of(&bus.read(unit, io::CONFIG, 2)?);
        if c & io::DONE != 0 {
            break Some(u32_of(&bus.read(unit, io::RX, 2)?));
        }
        if Instant::now() >= deadline {
            break None;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    // Put the port back as it was (the status bit is not configuration;
    // the transmit words are written while the port is on, which sends
    // them once).
    bus.write(unit, io::CONFIG, &words(u32_of(&config) & !io::DONE))?;
    bus.write(unit, io::TX, &tx)?;
    bus.write(unit, io::OPTIONS, &options)?;
    Ok(match received {
        Some(received) => Loopback::Done {
            sent: io::PATTERN,
            received,
        },
        None => Loopback::Skipped("the transfer did not end within 2 s".into()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::doctor::test_util::*;
    use crate::doctor::*;
    use crate::modbus::fake::{framed, rtu};

    /// A request reading `n` registers at `a` of id 1, and its reply.
    fn read_frames(a: u16, values: &[u16]) -> (String, String) {
        let [a0, a1] = a.to_be_bytes();
        let q = framed(&[1, 0x03, a0, a1, 0, values.len() as u8]);
        let mut body = vec![1, 0x03, (values.len() * 2) as u8];
        for v in values {
            body.extend_from_slice(&v.to_be_bytes());
        }
        (q, framed(&body))
    }

    #[test]
    fn the_axis_reads_are_the_axis_block_status_the_configured_block_and_each_register() {
        let mut c = vec![0u16; configured::LEN];
        c[usize::from(Register::OcdTh.address())] = 8;
        set32(&mut c, configured::MASK, 1 << Register::OcdTh.address());
        c[usize::from(configured::SET_UP)] = 1;
        let block = [0, 0, 0, 100, 0, 100, 1, 0, 0, 0xE612];
        let mut script = vec![read_frames(0x0600, &block), read_frames(0x011B, &[0xE612])];
        for (i, chunk) in c.chunks(16).enumerate() {
            script.push(read_frames(0x0700 + 16 * i as u16, chunk));
        }
        script.push(read_frames(0x0113, &[8]));
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        let a = read_axis(&mut m, 1);
        assert!(m.link.done());
        assert_eq!(a.status, Ok(0xE612));
        assert_eq!(a.chip, vec![(Register::OcdTh, Ok(8))]);
        assert_eq!(judge_registers(&a).verdict, Verdict::Ok);
    }

    #[test]
    fn the_diagnostics_are_read_in_chunks_of_16_registers() {
        let d = healthy_diag();
        let mut script = Vec::new();
        for (i, chunk) in d.chunks(16).enumerate() {
            script.push(read_frames(0x0300 + 16 * i as u16, chunk));
        }
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        assert_eq!(read_block(&mut m, 1, 0x0300, diag::LEN as u16).unwrap(), d);
        assert!(m.link.done());
    }

    #[test]
    fn the_loopback_sends_the_pattern_and_puts_the_port_back() {
        let w = |a: u16, v: &[u16]| {
            let [a0, a1] = a.to_be_bytes();
            let mut body = vec![1, 0x10, a0, a1, 0, v.len() as u8, (v.len() * 2) as u8];
            for x in v {
                body.extend_from_slice(&x.to_be_bytes());
            }
            (framed(&body), framed(&[1, 0x10, a0, a1, 0, v.len() as u8]))
        };
        let script = vec![
            read_frames(0x0240, &[0; 7]),
            read_frames(0x0200, &[0, 0]),
            read_frames(0x0202, &[0x1000, 0x0007]),
            read_frames(0x0210, &[0x1234, 0x5678]),
            w(0x0202, &[0x100A, 0x001F]),
            w(0x0200, &[0, 1]),
            read_frames(0x0220, &[0, 0]),
            w(0x0210, &[0xA55A, 0x0FF0]),
            read_frames(0x0202, &[0x100A, 0x081F]),
            read_frames(0x0220, &[0xA55A, 0x0FF0]),
            w(0x0202, &[0x1000, 0x0007]),
            w(0x0210, &[0x1234, 0x5678]),
            w(0x0200, &[0, 0]),
        ];
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        assert_eq!(
            loopback(&mut m, 1, 1),
            Loopback::Done {
                sent: 0xA55A_0FF0,
                received: 0xA55A_0FF0
            }
        );
        assert!(m.link.done());
    }

    #[test]
    fn a_box_with_no_chip_is_read_through_its_first_id_and_fails_the_chain() {
        let mut d = healthy_diag();
        d[usize::from(diag::CHAIN_LENGTH)] = 0;
        d[usize::from(diag::CHAIN_STATE)] = 3;
        let mut script = Vec::new();
        for (i, chunk) in d.chunks(16).enumerate() {
            script.push(read_frames(0x0300 + 16 * i as u16, chunk));
        }
        script.push(read_frames(0x034C, &[0, 100]));
        script.push(read_frames(0x034C, &[0, 110]));
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        let opts = Options {
            first_id: 1,
            loopback: false,
            seconds: 0.0,
        };
        let r = read(&mut m, &opts);
        assert!(m.link.done());
        assert!(r.axes.is_empty());
        assert_eq!(r.tick.map(|t| t.ticks), Some(10));
        let checks = judge(&r, &Expect::default());
        assert_eq!(find(&checks, "chain").verdict, Verdict::Fail);
        assert_eq!(
            find(&checks, "supply").verdict,
            Verdict::Ok,
            "read with no chip"
        );
    }

    #[test]
    fn over_usb_the_blocks_are_extension_reads_0xe0_of_at_most_16_registers() {
        use crate::usb::fake::{bus, reply};
        let d = healthy_diag();
        let replies = d
            .chunks(16)
            .map(|c| {
                let bytes: Vec<u8> = c.iter().flat_map(|v| v.to_be_bytes()).collect();
                vec![reply(0, 0, 0, 0xE0, &[(16, &bytes)])]
            })
            .collect();
        let mut b = bus(replies);
        assert_eq!(read_block(&mut b, 1, 0x0300, diag::LEN as u16).unwrap(), d);
        let w = &b.hid.0.written;
        assert_eq!(w.len(), 5);
        assert_eq!(
            (w[4][1], w[4][20], w[4][21], w[4][22]),
            (0xE0, 0x03, 0x40, 16)
        );
    }

    #[test]
    fn a_mapped_panel_is_not_overwritten_by_the_loopback() {
        let script = [read_frames(0x0240, &[0x8003, 0, 0, 0, 0, 0, 0])];
        let lines: Vec<(&str, &str)> = script
            .iter()
            .map(|(q, r)| (q.as_str(), r.as_str()))
            .collect();
        let mut m = rtu(&lines);
        assert!(matches!(loopback(&mut m, 1, 1), Loopback::Skipped(why) if why.contains("unmap")));
        assert!(m.link.done());
    }
}
