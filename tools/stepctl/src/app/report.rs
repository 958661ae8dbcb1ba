//! The commands that report on the box: scan, info, status, raw, doctor.

use comfy_table::Table;
use serde_json::{json, Value};

use super::{table, Ctx, Output};
use crate::bus::hex;
use crate::error::{Error, Result};
use crate::ops::{self, reg};

pub(super) fn doctor(
    ctx: &mut Ctx,
    expect_axes: Option<u16>,
    supply: f64,
    loopback: bool,
    seconds: f64,
    tick_tolerance: f64,
) -> Result<Output> {
    use crate::doctor::{self, Expect, Options};
    if !(1.0..=1000.0).contains(&supply) {
        return Err(Error::Usage(format!(
            "--supply {supply}: a nominal supply in V, 1..=1000"
        )));
    }
    if !(0.0..=100.0).contains(&tick_tolerance) {
        return Err(Error::Usage(format!(
            "--tick-tolerance {tick_tolerance}: a percentage, 0..=100"
        )));
    }
    let opts = Options {
        first_id: ctx.first_id,
        loopback,
        seconds,
    };
    let expect = Expect {
        axes: expect_axes,
        supply_v: supply,
        tick_tolerance: tick_tolerance / 100.0,
    };
    let checks = doctor::run(ctx.bus, &opts, &expect)?;
    let (ok, warn, fail) = doctor::summary(&checks);
    let code = if fail > 0 {
        crate::error::exit::DOCTOR_FAIL
    } else {
        0
    };
    Ok(Output {
        text: doctor::text(&checks),
        json: json!({
            "bus": ctx.bus.name(),
            "checks": checks,
            "summary": { "ok": ok, "warn": warn, "fail": fail },
            "exit_code": code,
        }),
        code,
    })
}

pub(super) fn scan(ctx: &mut Ctx, (lo, hi): (u8, u8), probe_ms: u64) -> Result<Output> {
    let name = ctx.bus.name();
    ctx.bus.set_timeout_ms(probe_ms);
    let mut found = Vec::new();
    for id in lo..=hi {
        match ctx.bus.read(id, reg::HW_FW_INFO, 3) {
            Ok(v) => {
                let fw = v.get(2).copied().unwrap_or(0);
                found.push(json!({
                    "id": id,
                    "driver_id": format!("0x{:02X}", v.first().copied().unwrap_or(0) & 0xFF),
                    "firmware": format!("{}.{}", fw >> 8, fw & 0xFF),
                }));
            }
            // It answered, if only with an exception: something is there.
            Err(Error::Exception { code, .. }) => {
                found.push(json!({ "id": id, "exception": code }))
            }
            Err(_) => {}
        }
    }
    if found.is_empty() {
        return Err(Error::Comm(format!(
            "no id in {lo}-{hi} answered on {name} within {probe_ms} ms each \
             (baud rate and parity as the box's settings? --probe-ms longer?)"
        )));
    }
    let mut t = table(&["id", "driver id", "firmware"]);
    for f in &found {
        t.add_row(vec![
            f["id"].to_string(),
            f["driver_id"].as_str().unwrap_or("?").to_string(),
            f["firmware"].as_str().unwrap_or("-").to_string(),
        ]);
    }
    Ok(Output::new(
        format!("{} id(s) answered on {name}:\n{t}", found.len()),
        json!({ "bus": name, "ids": found }),
    ))
}

pub(super) fn info(ctx: &mut Ctx) -> Result<Output> {
    let i = ops::box_info(ctx.bus, ctx.first_id)?;
    let text = format!(
        "box on {}\n  PoStep60 driver id {}, hardware {}, firmware {} (build {})\n  axes: {} (ids {}..={})\n  \
         last reset: {}; settings: {}; up {} s",
        i.bus,
        i.driver_id,
        i.hardware,
        i.firmware,
        i.build_id,
        i.axes,
        ctx.first_id,
        u16::from(ctx.first_id)
            .saturating_add(i.axes.max(1))
            .saturating_sub(1),
        i.reset_cause,
        i.settings_source,
        i.uptime_s
    );
    Ok(Output::new(
        text,
        serde_json::to_value(&i).unwrap_or(Value::Null),
    ))
}

pub(super) fn status_table(rows: &[ops::AxisStatus]) -> Table {
    let mut t = table(&[
        "axis", "position", "target", "speed/s", "state", "mode", "driver", "faults", "temp °C",
        "supply V",
    ]);
    for s in rows {
        t.add_row(vec![
            s.axis.to_string(),
            s.position.to_string(),
            s.target.to_string(),
            s.speed.to_string(),
            s.state.to_string(),
            format!("{} {}", s.mode, s.mode_name),
            s.driver_status_name.to_string(),
            s.fault_names.clone(),
            format!("{:.1}", s.temperature_c),
            format!("{:.2}", s.voltage_v),
        ]);
    }
    t
}

fn statuses(ctx: &mut Ctx, axes: &[u8]) -> Result<Vec<ops::AxisStatus>> {
    let axes = ctx.axes(axes)?;
    axes.iter().map(|a| ops::axis_status(ctx.bus, *a)).collect()
}

pub(super) fn status(ctx: &mut Ctx, axes: &[u8]) -> Result<Output> {
    let rows = statuses(ctx, axes)?;
    Ok(Output::new(
        status_table(&rows).to_string(),
        json!({ "axes": rows }),
    ))
}

