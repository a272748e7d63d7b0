//! PNG plots of an evaluation, drawn by a small built-in rasteriser (no
//! plotting dependency): one image with
//! * left half: a top view of the reference and the aligned estimate on the
//!   two world axes of largest extent, equal aspect, with a legend and start
//!   markers;
//! * right half: the ATE per associated pose over time (seconds from the
//!   first associated estimate stamp) with the RMSE as a horizontal line.
//!
//! A title above both states the ATE RMSE, the alignment and the match count.

mod canvas;
mod font;

pub use canvas::{Canvas, Rgb};

use crate::{EvalError, EvalReport};
use std::path::Path;

/// Colour of the reference trajectory.
pub const REFERENCE_COLOR: Rgb = [0, 114, 178];
/// Colour of the aligned estimate.
pub const ESTIMATE_COLOR: Rgb = [213, 94, 0];
/// Colour of the ATE curve.
pub const ERROR_COLOR: Rgb = [0, 140, 100];
const BACKGROUND: Rgb = [255, 255, 255];
const FRAME_COLOR: Rgb = [60, 60, 60];
const GRID_COLOR: Rgb = [228, 228, 228];
const TEXT_COLOR: Rgb = [25, 25, 25];
const RMSE_COLOR: Rgb = [110, 110, 110];

/// Line widths, pixels. The reference is wider so it stays visible under
/// a well-aligned estimate.
const REFERENCE_WIDTH: f64 = 3.0;
const ESTIMATE_WIDTH: f64 = 2.0;
const ERROR_WIDTH: f64 = 2.0;
const START_MARKER_RADIUS: f64 = 5.0;
const SAMPLE_MARKER_RADIUS: f64 = 2.2;
/// Sample markers on the ATE curve are drawn up to this many poses.
const MAX_SAMPLE_MARKERS: usize = 400;
/// Text scales (pixels per font cell).
const TITLE_SCALE: usize = 3;
const LABEL_SCALE: usize = 2;
/// Heights and margins, pixels.
const TITLE_HEIGHT: f64 = 48.0;
const MARGIN_LEFT: f64 = 100.0;
const MARGIN_RIGHT: f64 = 30.0;
const MARGIN_TOP: f64 = 44.0;
const MARGIN_BOTTOM: f64 = 64.0;
const TICK_LEN: f64 = 6.0;
/// Distance of a panel title above its plot area.
const PANEL_TITLE_OFFSET: f64 = 30.0;
/// About this many ticks per axis.
const TARGET_TICKS: f64 = 6.0;
/// Share of the data range added on each side of the top view.
const VIEW_PADDING: f64 = 0.05;
/// Smallest axis span, in data units, so that a static trajectory still
/// gets a finite scale.
const MIN_SPAN: f64 = 1e-6;
/// Headroom above the largest ATE.
const ERROR_HEADROOM: f64 = 1.08;
/// Smallest plot size that leaves room for the margins.
const MIN_WIDTH: usize = 400;
const MIN_HEIGHT: usize = 240;

/// Options of [`plot_evaluation_with`].
#[derive(Debug, Clone, PartialEq)]
pub struct PlotOptions {
    /// Image width, pixels (default 1400, at least 400).
    pub width: usize,
    /// Image height, pixels (default 650, at least 240).
    pub height: usize,
    /// Title; default (`None`): "ATE RMSE <value> m (<alignment>, <n> matched)".
    pub title: Option<String>,
}

impl Default for PlotOptions {
    fn default() -> Self {
        Self { width: 1400, height: 650, title: None }
    }
}

impl PlotOptions {
    /// Checks the size.
    pub fn validate(&self) -> Result<(), EvalError> {
        if self.width < MIN_WIDTH || self.height < MIN_HEIGHT {
            return Err(EvalError::InvalidOptions(format!(
                "plot size {}x{} is below the minimum {MIN_WIDTH}x{MIN_HEIGHT}",
                self.width, self.height
            )));
        }
        Ok(())
    }
}

/// Writes the evaluation plot as PNG with default options.
pub fn plot_evaluation(report: &EvalReport, path: &Path) -> Result<(), EvalError> {
    plot_evaluation_with(report, path, &PlotOptions::default())
}

/// Writes the evaluation plot as PNG (atomically).
pub fn plot_evaluation_with(report: &EvalReport, path: &Path, opts: &PlotOptions) -> Result<(), EvalError> {
    let img = render_evaluation(report, opts)?;
    img.write_png(path)?;
    Ok(())
}

