//! Plot what the profile generator and the simulated chip do for a
//! retargeted move.
//!
//! `cargo run -p host-tests --bin plot-profile [OUT.svg]` (default
//! `docs/profile-retarget.svg`): one axis (full steps on a chip at 1/128)
//! starts toward +10 000 steps, is retargeted behind itself at 0.6 s
//! (decelerate, reverse), then gets a new target and a higher max speed at
//! 1.4 s. Drawn: the required position, the profile's position and speed,
//! and the simulated powerSTEP01's position and speed read back from it.

use bridge_logic::motion::{AxisConfig, Limits};
use bridge_logic::powerstep::{DriveMode, StepSel};
use host_tests::rig::Rig;
use host_tests::svg::{render, Panel, Series};

fn main() {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "docs/profile-retarget.svg".into());
    let tick_us = 1000;
    let mut rig = new_rig(tick_us);
    rig.axis(0).move_to(10_000);
    let traces = simulate(&mut rig, tick_us);
    let svg = draw(&traces);
    if let Err(e) = std::fs::write(&out, svg) {
        eprintln!("plot-profile: cannot write {out}: {e}");
        std::process::exit(1);
    }
    println!(
        "wrote {out}; max following error {} microsteps",
        rig.max_following[0]
    );
}

/// One axis, full steps on a chip at 1/128, voltage mode, 8 000 steps/s.
fn new_rig(tick_us: u32) -> Rig {
    let cfg = AxisConfig {
        tick_us,
        logical_shift: 0,
        step: StepSel::OneTwentyEighth,
        drive: DriveMode::Voltage,
    };
    Rig::new(
        &[cfg],
        Limits {
            max_speed: 8_000,
            acc: 20_000,
            dec: 30_000,
        },
    )
}

/// What is drawn, (seconds, value) per tick.
struct Traces {
    /// The required position (the latest target).
    target: Vec<(f64, f64)>,
    /// The profile's position and speed.
    pos: Vec<(f64, f64)>,
    speed: Vec<(f64, f64)>,
    /// The simulated chip's ABS_POS / 128 and signed SPEED.
    chip: Vec<(f64, f64)>,
    chip_speed: Vec<(f64, f64)>,
}

/// 3 s of ticks: retargeted behind itself at 0.6 s, a new target and a
/// higher max speed at 1.4 s.
fn simulate(rig: &mut Rig, tick_us: u32) -> Traces {
    let (mut pos, mut target, mut speed, mut chip, mut chip_speed) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut required = 10_000i64;
    for k in 0..3_000u32 {
        match k {
            600 => {
                required = -3_000;
                rig.axis(0).move_to(required);
            }
            1400 => {
                required = 6_000;
                rig.axis(0).set_limits(Limits {
                    max_speed: 12_000,
                    acc: 20_000,
                    dec: 30_000,
                });
                rig.axis(0).move_to(required);
            }
            _ => {}
        }
        rig.tick();
        let t = f64::from(k + 1) * f64::from(tick_us) / 1e6;
        let a = rig.group.axis(0).expect("axis 0");
        pos.push((t, a.profile().position_fine() as f64 / (1u64 << 33) as f64));
        target.push((t, required as f64));
        speed.push((t, a.profile().velocity() as f64));
        chip.push((t, rig.chip_position(0) as f64 / 128.0));
        let dev = rig.chain.bus().device(0).expect("chip 0");
        let s = f64::from(dev.speed_reg()) / 67.108864;
        let sign = if dev.status().direction() == bridge_logic::powerstep::Direction::Forward {
            1.0
        } else {
            -1.0
        };
        chip_speed.push((t, sign * s));
    }
    Traces {
        target,
        pos,
        speed,
        chip,
        chip_speed,
    }
}

/// The two panels: positions, speeds.
fn draw(t: &Traces) -> String {
    render(
        "stepbridge: retargeted move, profile vs simulated powerSTEP01 (1 kHz tick)",
        &[
            Panel {
                title: "position",
                y_label: "full steps",
                series: vec![
                    Series {
                        name: "required (target)",
                        color: "#c33",
                        points: &t.target,
                    },
                    Series {
                        name: "profile position",
                        color: "#236",
                        points: &t.pos,
                    },
                    Series {
                        name: "chip ABS_POS / 128",
                        color: "#e90",
                        points: &t.chip,
                    },
                ],
            },
            Panel {
                title: "speed",
                y_label: "full steps/s",
                series: vec![
                    Series {
                        name: "profile speed",
                        color: "#292",
                        points: &t.speed,
                    },
                    Series {
                        name: "chip SPEED",
                        color: "#e90",
                        points: &t.chip_speed,
                    },
                ],
            },
        ],
    )
}