pub(super) fn raw(
    ctx: &mut Ctx,
    unit: u8,
    command: u16,
    values: &[u16],
    count: Option<u16>,
) -> Result<Output> {
    let count = if !ctx.bus.is_modbus() {
        count
    } else if let Some(c) = count {
        Some(c)
    } else if command >> 8 == 0 && values.is_empty() {
        use bridge_logic::transport::modbus::map::registers;
        match registers(command) {
            Some((n, false)) => Some(u16::from(n)),
            Some((_, true)) => {
                return Err(Error::Usage(format!(
                    "0x{command:04X} is a write command: give its value(s)"
                )))
            }
            // Let the box say what it thinks of it (exception 02).
            None => Some(1),
        }
    } else {
        Some(1)
    };
    let r = match ctx.bus.raw(unit, command, values, count) {
        Ok(r) => r,
        Err(e) => return Err(ctx.explain(unit, command, e)),
    };
    let mut text = format!("-> {}\n<- {}", hex(&r.request), hex(&r.reply));
    if !r.registers.is_empty() {
        let regs: Vec<String> = r
            .registers
            .iter()
            .map(|v| format!("0x{v:04X} ({v})"))
            .collect();
        text.push_str(&format!("\nregisters: {}", regs.join(", ")));
    }
    Ok(Output::new(
        text,
        json!({
            "request": hex(&r.request), "reply": hex(&r.reply), "registers": r.registers,
        }),
    ))
}

/// `scan --usb`: the devices, without opening them.
pub fn scan_usb(found: &[crate::usb::Found]) -> Result<Output> {
    if found.is_empty() {
        return Err(crate::usb::not_found());
    }
    let mut t = table(&["serial", "product", "path"]);
    for f in found {
        t.add_row(vec![f.serial.clone(), f.product.clone(), f.path.clone()]);
    }
    Ok(Output::new(
        format!("{} USB device(s):\n{t}", found.len()),
        json!({ "usb": found }),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::app::test_util::*;

    #[test]
    fn scan_lists_the_ids_that_answer_and_skips_silent_ones() {
        let mut m = rtu(&[
            (
                "01 03 00 0A 00 03 25 C9",
                "01 03 06 00 41 01 00 00 01 DD 46",
            ),
            (
                "02 03 00 0A 00 03 25 FA",
                "02 03 06 00 41 01 00 00 01 C9 B6",
            ),
            ("03 03 00 0A 00 03 24 2B", ""),
        ]);
        let o = run_on(&mut m, &["scan", "--ids", "1-3"]).unwrap();
        let ids: Vec<u64> = o.json["ids"]
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i["id"].as_u64().unwrap())
            .collect();
        assert_eq!(ids, vec![1, 2]);
        assert_eq!(o.json["ids"][0]["firmware"], "0.1");
    }

    #[test]
    fn scan_with_nothing_answering_is_a_communication_error() {
        let mut m = rtu(&[("05 03 00 0A 00 03 24 4D", "")]);
        assert_eq!(
            run_on(&mut m, &["scan", "--ids", "5"])
                .unwrap_err()
                .exit_code(),
            2
        );
    }

    #[test]
    fn status_without_axes_asks_the_chain_length_then_every_axis() {
        let mut m = rtu(&[
            ("01 03 03 40 00 01 85 9A", "01 03 02 00 01 79 84"),
            (MOTION_1, &motion(1, 0, 0, 0, 1, 0)),
            ("01 03 00 14 00 01 C4 0E", "01 03 02 00 04 B9 87"),
            ("01 03 00 13 00 01 75 CF", "01 03 02 00 02 39 85"),
            ("01 03 00 11 00 01 D4 0F", "01 03 02 00 C8 B9 D2"),
            ("01 03 00 10 00 01 85 CF", "01 03 02 01 4D 79 E1"),
        ]);
        let o = run_on(&mut m, &["status"]).unwrap();
        assert_eq!(o.json["axes"][0]["mode_name"], "position");
        assert!(o.text.contains("position"));
        assert!(m.link.done());
    }

    #[test]
    fn raw_reads_a_command_with_its_own_register_count() {
        let mut m = rtu(&[("01 03 00 40 00 02 C5 DF", "01 03 04 FF FF FC 18 BB 1D")]);
        let o = run_on(&mut m, &["raw", "1", "0x40"]).unwrap();
        assert_eq!(o.json["registers"], json!([0xFFFF, 0xFC18]));
        assert!(o.text.contains("<- 01 03 04 FF FF FC 18"));
    }

    #[test]
    fn raw_surfaces_an_exception_with_its_meaning() {
        let mut m = rtu(&[("01 03 00 99 00 01 54 25", "01 83 02 C0 F1")]);
        let e = run_on(&mut m, &["raw", "1", "0x99"]).unwrap_err();
        assert!(
            e.to_string().contains("exception 02: illegal data address"),
            "{e}"
        );
    }

    #[test]
    fn raw_refuses_to_read_a_write_command_before_sending() {
        let mut m = rtu(&[]);
        assert_eq!(
            run_on(&mut m, &["raw", "1", "0x50"])
                .unwrap_err()
                .exit_code(),
            1
        );
    }
}