/// Renders the evaluation plot.
pub fn render_evaluation(report: &EvalReport, opts: &PlotOptions) -> Result<colslam_image::Image, EvalError> {
    opts.validate()?;
    let d = &report.detail;
    if d.reference_positions.is_empty() || d.aligned_positions.is_empty() || d.ate_errors.is_empty() {
        return Err(EvalError::Plot("the report holds no per-pose data (was it deserialised?)".into()));
    }
    let (w, h) = (opts.width as f64, opts.height as f64);
    let mut c = Canvas::new(opts.width, opts.height, BACKGROUND);
    let title = opts.title.clone().unwrap_or_else(|| {
        format!("ATE RMSE {} m ({} alignment, {} matched)", fmt_sig(report.ate_rmse), report.align, report.matched)
    });
    c.text_centered(0.5 * w, 0.5 * (TITLE_HEIGHT - Canvas::text_height(TITLE_SCALE)), &title, TITLE_SCALE, TEXT_COLOR);

    let half = (0.5 * w).floor();
    let left = Rect { x0: MARGIN_LEFT, y0: TITLE_HEIGHT + MARGIN_TOP, x1: half - MARGIN_RIGHT, y1: h - MARGIN_BOTTOM };
    let right = Rect { x0: half + MARGIN_LEFT, y0: left.y0, x1: w - MARGIN_RIGHT, y1: left.y1 };
    draw_top_view(&mut c, report, &left);
    draw_error_curve(&mut c, report, &right);
    Ok(c.into_image())
}

/// A plot area in pixels.
#[derive(Debug, Clone, Copy)]
struct Rect {
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
}

/// A linear map from data `[lo, hi]` to pixels `[p0, p1]`.
#[derive(Debug, Clone, Copy)]
struct Axis {
    lo: f64,
    hi: f64,
    p0: f64,
    p1: f64,
}

impl Axis {
    fn map(&self, v: f64) -> f64 {
        self.p0 + (v - self.lo) / (self.hi - self.lo) * (self.p1 - self.p0)
    }
}

const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

fn draw_top_view(c: &mut Canvas, report: &EvalReport, r: &Rect) {
    let d = &report.detail;
    let all = || d.reference_positions.iter().chain(&d.aligned_positions);
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in all() {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    // The two axes of largest extent, the larger one horizontal.
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| (hi[b] - lo[b]).total_cmp(&(hi[a] - lo[a])));
    let (ka, kb) = (order[0], order[1]);
    let span_a = (hi[ka] - lo[ka]).max(MIN_SPAN) * (1.0 + 2.0 * VIEW_PADDING);
    let span_b = (hi[kb] - lo[kb]).max(MIN_SPAN) * (1.0 + 2.0 * VIEW_PADDING);
    let (pw, ph) = (r.x1 - r.x0, r.y1 - r.y0);
    // Equal aspect: one pixel per `1 / px_per_unit` on both axes.
    let px_per_unit = (pw / span_a).min(ph / span_b);
    let (ca, cb) = (0.5 * (lo[ka] + hi[ka]), 0.5 * (lo[kb] + hi[kb]));
    let ax = Axis { lo: ca - 0.5 * pw / px_per_unit, hi: ca + 0.5 * pw / px_per_unit, p0: r.x0, p1: r.x1 };
    let ay = Axis { lo: cb - 0.5 * ph / px_per_unit, hi: cb + 0.5 * ph / px_per_unit, p0: r.y1, p1: r.y0 };
    let (na, nb) = (AXIS_NAMES[ka], AXIS_NAMES[kb]);
    draw_frame(c, r, &ax, &ay, &format!("{na} [m]"), &format!("{nb} [m]"));
    c.text_centered(
        0.5 * (r.x0 + r.x1),
        r.y0 - PANEL_TITLE_OFFSET,
        &format!("top view ({na}-{nb})"),
        LABEL_SCALE,
        TEXT_COLOR,
    );

    let project = |pts: &[colslam_geometry::Vec3]| -> Vec<(f64, f64)> {
        pts.iter().map(|p| (ax.map(p[ka]), ay.map(p[kb]))).collect()
    };
    let ref_px = project(&d.reference_positions);
    let est_px = project(&d.aligned_positions);
    c.polyline(&ref_px, REFERENCE_WIDTH, REFERENCE_COLOR);
    c.polyline(&est_px, ESTIMATE_WIDTH, ESTIMATE_COLOR);
    for (pts, color) in [(&ref_px, REFERENCE_COLOR), (&est_px, ESTIMATE_COLOR)] {
        if let Some(&p) = pts.first() {
            c.disc(p, START_MARKER_RADIUS, color);
        }
    }
    let est_label = if report.align == crate::Alignment::None { "estimate" } else { "estimate (aligned)" };
    let entries = [("reference", REFERENCE_COLOR), (est_label, ESTIMATE_COLOR), ("start", FRAME_COLOR)];
    draw_legend(c, r, &entries, &[&ref_px, &est_px]);
}

