//! Side view of an evaluation: the reference and the aligned estimate on the
//! world axis of largest extent (horizontal) against the axis that the top
//! view of `colslam_eval::plot` leaves out (the one of least extent),
//! equal aspect. Drawn with colslam_eval's rasteriser.

use anyhow::{Context, Result};
use colslam_eval::EvalReport;
use colslam_eval::plot::{Canvas, ESTIMATE_COLOR, REFERENCE_COLOR, Rgb};
use std::path::Path;

/// Image size, pixels.
const WIDTH: usize = 900;
const HEIGHT: usize = 520;
const MARGIN: f64 = 60.0;
const TITLE_Y: f64 = 14.0;
const TEXT_SCALE: usize = 2;
const LINE_WIDTH: f64 = 2.0;
const START_RADIUS: f64 = 5.0;
/// Share of the data range added on each side.
const PADDING: f64 = 0.08;
/// Smallest span, metres, so a flat trajectory still gets a finite scale.
const MIN_SPAN: f64 = 1e-6;
const BACKGROUND: Rgb = [255, 255, 255];
const FRAME: Rgb = [60, 60, 60];
const TEXT: Rgb = [25, 25, 25];
const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

/// Writes the side view of `report` to `path` (PNG, atomically).
pub fn plot_side_view(report: &EvalReport, title: &str, path: &Path) -> Result<()> {
    let d = &report.detail;
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in d.reference_positions.iter().chain(&d.aligned_positions) {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    anyhow::ensure!(lo[0].is_finite(), "no positions to plot");
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| (hi[b] - lo[b]).total_cmp(&(hi[a] - lo[a])));
    // Largest extent horizontal, least extent vertical (the top view shows
    // the two largest).
    let (ka, kb) = (order[0], order[2]);
    let span_a = (hi[ka] - lo[ka]).max(MIN_SPAN) * (1.0 + 2.0 * PADDING);
    let span_b = (hi[kb] - lo[kb]).max(MIN_SPAN) * (1.0 + 2.0 * PADDING);
    let (x0, y0, x1, y1) = (MARGIN, MARGIN, WIDTH as f64 - MARGIN, HEIGHT as f64 - MARGIN);
    let scale = ((x1 - x0) / span_a).min((y1 - y0) / span_b);
    let (ca, cb) = (0.5 * (lo[ka] + hi[ka]), 0.5 * (lo[kb] + hi[kb]));
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let map = |p: &colslam_geometry::Vec3| (cx + (p[ka] - ca) * scale, cy - (p[kb] - cb) * scale);

    let mut c = Canvas::new(WIDTH, HEIGHT, BACKGROUND);
    c.text_centered(0.5 * WIDTH as f64, TITLE_Y, title, TEXT_SCALE, TEXT);
    c.polyline(&[(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)], 1.0, FRAME);
    let refs: Vec<(f64, f64)> = d.reference_positions.iter().map(map).collect();
    let ests: Vec<(f64, f64)> = d.aligned_positions.iter().map(map).collect();
    c.polyline(&refs, LINE_WIDTH + 1.0, REFERENCE_COLOR);
    c.polyline(&ests, LINE_WIDTH, ESTIMATE_COLOR);
    for (pts, color) in [(&refs, REFERENCE_COLOR), (&ests, ESTIMATE_COLOR)] {
        if let Some(&p) = pts.first() {
            c.disc(p, START_RADIUS, color);
        }
    }
    let (na, nb) = (AXIS_NAMES[ka], AXIS_NAMES[kb]);
    let caption = format!(
        "side view {na}-{nb}: {na} {:.3}..{:.3} m, {nb} {:.3}..{:.3} m, blue reference, orange estimate (aligned)",
        lo[ka], hi[ka], lo[kb], hi[kb]
    );
    c.text_centered(0.5 * WIDTH as f64, y1 + 20.0, &caption, 1, TEXT);
    c.into_image().write_png(path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
