//! A tiny dependency-free SVG line-chart writer for the plots in `docs/`.

use std::fmt::Write as _;

/// One line of a panel.
pub struct Series<'a> {
    pub name: &'a str,
    pub color: &'a str,
    pub points: &'a [(f64, f64)],
}

/// One panel (shared x axis).
pub struct Panel<'a> {
    pub title: &'a str,
    pub y_label: &'a str,
    pub series: Vec<Series<'a>>,
}

const W: f64 = 900.0;
const PANEL_H: f64 = 260.0;
const ML: f64 = 80.0;
const MR: f64 = 20.0;
const MT: f64 = 30.0;
const MB: f64 = 40.0;

fn bounds(panel: &Panel) -> (f64, f64, f64, f64) {
    let pts = panel.series.iter().flat_map(|s| s.points.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    if y1 <= y0 {
        y1 = y0 + 1.0;
    }
    let pad = (y1 - y0) * 0.05;
    (x0, x1, y0 - pad, y1 + pad)
}

/// Render panels stacked vertically, x in seconds.
pub fn render(title: &str, panels: &[Panel]) -> String {
    let h = MT + panels.len() as f64 * (PANEL_H + MB) + 10.0;
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{h}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(s, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = writeln!(
        s,
        r#"<text x="{}" y="18" font-size="15" text-anchor="middle">{title}</text>"#,
        W / 2.0
    );
    for (i, panel) in panels.iter().enumerate() {
        let top = MT + i as f64 * (PANEL_H + MB);
        let (x0, x1, y0, y1) = bounds(panel);
        let f = Frame {
            top,
            pw: W - ML - MR,
            x0,
            x1,
            y0,
            y1,
        };
        axes(&mut s, &f, panel);
        lines(&mut s, &f, panel);
    }
    s.push_str("</svg>\n");
    s
}

/// Where a panel is drawn: its top, plot width and data bounds.
struct Frame {
    top: f64,
    pw: f64,
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
}

impl Frame {
    fn px(&self, x: f64) -> f64 {
        ML + (x - self.x0) / (self.x1 - self.x0) * self.pw
    }

    fn py(&self, y: f64) -> f64 {
        self.top + PANEL_H - (y - self.y0) / (self.y1 - self.y0) * PANEL_H
    }
}

/// A panel's frame, grid with its tick labels, y label and title.
fn axes(s: &mut String, f: &Frame, panel: &Panel) {
    let (top, pw) = (f.top, f.pw);
    let _ = writeln!(
        s,
        r##"<rect x="{ML}" y="{top}" width="{pw}" height="{PANEL_H}" fill="none" stroke="#888"/>"##
    );
    for k in 0..=5 {
        let yv = f.y0 + (f.y1 - f.y0) * k as f64 / 5.0;
        let xv = f.x0 + (f.x1 - f.x0) * k as f64 / 5.0;
        let _ = writeln!(
            s,
            r##"<line x1="{ML}" x2="{}" y1="{y}" y2="{y}" stroke="#eee"/><text x="{}" y="{}" text-anchor="end">{yv:.0}</text>"##,
            ML + pw,
            ML - 4.0,
            f.py(yv) + 4.0,
            y = f.py(yv)
        );
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{}" text-anchor="middle">{xv:.2} s</text>"#,
            f.px(xv),
            top + PANEL_H + 15.0
        );
    }
    let _ = writeln!(
        s,
        r#"<text x="14" y="{}" transform="rotate(-90 14 {})" text-anchor="middle">{}</text>"#,
        top + PANEL_H / 2.0,
        top + PANEL_H / 2.0,
        panel.y_label
    );
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}">{}</text>"#,
        ML + 6.0,
        top + 14.0,
        panel.title
    );
}

/// Each series as a path, and its name in the legend.
fn lines(s: &mut String, f: &Frame, panel: &Panel) {
    for (j, series) in panel.series.iter().enumerate() {
        let mut d = String::new();
        for (k, &(x, y)) in series.points.iter().enumerate() {
            let _ = write!(
                d,
                "{}{:.1},{:.1} ",
                if k == 0 { "M" } else { "L" },
                f.px(x),
                f.py(y)
            );
        }
        let _ = writeln!(
            s,
            r#"<path d="{d}" fill="none" stroke="{}" stroke-width="1.5"/>"#,
            series.color
        );
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{}" fill="{}">{}</text>"#,
            ML + f.pw - 200.0,
            f.top + 16.0 + 14.0 * j as f64,
            series.color,
            series.name
        );
    }
}