fn draw_error_curve(c: &mut Canvas, report: &EvalReport, r: &Rect) {
    let d = &report.detail;
    let t_max = d.seconds_from_start.iter().copied().fold(0.0f64, f64::max);
    let t_min = d.seconds_from_start.iter().copied().fold(0.0f64, f64::min);
    let e_max = d.ate_errors.iter().copied().fold(0.0f64, f64::max);
    let (t_lo, t_hi) = if t_max - t_min > MIN_SPAN { (t_min, t_max) } else { (t_min, t_min + 1.0) };
    let e_hi = if e_max > 0.0 { e_max * ERROR_HEADROOM } else { 1e-3 };
    let ax = Axis { lo: t_lo, hi: t_hi, p0: r.x0, p1: r.x1 };
    let ay = Axis { lo: 0.0, hi: e_hi, p0: r.y1, p1: r.y0 };
    draw_frame(c, r, &ax, &ay, "time [s]", "ATE [m]");
    c.text_centered(0.5 * (r.x0 + r.x1), r.y0 - PANEL_TITLE_OFFSET, "ATE over time", LABEL_SCALE, TEXT_COLOR);

    let y_rmse = ay.map(report.ate_rmse);
    c.line((r.x0, y_rmse), (r.x1, y_rmse), 1.5, RMSE_COLOR);

    let pts: Vec<(f64, f64)> =
        d.seconds_from_start.iter().zip(&d.ate_errors).map(|(&t, &e)| (ax.map(t), ay.map(e))).collect();
    c.polyline(&pts, ERROR_WIDTH, ERROR_COLOR);
    if pts.len() <= MAX_SAMPLE_MARKERS {
        for &p in &pts {
            c.disc(p, SAMPLE_MARKER_RADIUS, ERROR_COLOR);
        }
    }
    // The RMSE label goes on a white box above the curve, at the right end
    // of the RMSE line.
    let label = format!("rmse {}", fmt_sig(report.ate_rmse));
    let (lw, lh) = (Canvas::text_width(&label, LABEL_SCALE), Canvas::text_height(LABEL_SCALE));
    let (lx, ly) = (r.x1 - lw - 10.0, (y_rmse - lh - 8.0).max(r.y0 + 2.0));
    c.fill_rect(lx - 4.0, ly - 4.0, lx + lw + 4.0, ly + lh + 6.0, BACKGROUND);
    c.text(lx, ly, &label, LABEL_SCALE, RMSE_COLOR);
}

/// Grid, frame, ticks, tick labels and axis labels of a plot area.
fn draw_frame(c: &mut Canvas, r: &Rect, ax: &Axis, ay: &Axis, xlabel: &str, ylabel: &str) {
    let xt = ticks(ax.lo, ax.hi);
    let yt = ticks(ay.lo, ay.hi);
    for &(v, _) in &xt {
        let x = ax.map(v);
        c.line((x, r.y0), (x, r.y1), 1.0, GRID_COLOR);
    }
    for &(v, _) in &yt {
        let y = ay.map(v);
        c.line((r.x0, y), (r.x1, y), 1.0, GRID_COLOR);
    }
    for &(v, ref s) in &xt {
        let x = ax.map(v);
        c.line((x, r.y1), (x, r.y1 + TICK_LEN), 1.5, FRAME_COLOR);
        c.text_centered(x, r.y1 + TICK_LEN + 4.0, s, LABEL_SCALE, TEXT_COLOR);
    }
    for &(v, ref s) in &yt {
        let y = ay.map(v);
        c.line((r.x0 - TICK_LEN, y), (r.x0, y), 1.5, FRAME_COLOR);
        c.text_right(r.x0 - TICK_LEN - 4.0, y, s, LABEL_SCALE, TEXT_COLOR);
    }
    let corners = [(r.x0, r.y0), (r.x1, r.y0), (r.x1, r.y1), (r.x0, r.y1), (r.x0, r.y0)];
    c.polyline(&corners, 1.5, FRAME_COLOR);
    c.text_centered(0.5 * (r.x0 + r.x1), r.y1 + TICK_LEN + 30.0, xlabel, LABEL_SCALE, TEXT_COLOR);
    c.text_right(r.x0 - 8.0, r.y0 - 14.0, ylabel, LABEL_SCALE, TEXT_COLOR);
}

