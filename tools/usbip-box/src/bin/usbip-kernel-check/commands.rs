//! Every USB command of manual §10 through hidraw: OUT reports written byte
//! by byte from the manual's tables (`OutDATA[0]` = 0x02, the report id, as
//! stepctl and a Windows HID host send it; `[1]` the command, `[62]` the
//! axis, `[63]` 0), IN reports checked at the tables' offsets, never with
//! the project's codec. The expectations are `host-tests/tests/
//! usb_commands.rs`'s, on a 4-axis box that runs in real time.

use std::time::{Duration, Instant};

use host_tests::usb_manual::{be16, be32, le32, out, phys, trajectory, write_driver_settings};

use crate::device::Attached;
use crate::hid::Hid;
use crate::Checks;

mod stream;

/// The box's unique id (`usbip_box::postep_box::UID`), as 0x01 reports it.
use usbip_box::postep_box::UID;

/// The reply to `o`, checked for the IN report id; an empty report when
/// none came (the checks on it then fail).
fn ask(c: &mut Checks, hid: &Hid, name: &str, o: &[u8; 64]) -> Result<Vec<u8>, String> {
    let r = hid.transact(o)?.unwrap_or_default();
    c.check(
        &format!("{name}: answered, IN_REPORT_ID 0x02, 64 bytes"),
        r.len() == 64 && r[0] == 0x02,
        format!("{} bytes", r.len()),
    );
    Ok(if r.len() == 64 { r } else { vec![0; 64] })
}

/// 0xE0 (extension): `n` registers of the extension space from `address`.
fn ext_read(hid: &Hid, axis: u8, address: u16, n: u8) -> Result<Vec<u16>, String> {
    let mut o = out(0xE0);
    o[20..22].copy_from_slice(&address.to_be_bytes());
    o[22] = n;
    o[62] = axis;
    let r = hid
        .transact(&o)?
        .ok_or(format!("0xE0 {address:#06x}: no answer"))?;
    if r[14] != 0 {
        return Err(format!("0xE0 {address:#06x}: status {}", r[14]));
    }
    Ok((0..usize::from(n)).map(|i| be16(&r, 16 + 2 * i)).collect())
}

fn ext_i32(hid: &Hid, axis: u8, address: u16) -> Result<i32, String> {
    let v = ext_read(hid, axis, address, 2)?;
    Ok((u32::from(v[0]) << 16 | u32::from(v[1])) as i32)
}

/// The axis's position (extension 0x0602).
fn position(hid: &Hid, axis: u8) -> Result<i32, String> {
    ext_i32(hid, axis, 0x0602)
}

/// The simulated chip's ABS_POS (extension 0x0101: the powerSTEP01
/// register, read from the chip by GetParam), sign-extended from 22 bits.
fn chip_abs_pos(hid: &Hid, axis: u8) -> Result<i32, String> {
    let raw = ext_i32(hid, axis, 0x0101)? as u32 & 0x3F_FFFF;
    Ok(((raw << 10) as i32) >> 10)
}

