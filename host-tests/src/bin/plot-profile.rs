//! Plot what the profile generator does for a retargeted move.
//!
//! `cargo run -p host-tests --bin plot-profile [OUT.svg]` (default
//! `docs/profile-retarget.svg`): an axis starts toward +10 000 steps, is
//! retargeted behind itself at 0.6 s (decelerate, reverse), then gets a new
//! target and a higher max speed at 1.4 s.

use bridge_logic::motion::{Limits, Profile};
use host_tests::svg::{render, Panel, Series};

fn main() {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "docs/profile-retarget.svg".into());
    let tick_us = 1000;
    let mut p = Profile::new(
        tick_us,
        Limits {
            max_speed: 8_000,
            acc: 20_000,
            dec: 30_000,
        },
    );
    p.move_to(10_000);
    let mut pos = Vec::new();
    let mut target = Vec::new();
    let mut speed = Vec::new();
    let mut required = 10_000i64;
    for k in 0..3_000u32 {
        match k {
            600 => {
                required = -3_000;
                p.move_to(required);
            }
            1400 => {
                required = 6_000;
                p.set_limits(Limits {
                    max_speed: 16_000,
                    acc: 20_000,
                    dec: 30_000,
                });
                p.move_to(required);
            }
            _ => {}
        }
        p.tick();
        let t = f64::from(k + 1) * f64::from(tick_us) / 1e6;
        pos.push((t, p.position_fine() as f64 / (1u64 << 33) as f64));
        target.push((t, required as f64));
        speed.push((t, p.velocity() as f64));
    }
    let svg = render(
        "stepbridge profile generator: retargeted move (1 kHz tick)",
        &[
            Panel {
                title: "position",
                y_label: "steps",
                series: vec![
                    Series {
                        name: "required (target)",
                        color: "#c33",
                        points: &target,
                    },
                    Series {
                        name: "profile position",
                        color: "#236",
                        points: &pos,
                    },
                ],
            },
            Panel {
                title: "speed",
                y_label: "steps/s",
                series: vec![Series {
                    name: "profile speed",
                    color: "#292",
                    points: &speed,
                }],
            },
        ],
    );
    if let Err(e) = std::fs::write(&out, svg) {
        eprintln!("plot-profile: cannot write {out}: {e}");
        std::process::exit(1);
    }
    println!("wrote {out}");
}