/// Legend box in the corner of `r` that covers the fewest plotted points.
fn draw_legend(c: &mut Canvas, r: &Rect, entries: &[(&str, Rgb)], curves: &[&Vec<(f64, f64)>]) {
    const PAD: f64 = 10.0;
    const SAMPLE: f64 = 30.0;
    const ROW: f64 = 24.0;
    let text_w = entries.iter().map(|(s, _)| Canvas::text_width(s, LABEL_SCALE)).fold(0.0, f64::max);
    let bw = PAD * 3.0 + SAMPLE + text_w;
    let bh = PAD * 2.0 + ROW * entries.len() as f64 - (ROW - Canvas::text_height(LABEL_SCALE));
    let candidates = [
        (r.x0 + PAD, r.y0 + PAD),
        (r.x1 - PAD - bw, r.y0 + PAD),
        (r.x0 + PAD, r.y1 - PAD - bh),
        (r.x1 - PAD - bw, r.y1 - PAD - bh),
    ];
    let covered = |&(x, y): &(f64, f64)| {
        curves.iter().flat_map(|v| v.iter()).filter(|p| p.0 >= x && p.0 <= x + bw && p.1 >= y && p.1 <= y + bh).count()
    };
    let (bx, by) = candidates.iter().copied().min_by_key(covered).unwrap_or(candidates[0]);
    c.fill_rect(bx, by, bx + bw, by + bh, BACKGROUND);
    let outline = [(bx, by), (bx + bw, by), (bx + bw, by + bh), (bx, by + bh), (bx, by)];
    c.polyline(&outline, 1.0, FRAME_COLOR);
    for (i, (label, color)) in entries.iter().enumerate() {
        let top = by + PAD + ROW * i as f64;
        let cy = top + 0.5 * Canvas::text_height(LABEL_SCALE);
        if *label == "start" {
            c.disc((bx + PAD + 0.5 * SAMPLE, cy), START_MARKER_RADIUS, *color);
        } else {
            c.line((bx + PAD, cy), (bx + PAD + SAMPLE, cy), 3.0, *color);
        }
        c.text(bx + 2.0 * PAD + SAMPLE, top, label, LABEL_SCALE, TEXT_COLOR);
    }
}

/// "Nice" ticks (1, 2 or 5 times a power of ten) inside `[lo, hi]`, with
/// labels carrying just enough decimals for the step.
fn ticks(lo: f64, hi: f64) -> Vec<(f64, String)> {
    let span = hi - lo;
    if !(span.is_finite() && span > 0.0) {
        return Vec::new();
    }
    let raw = span / TARGET_TICKS;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|&s| s >= raw).unwrap_or(10.0 * mag);
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last)
        .map(|k| {
            let v = k as f64 * step;
            let mut s = format!("{v:.decimals$}");
            if s.starts_with('-') && s[1..].chars().all(|ch| ch == '0' || ch == '.') {
                s.remove(0); // no "-0.0"
            }
            (v, s)
        })
        .collect()
}

/// Four significant digits, without exponent for the usual metre range.
fn fmt_sig(v: f64) -> String {
    format_significant(v, 4)
}

/// `v` with `digits` significant digits (at least 1) in fixed notation:
/// decimals only where they are significant (at most 9), so a large value
/// keeps all its integer digits (`30.6228` to 3 digits is `30.6`, `3062.8`
/// is `3063`, `0.5` is `0.500`). Zero and non-finite values print as Rust
/// does (`0`, `NaN`, `inf`).
pub fn format_significant(v: f64, digits: usize) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = digits.clamp(1, 17) as i64;
    let decimals = (digits - 1 - v.abs().log10().floor() as i64).clamp(0, 9) as usize;
    format!("{v:.decimals$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_ticks() {
        let t = ticks(0.0, 1.0);
        let v: Vec<&str> = t.iter().map(|(_, s)| s.as_str()).collect();
        assert_eq!(v, ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        let t = ticks(-0.013, 0.021);
        assert!(t.iter().any(|(_, s)| s == "0.00"), "{t:?}");
        assert!(t.iter().any(|(_, s)| s == "-0.01"), "{t:?}");
        assert!(t.iter().all(|(v, _)| *v >= -0.013 && *v <= 0.021));
        assert_eq!(ticks(12.0, 130.0).first().map(|x| x.1.clone()), Some("20".to_string()));
        assert!(ticks(1.0, 1.0).is_empty());
    }

    #[test]
    fn significant_digits() {
        assert_eq!(fmt_sig(0.023456), "0.02346");
        assert_eq!(fmt_sig(1.5), "1.500");
        assert_eq!(fmt_sig(1234.5), "1234");
        assert_eq!(format_significant(30.6228, 3), "30.6");
        assert_eq!(format_significant(306.228, 3), "306");
        assert_eq!(format_significant(0.5, 3), "0.500");
        assert_eq!(format_significant(0.0, 3), "0");
    }
}