/// Wait until the axis rests: idle (state 1) at speed 0 on `target` if one
/// is given, else idle on the same position in two reads 100 ms apart (a
/// reply comes before the next control tick has started the motion). Its
/// position.
fn settle(hid: &Hid, axis: u8, target: Option<i32>, within: Duration) -> Result<i32, String> {
    let t0 = Instant::now();
    let mut last = None;
    loop {
        let v = ext_read(hid, axis, 0x0600, 7)?;
        let word = |i: usize| (u32::from(v[i]) << 16 | u32::from(v[i + 1])) as i32;
        let (speed, pos, state) = (word(0), word(2), v[6]);
        let rest = state == 1 && speed == 0;
        match target {
            Some(t) if rest && pos == t => return Ok(pos),
            None if rest && last == Some(pos) => return Ok(pos),
            _ => {}
        }
        last = rest.then_some(pos);
        if t0.elapsed() > within {
            return Err(format!(
                "axis {axis} not at rest{} after {} s (at {pos}, {speed} steps/s, state {state})",
                target.map_or(String::new(), |t| format!(" on {t}")),
                within.as_secs()
            ));
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn diag_u32(hid: &Hid, offset: u16) -> Result<u32, String> {
    Ok(ext_i32(hid, 0, 0x0300 | offset)? as u32)
}

pub fn run(c: &mut Checks, hid: &mut Hid) -> Result<(), String> {
    device_info(c, hid)?;
    factory_reads(c, hid)?;
    trajectory_move(c, hid)?;
    stream::stream(c, hid)?;
    stop_and_zero(c, hid)?;
    axis_select(c, hid)?;
    refused_and_run_sleep(c, hid)?;
    driver_registers(c, hid)?;
    step_dir(c, hid)?;
    driver_settings(c, hid)?;
    other_configuration(c, hid)?;
    custom_name(c, hid)?;
    bad_reports(c, hid)?;
    short_report(c, hid)?;
    Ok(())
}

fn device_info(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    let r = ask(c, hid, "0x01 device info", &out(0x01))?;
    // 0x01's [1..2] is BL_FW_VERSION (MSB first), not a packet id.
    c.eq(
        "0x01: bootloader [1..2] and application [3..4] version 0x0109 (the PoStep60's), response [15]",
        (be16(&r, 1), be16(&r, 3), r[15]),
        (0x0109, 0x0109, 0x00),
    );
    c.eq("0x01: DEVICE_MODE [5] application", r[5], 0xAB);
    c.eq("0x01: bootloader override pin [6] bit 0 high", r[6] & 1, 1);
    c.eq(
        "0x01: supply [8..9] MSB first, 24 V at 0.072 V",
        be16(&r, 8),
        333,
    );
    c.eq(
        "0x01: IAP_UID [24..35] MSB first",
        (be32(&r, 24), be32(&r, 28), be32(&r, 32)),
        (UID[0], UID[1], UID[2]),
    );
    let t = f64::from(be16(&r, 44)) * 0.125;
    c.check(
        "0x01: temperature [44..45] MSB first, about 25 °C",
        (24.0..=26.0).contains(&t),
        format!("{t} °C"),
    );
    c.eq("0x01: status [46] ACTIVE", r[46], 0x02);
    c.eq("0x01: axis [13], done [14]", (r[13], r[14]), (0, 0));
    Ok(())
}

fn factory_reads(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    let r = ask(c, hid, "0x81 read driver settings", &out(0x81))?;
    c.eq(
        "0x81: packet id 0xBA, response 0x81",
        (r[1], r[15]),
        (0xBA, 0x81),
    );
    let ctrl = u16::from_le_bytes([r[40], r[41]]);
    c.eq(
        "0x81: CTRL MODE 1/16 and ENBL (factory)",
        ctrl & 0x79,
        (4 << 3) | 1,
    );
    c.eq("0x81: temperature limit [56] 80 °C (factory)", r[56], 80);
    c.eq("0x81: CONFIG_SET [62] trajectory (factory)", r[62], 4);
    let e = ask(c, hid, "0x84 read EEPROM", &out(0x84))?;
    c.eq(
        "0x84: packet id 0x84, response 0x00",
        (e[1], e[15]),
        (0x84, 0x00),
    );
    c.eq(
        "0x84: TORQUE 1.0 A (Tq 123) as stored",
        u16::from_le_bytes([e[42], e[43]]) & 0xFF,
        123,
    );
    let o = ask(c, hid, "0x88 read other configuration", &out(0x88))?;
    c.eq(
        "0x88: packet id 0xCC, response 0x87",
        (o[1], o[15]),
        (0xCC, 0x87),
    );
    c.eq(
        "0x88: max speed, acc, dec LSB first (factory 1000)",
        (le32(&o, 24), le32(&o, 28), le32(&o, 32)),
        (1000, 1000, 1000),
    );
    Ok(())
}

fn trajectory_move(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    // 80 000 steps/s is above any 16-bit value: USB limits are 32-bit.
    let r = ask(
        c,
        hid,
        "0xB1 trajectory",
        &trajectory(0, 15_000, 80_000, 160_000, 160_000),
    )?;
    c.eq(
        "0xB1: packet id 0, response 0xB1, done",
        (r[1], r[15], r[14]),
        (0x00, 0xB1, 0),
    );
    let o = ask(c, hid, "0x88 after 0xB1", &out(0x88))?;
    c.eq("0x88: 0xB1's 32-bit max speed", le32(&o, 24), 80_000);
    let t0 = Instant::now();
    let pos = settle(hid, 0, Some(15_000), Duration::from_secs(20))?;
    c.eq("0xB1 move: the axis arrives at 15000", pos, 15_000);
    c.eq(
        "0xB1 move: the simulated chip's ABS_POS is there",
        chip_abs_pos(hid, 0)?,
        phys(15_000),
    );
    c.check(
        "0xB1 move: time",
        true,
        format!("{:.2} s", t0.elapsed().as_secs_f64()),
    );
    Ok(())
}

fn stop_and_zero(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    hid.transact(&trajectory(0, 400_000, 16_000, 16_000, 16_000))?;
    std::thread::sleep(Duration::from_millis(500));
    let r = ask(c, hid, "0xB2 trajectory stop", &out(0xB2))?;
    c.eq("0xB2: done", (r[1], r[15], r[14]), (0x00, 0x00, 0));
    let p = settle(hid, 0, None, Duration::from_secs(5))?;
    std::thread::sleep(Duration::from_millis(200));
    c.check(
        "0xB2: the axis stopped short of its target and stays",
        p < 400_000 && position(hid, 0)? == p,
        format!("at {p}"),
    );
    let r = ask(c, hid, "0xB3 trajectory zero", &out(0xB3))?;
    c.eq("0xB3: done", (r[1], r[15], r[14]), (0x00, 0x00, 0));
    std::thread::sleep(Duration::from_millis(100));
    c.eq("0xB3: the position reads 0", position(hid, 0)?, 0);
    c.eq("0xB3: the chip's ABS_POS reads 0", chip_abs_pos(hid, 0)?, 0);
    Ok(())
}

fn axis_select(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    let mut t = trajectory(0, 2000, 16_000, 16_000, 16_000);
    t[62] = 1;
    let r = ask(c, hid, "[62] = 1 selects axis 1", &t)?;
    c.eq("[62] = 1: [13] echoes axis 1, done", (r[13], r[14]), (1, 0));
    c.eq(
        "axis 1 arrives",
        settle(hid, 1, Some(2000), Duration::from_secs(10))?,
        2000,
    );
    c.eq(
        "axis 1: its chip's ABS_POS",
        chip_abs_pos(hid, 1)?,
        phys(2000),
    );
    c.eq("axis 0 did not move", position(hid, 0)?, 0);
    t[62] = 7;
    let r = ask(c, hid, "[62] = 7 (the chain has 4)", &t)?;
    c.eq("[62] = 7: no such axis (9)", (r[13], r[14]), (7, 9));
    Ok(())
}

fn refused_and_run_sleep(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    let mut sd = out(0x90);
    sd[20..24].copy_from_slice(&480u32.to_le_bytes());
    let r = ask(c, hid, "0x90 step/dir in mode 4", &sd)?;
    c.eq(
        "0x90 in mode 4: response 0x90, wrong mode (1)",
        (r[1], r[15], r[14]),
        (0x00, 0x90, 1),
    );
    let mut p = out(0xB0);
    p[20..24].copy_from_slice(&48u32.to_le_bytes());
    p[24] = 200;
    let r = ask(c, hid, "0xB0 set PWM", &p)?;
    c.eq(
        "0xB0: response 0xB0, unsupported (5)",
        (r[1], r[15], r[14]),
        (0x00, 0xB0, 5),
    );
    let mut rs = out(0xA1);
    rs[20] = 0x00;
    let r = ask(c, hid, "0xA1 sleep (0x00)", &rs)?;
    c.eq("0xA1 0x00: done", (r[1], r[15], r[14]), (0x00, 0x00, 0));
    std::thread::sleep(Duration::from_millis(50));
    let i = ask(c, hid, "0x01 while asleep", &out(0x01))?;
    c.eq("0x01: status [46] SLEEP", i[46], 0x01);
    let mut t = trajectory(0, 100, 1000, 1000, 1000);
    t[62] = 0;
    let r = ask(c, hid, "0xB1 while asleep", &t)?;
    c.eq("0xB1 while asleep: refused, asleep (2)", r[14], 2);
    rs[20] = 0x01;
    let r = ask(c, hid, "0xA1 run (0x01)", &rs)?;
    c.eq("0xA1 0x01: done", r[14], 0);
    std::thread::sleep(Duration::from_millis(50));
    let i = ask(c, hid, "0x01 after run", &out(0x01))?;
    c.eq("0x01: status [46] ACTIVE again", i[46], 0x02);
    rs[20] = 0xDA;
    let r = ask(c, hid, "0xA1 with I2C's 0xDA", &rs)?;
    c.eq("0xA1 0xDA: ignored (4)", r[14], 4);
    Ok(())
}

fn driver_registers(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    let r = ask(c, hid, "0x85 read driver registers", &out(0x85))?;
    c.eq(
        "0x85: packet id 0xBC, response 0x00",
        (r[1], r[15]),
        (0xBC, 0x00),
    );
    c.eq(
        "0x85: CTRL MODE 1/16, ENBL",
        u16::from_le_bytes([r[40], r[41]]) & 0x79,
        (4 << 3) | 1,
    );
    c.eq(
        "0x85: STATUS [54..55] no fault",
        u16::from_le_bytes([r[54], r[55]]),
        0,
    );
    let r = ask(c, hid, "0x86 reset faults", &out(0x86))?;
    c.eq("0x86: done", (r[1], r[15], r[14]), (0x00, 0x00, 0));
    Ok(())
}

fn step_dir(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    // CONFIG_SET 2 (step control) through 0x80.
    let regs = [0x0C21, 0x01FF, 0x0030, 0x0080, 0x0110, 0x0040, 0x0A59, 0];
    let r = ask(
        c,
        hid,
        "0x80 mode 2 (step control)",
        &write_driver_settings(regs, 2, 80, 1, 0),
    )?;
    c.eq("0x80 mode 2: done", r[14], 0);
    let mut sd = out(0x90);
    sd[20..24].copy_from_slice(&480u32.to_le_bytes()); // 480 000 / 480 = 1000 steps/s
    let r = ask(c, hid, "0x90 step/dir 480", &sd)?;
    c.eq("0x90: response 0x90, done", (r[15], r[14]), (0x90, 0));
    std::thread::sleep(Duration::from_millis(2500));
    c.eq(
        "0x90: runs at 480 000 / 480 = 1000 steps/s",
        ext_i32(hid, 0, 0x0600)?,
        1000,
    );
    sd[24] = 0x01;
    hid.transact(&sd)?;
    std::thread::sleep(Duration::from_millis(3500));
    c.eq(
        "0x90 [24] = 1: reversed, −1000 steps/s",
        ext_i32(hid, 0, 0x0600)?,
        -1000,
    );
    sd[20..24].copy_from_slice(&0u32.to_le_bytes());
    hid.transact(&sd)?;
    let p = settle(hid, 0, None, Duration::from_secs(10));
    c.check(
        "0x90 StepValue 0: the axis stops",
        p.is_ok(),
        format!("{p:?}"),
    );
    Ok(())
}

fn driver_settings(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    // CTRL: ENBL, MODE 1/8 (0011), ISGAIN 20 (10), DTIME 650 ns (10);
    // TORQUE 0x0D0 with SMPLTH 3; the rest stored as they are.
    let regs = [
        0x0A19, 0x03D0, 0x0031, 0x0181, 0x0512, 0x0A41, 0x0A5A, 0x0000,
    ];
    let r = ask(
        c,
        hid,
        "0x80 write driver settings",
        &write_driver_settings(regs, 5, 90, 1, 3),
    )?;
    c.eq(
        "0x80: packet id 0, response 0, done",
        (r[1], r[15], r[14]),
        (0x00, 0x00, 0),
    );
    std::thread::sleep(Duration::from_millis(300));
    let r = ask(c, hid, "0x81 after 0x80", &out(0x81))?;
    let reg = |i: usize| u16::from_le_bytes([r[40 + 2 * i], r[41 + 2 * i]]);
    c.eq(
        "0x81: CTRL and TORQUE read back",
        (reg(0), reg(1)),
        (0x0A19, 0x03D0),
    );
    c.eq(
        "0x81: OFF..DRIVE read back",
        (2..7).map(reg).collect::<Vec<_>>(),
        regs[2..7].to_vec(),
    );
    c.eq("0x81: STATUS no fault", reg(7), 0);
    c.eq(
        "0x81: limit, idle, overheat, address, CONFIG_SET, serial",
        (r[56], r[57], r[58], r[59], r[60], r[61], r[62], r[63]),
        (90, 61, 3, 123, 3, 1, 5, 3),
    );
    // The save runs at rest: 0x84 reads the store.
    let e = ask(c, hid, "0x84 after 0x80", &out(0x84))?;
    c.eq(
        "0x84: stored TORQUE, limit, serial",
        (u16::from_le_bytes([e[42], e[43]]), e[56], e[63]),
        (0x03D0, 90, 3),
    );
    Ok(())
}

fn other_configuration(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    // Profile 1 (BINx, the mode 0x80 just set): limits and switches, no
    // move. 90 000 steps/s: within the chip's cap at 1/8 (99 848).
    let mut t = trajectory(1, 0, 90_000, 200_000, 300_000);
    t[36] = 0b011; // end switch on, NC
    t[40..44].copy_from_slice(&250i32.to_le_bytes());
    t[44..48].copy_from_slice(&(-75i32).to_le_bytes());
    let r = ask(c, hid, "0xB1 limits and switches", &t)?;
    c.eq("0xB1: response 0xB1, done", (r[15], r[14]), (0xB1, 0));
    let r = ask(c, hid, "0x88 read other configuration", &out(0x88))?;
    c.eq(
        "0x88: max speed, acc, dec as 0xB1 wrote them",
        (le32(&r, 24), le32(&r, 28), le32(&r, 32)),
        (90_000, 200_000, 300_000),
    );
    c.eq("0x88: [36] end switch, NC, BINx enabled", r[36], 0b00111);
    c.eq(
        "0x88: BIN1/BIN2 steps",
        (le32(&r, 40) as i32, le32(&r, 44) as i32),
        (250, -75),
    );
    let r = ask(c, hid, "0x87 save other configurations", &out(0x87))?;
    c.eq("0x87: done", (r[1], r[15], r[14]), (0x00, 0x00, 0));
    Ok(())
}

fn custom_name(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    let mut w = out(0xC0);
    w[2..15].copy_from_slice(b"left gantry X");
    let r = ask(c, hid, "0xC0 write custom name", &w)?;
    c.eq("0xC0: done", (r[1], r[15], r[14]), (0x00, 0x00, 0));
    let r = ask(c, hid, "0xC1 read custom name", &out(0xC1))?;
    c.eq("0xC1: response 0xC0", (r[1], r[15]), (0x00, 0xC0));
    c.eq(
        "0xC1: the name at [16..]",
        &r[16..29],
        b"left gantry X".as_slice(),
    );
    c.check(
        "0xC1: zero after it",
        r[29..48].iter().all(|b| *b == 0),
        "[29..47]",
    );
    Ok(())
}

fn bad_reports(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    let bad = diag_u32(hid, 0x16)?;
    let unknown = diag_u32(hid, 0x18)?;
    let mut t = trajectory(4, 5000, 16_000, 16_000, 16_000);
    t[2] = 0;
    t[63] = 0x01; // "Must be always 0x00!"
    let r = hid.unanswered(&t)?;
    c.check(
        "[63] = 0x01: ignored, no answer",
        r.is_none(),
        format!("{r:?}"),
    );
    let r = hid.unanswered(&out(0x42))?;
    c.check(
        "unknown command 0x42: no answer",
        r.is_none(),
        format!("{r:?}"),
    );
    let r = hid.unanswered(&t[..20])?;
    c.check("a 20-byte report: no answer", r.is_none(), format!("{r:?}"));
    c.eq(
        "bad reports counted (diagnostics 0x0316)",
        diag_u32(hid, 0x16)? - bad,
        2,
    );
    c.eq(
        "unknown command counted (diagnostics 0x0318)",
        diag_u32(hid, 0x18)? - unknown,
        1,
    );
    Ok(())
}

/// Linux usbhid strips a report id of 0: a hidraw write whose first byte is
/// 0x00 reaches the device as 63 bytes, `OutDATA[1..63]`. Any other first
/// byte goes out as it is, 64 bytes.
fn short_report(c: &mut Checks, hid: &Hid) -> Result<(), String> {
    let mut o = out(0xC1);
    o[0] = 0x01;
    let r = hid.transact(&o)?;
    c.check(
        "OutDATA[0] = 0x01 (not the report id): 64 bytes on the wire, answered like 0x02",
        r.as_ref().is_some_and(|r| r[15] == 0xC0),
        format!("{:?}", r.map(|r| (r[1], r[15], r[14]))),
    );
    let mut o = out(0xC1);
    o[0] = 0x00;
    let r = hid.transact(&o)?;
    c.check(
        "a 63-byte report (hidraw write with [0] = 0x00) is taken as OutDATA[1..63]",
        r.as_ref().is_some_and(|r| r[15] == 0xC0),
        format!("{:?}", r.map(|r| (r[1], r[15], r[14]))),
    );
    Ok(())
}

/// 0x02: no answer, the device restarts and leaves the bus (hidraw reports
/// the disconnect, or nothing comes).
fn reset_once(c: &mut Checks, hid: Hid, att: &Attached, name: &str) -> Result<(), String> {
    hid.write(&out(0x02))?;
    let r = hid.read(crate::hid::NO_ANSWER_WAIT.as_millis() as i32);
    c.check(
        &format!("{name}: no answer (the device restarts)"),
        matches!(r, Ok(None) | Err(_)),
        match &r {
            Ok(None) => "nothing came".to_string(),
            Ok(Some((r, _))) => format!("{:?}", &r[..16]),
            Err(e) => e.clone(),
        },
    );
    drop(hid);
    let gone = att.wait_gone()?;
    c.check(
        &format!("{name}: the device leaves the bus"),
        true,
        format!("after {:.2} s", gone.as_secs_f64()),
    );
    Ok(())
}

/// 0x02 twice: boot mode, then the application; re-attached each time.
pub fn system_reset(
    c: &mut Checks,
    att: Attached,
    hid: Hid,
    listen: &str,
) -> Result<(Attached, Hid), String> {
    reset_once(c, hid, &att, "0x02")?;
    let att = Attached::attach(listen)?;
    let hid = Hid::open(c, &att)?;
    let r = ask(c, &hid, "0x01 after 0x02", &out(0x01))?;
    c.eq(
        "boot mode: 0x01 DEVICE_MODE 0xB0, status SLEEP",
        (r[5], r[46]),
        (0xB0, 0x01),
    );
    let r = ask(
        c,
        &hid,
        "0xB1 in boot mode",
        &trajectory(0, 5000, 1000, 1000, 1000),
    )?;
    c.eq("boot mode: 0xB1 refused (8)", r[14], 8);
    let r = ask(c, &hid, "0x88 after the restart", &out(0x88))?;
    c.eq(
        "the restart kept 0x87's stored limits",
        le32(&r, 24),
        90_000,
    );
    let r = ask(c, &hid, "0xC1 after the restart", &out(0xC1))?;
    c.eq(
        "the restart kept 0xC0's name",
        &r[16..29],
        b"left gantry X".as_slice(),
    );
    reset_once(c, hid, &att, "0x02 in boot mode")?;
    let att = Attached::attach(listen)?;
    let hid = Hid::open(c, &att)?;
    let r = ask(c, &hid, "0x01 after the second 0x02", &out(0x01))?;
    c.eq(
        "application again: DEVICE_MODE 0xAB, ACTIVE",
        (r[5], r[46]),
        (0xAB, 0x02),
    );
    Ok((att, hid))
}

/// 0x83 and its table's 0x82: factory settings, in use and stored.
pub fn erase(c: &mut Checks, hid: &mut Hid) -> Result<(), String> {
    for code in [0x82u8, 0x83] {
        // Something to erase: limits in use, and settings stored by 0x80.
        hid.transact(&trajectory(0, 0, 3000, 4000, 5000))?;
        let regs = [
            0x0A19, 0x03D0, 0x0031, 0x0181, 0x0512, 0x0A41, 0x0A5A, 0x0000,
        ];
        hid.transact(&write_driver_settings(regs, 5, 90, 1, 3))?;
        std::thread::sleep(Duration::from_millis(300));
        let r = ask(c, hid, &format!("{code:#04x} erase EEPROM"), &out(code))?;
        c.eq(
            &format!("{code:#04x}: done"),
            (r[1], r[15], r[14]),
            (0x00, 0x00, 0),
        );
        std::thread::sleep(Duration::from_millis(300));
        let r = ask(c, hid, &format!("0x81 after {code:#04x}"), &out(0x81))?;
        c.eq(
            &format!("{code:#04x}: factory mode 4, limit 80 °C in use"),
            (r[62], r[56]),
            (4, 80),
        );
        let e = ask(c, hid, &format!("0x84 after {code:#04x}"), &out(0x84))?;
        c.eq(
            &format!("{code:#04x}: factory limit 80 °C, serial 0 stored"),
            (e[56], e[63]),
            (80, 0),
        );
        let o = ask(c, hid, &format!("0x88 after {code:#04x}"), &out(0x88))?;
        c.eq(
            &format!("{code:#04x}: factory max speed 1000"),
            le32(&o, 24),
            1000,
        );
    }
    Ok(())
}
