//! A two-panel SVG bar chart (frames sent, run-on) per trace at 1 Mbit/s, log scale.

use std::fmt::Write;

use crate::scheme::Scheme;
use crate::Row;

const WIDTH: f64 = 760.0;
const PANEL_H: f64 = 220.0;
const LEFT: f64 = 60.0;
const COLORS: [&str; 3] = ["#c0392b", "#e69f00", "#0072b2"];

/// Title, the value plotted, and the panel's top edge.
type Panel = (&'static str, fn(&Row) -> f64, f64);

/// The plot for the 1 Mbit/s rows of `rows`.
pub fn svg(rows: &[Row]) -> String {
    let fast: Vec<&Row> = rows.iter().filter(|r| r.bitrate == 1_000_000).collect();
    let mut traces: Vec<&str> = Vec::new();
    for r in &fast {
        if !traces.contains(&r.trace) {
            traces.push(r.trace);
        }
    }
    let mut out = String::new();
    let height = 2.0 * PANEL_H + 90.0;
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{height}" font-family="sans-serif" font-size="11">"#
    );
    let _ = writeln!(out, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let panels: [Panel; 2] = [
        ("frames sent (log)", |r| r.frames as f64, 20.0),
        (
            "run-on after the wheel stops, ms (log)",
            |r| r.run_on_ms,
            40.0 + PANEL_H,
        ),
    ];
    for (title, value, top) in panels {
        panel(&mut out, &fast, &traces, title, value, top);
    }
    let legend_y = 2.0 * PANEL_H + 70.0;
    for (i, scheme) in Scheme::ALL.into_iter().enumerate() {
        let x = LEFT + 170.0 * i as f64;
        let _ = writeln!(
            out,
            r#"<rect x="{x}" y="{}" width="12" height="12" fill="{}"/><text x="{}" y="{}">{}</text>"#,
            legend_y - 10.0,
            COLORS[i],
            x + 16.0,
            legend_y,
            match scheme {
                Scheme::Paper => "paper (1 frame per unit step)",
                Scheme::Compat => "compat (bounded unit steps)",
                Scheme::Record => "feed record (absolute position)",
            }
        );
    }
    let _ = writeln!(out, "</svg>");
    out
}

fn panel(
    out: &mut String,
    rows: &[&Row],
    traces: &[&str],
    title: &str,
    value: fn(&Row) -> f64,
    top: f64,
) {
    let max = rows.iter().map(|r| value(r)).fold(1.0f64, f64::max);
    let decades = max.log10().ceil().max(1.0);
    let plot_h = PANEL_H - 40.0;
    let base = top + 20.0 + plot_h;
    let y_of = |v: f64| base - (v.max(1.0).log10() / decades) * plot_h;
    let _ = writeln!(
        out,
        r#"<text x="{LEFT}" y="{}" font-weight="bold">{title} at 1 Mbit/s</text>"#,
        top + 10.0
    );
    for d in 0..=decades as i32 {
        let y = y_of(10f64.powi(d));
        let _ = writeln!(
            out,
            r##"<line x1="{LEFT}" x2="{}" y1="{y}" y2="{y}" stroke="#ddd"/><text x="{}" y="{}" text-anchor="end">1e{d}</text>"##,
            WIDTH - 10.0,
            LEFT - 4.0,
            y + 4.0
        );
    }
    let group_w = (WIDTH - LEFT - 20.0) / traces.len() as f64;
    for (ti, trace) in traces.iter().enumerate() {
        let x0 = LEFT + group_w * ti as f64 + 10.0;
        for (si, scheme) in Scheme::ALL.into_iter().enumerate() {
            let Some(r) = rows
                .iter()
                .find(|r| r.trace == *trace && r.scheme == scheme)
            else {
                continue;
            };
            let v = value(r);
            let y = y_of(v);
            let x = x0 + si as f64 * (group_w - 20.0) / 3.0;
            let w = (group_w - 20.0) / 3.0 - 4.0;
            let _ = writeln!(
                out,
                r#"<rect x="{x:.1}" y="{y:.1}" width="{w:.1}" height="{:.1}" fill="{}"><title>{trace} {}: {v:.1}</title></rect>"#,
                (base - y).max(0.5),
                COLORS[si],
                scheme.name()
            );
        }
        let _ = writeln!(
            out,
            r#"<text x="{:.1}" y="{}" text-anchor="middle">{trace}</text>"#,
            x0 + (group_w - 20.0) / 2.0,
            base + 14.0
        );
    }
}
