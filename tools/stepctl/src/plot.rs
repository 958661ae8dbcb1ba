//! `stepctl record --plot`: position and speed vs time as SVG, and `stepctl
//! path --plot`: two axes against each other (plotters, SVG backend only).

use std::path::Path;

use plotters::prelude::*;

use crate::error::{Error, Result};

/// One sample of `record`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Sample {
    pub t_s: f64,
    pub position: i32,
    pub speed: i32,
}

fn span(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1.0);
    (lo - pad, hi + pad)
}

/// A chart: name, axis label, the value of a sample, colour.
type Series = (&'static str, &'static str, fn(&Sample) -> f64, RGBColor);

/// Two charts, one above the other: position (steps) and speed (steps/s)
/// against time (s).
pub fn svg(path: &Path, title: &str, samples: &[Sample]) -> Result<()> {
    let fail =
        |e: &dyn std::fmt::Display| Error::Usage(format!("cannot draw {}: {e}", path.display()));
    let t_end = samples.last().map_or(1.0, |s| s.t_s.max(0.001));
    let root = SVGBackend::new(path, (900, 640)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    let root = root
        .titled(title, ("sans-serif", 20))
        .map_err(|e| fail(&e))?;
    let panels = root.split_evenly((2, 1));
    let series: [Series; 2] = [
        (
            "position",
            "position, steps",
            |s| f64::from(s.position),
            BLUE,
        ),
        ("speed", "speed, steps/s", |s| f64::from(s.speed), RED),
    ];
    for (area, (name, unit, value, color)) in panels.iter().zip(series) {
        let (lo, hi) = span(samples.iter().map(value));
        let mut chart = ChartBuilder::on(area)
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..t_end, lo..hi)
            .map_err(|e| fail(&e))?;
        chart
            .configure_mesh()
            .x_desc("time, s")
            .y_desc(unit)
            .draw()
            .map_err(|e| fail(&e))?;
        chart
            .draw_series(LineSeries::new(
                samples.iter().map(|s| (s.t_s, value(s))),
                color.stroke_width(2),
            ))
            .map_err(|e| fail(&e))?
            .label(name);
    }
    root.present().map_err(|e| fail(&e))?;
    Ok(())
}

/// Two axes against each other (`stepctl path --plot`): the recorded
/// points `xy` (steps of the first axis, steps of the second), joined in
/// the order taken.
pub fn xy_svg(path: &Path, title: &str, names: &(String, String), xy: &[(f64, f64)]) -> Result<()> {
    let fail =
        |e: &dyn std::fmt::Display| Error::Usage(format!("cannot draw {}: {e}", path.display()));
    let root = SVGBackend::new(path, (760, 760)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    let root = root
        .titled(title, ("sans-serif", 20))
        .map_err(|e| fail(&e))?;
    let (x0, x1) = span(xy.iter().map(|p| p.0));
    let (y0, y1) = span(xy.iter().map(|p| p.1));
    let mut chart = ChartBuilder::on(&root)
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| fail(&e))?;
    chart
        .configure_mesh()
        .x_desc(format!("{}, steps", names.0))
        .y_desc(format!("{}, steps", names.1))
        .draw()
        .map_err(|e| fail(&e))?;
    chart
        .draw_series(LineSeries::new(xy.iter().copied(), BLUE.stroke_width(2)))
        .map_err(|e| fail(&e))?;
    root.present().map_err(|e| fail(&e))?;
    Ok(())
}

pub fn csv(samples: &[Sample]) -> String {
    let mut s = String::from("t_s,position_steps,speed_steps_per_s\n");
    for x in samples {
        s.push_str(&format!("{:.4},{},{}\n", x.t_s, x.position, x.speed));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recording_draws_an_svg_with_both_charts() {
        let dir = std::env::temp_dir().join(format!("stepctl-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("rec.svg");
        let samples: Vec<Sample> = (0..50)
            .map(|i| Sample {
                t_s: f64::from(i) * 0.02,
                position: i * 100,
                speed: 5000,
            })
            .collect();
        svg(&path, "axis 1", &samples).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("<svg"));
        assert!(text.contains("position, steps") && text.contains("speed, steps/s"));
        assert!(text.matches("<polyline").count() >= 2);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_path_draws_its_two_axes_against_each_other() {
        let dir = std::env::temp_dir().join(format!("stepctl-xy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("xy.svg");
        let xy: Vec<(f64, f64)> = (0..40)
            .map(|i| (f64::from(i).cos() * 100.0, f64::from(i).sin() * 100.0))
            .collect();
        xy_svg(&path, "path", &("axis 1".into(), "axis 2".into()), &xy).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("<svg"));
        assert!(text.contains("axis 1, steps") && text.contains("axis 2, steps"));
        assert!(text.contains("<polyline"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn csv_has_a_header_and_a_line_per_sample() {
        let s = csv(&[Sample {
            t_s: 0.5,
            position: -3,
            speed: 7,
        }]);
        assert_eq!(s, "t_s,position_steps,speed_steps_per_s\n0.5000,-3,7\n");
    }
}
