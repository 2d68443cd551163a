//! Trajectory plots (SVG or PNG, chosen by the output's extension), drawn with plotters and an
//! embedded DejaVu Sans (assets/, Bitstream Vera license) so PNG text needs no system fonts.
//!
//! Panels, all against the ground truth's world `w` after aligning the estimate the way
//! [`crate::eval::evaluate`] does:
//! 1. top view (x-y) of the ground truth and the aligned estimate, equal axis scales;
//! 2. height (z) over time;
//! 3. ATE position error of every matched pose over time;
//! 4. with a stats CSV (`t_s`, `backend_ms` columns), back-end time per keyframe.
//!
//! Times are seconds since the first ground-truth pose. Stats-file times that fall inside the
//! ground truth's span are taken as the same clock and shifted the same way; otherwise they
//! are taken as already relative.

use crate::eval::{evaluate, EvalOptions, EvalReport};
use anyhow::{anyhow, bail, Context, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use povins_platform::trajectory::StampedPose;
use std::ops::Range;
use std::path::Path;
use std::sync::OnceLock;

/// DejaVu Sans Book, registered as plotters' `sans-serif`.
static FONT_TTF: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
pub(crate) const FONT: &str = "sans-serif";

/// Output size in pixels (SVG user units).
pub const SIZE_PX: (u32, u32) = (1600, 1100);
/// Longest polyline drawn per series; longer series are decimated (plots stay small).
const MAX_POINTS: usize = 4000;

const GT_COLOR: RGBColor = RGBColor(40, 40, 40);
pub(crate) const EST_COLOR: RGBColor = RGBColor(214, 39, 40);
pub(crate) const ERR_COLOR: RGBColor = RGBColor(31, 119, 180);
pub(crate) const BACKEND_COLOR: RGBColor = RGBColor(44, 160, 44);

pub(crate) fn register_font() -> Result<()> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE
        .get_or_init(|| plotters::style::register_font(FONT, FontStyle::Normal, FONT_TTF).is_ok());
    if ok {
        Ok(())
    } else {
        bail!("the embedded font could not be loaded")
    }
}

/// One row of a stats CSV: keyframe time and back-end time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BackendSample {
    /// Keyframe time, s.
    pub t_s: f64,
    /// Back-end (optimization) time for that keyframe, ms.
    pub backend_ms: f64,
}

/// Reads a CSV whose header names at least `t_s` and `backend_ms` (any order, extra columns
/// allowed, a leading `#` on the header is ignored).
pub fn read_stats_csv(path: &Path) -> Result<Vec<BackendSample>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read stats file {}", path.display()))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((_, header)) = lines.next() else {
        bail!("{}: empty stats file", path.display());
    };
    let cols: Vec<&str> = header
        .trim_start_matches('#')
        .split(',')
        .map(str::trim)
        .collect();
    let col = |name: &str| {
        cols.iter().position(|c| *c == name).ok_or_else(|| {
            anyhow!(
                "{}:1: header has no `{name}` column (found {cols:?})",
                path.display()
            )
        })
    };
    let (i_t, i_b) = (col("t_s")?, col("backend_ms")?);
    let mut out = Vec::new();
    for (i, line) in lines {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let get = |k: usize, name: &str| -> Result<f64> {
            let s = fields
                .get(k)
                .ok_or_else(|| anyhow!("{}:{}: missing `{name}` field", path.display(), i + 1))?;
            match s.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => bail!(
                    "{}:{}: `{name}` value {s:?} is not a finite number",
                    path.display(),
                    i + 1
                ),
            }
        };
        out.push(BackendSample {
            t_s: get(i_t, "t_s")?,
            backend_ms: get(i_b, "backend_ms")?,
        });
    }
    Ok(out)
}

/// Everything a figure shows, in plot units.
struct Figure {
    title: String,
    est_label: String,
    /// (x, y) top view, m.
    gt_xy: Vec<(f64, f64)>,
    est_xy: Vec<(f64, f64)>,
    /// (t s, z m).
    gt_z: Vec<(f64, f64)>,
    est_z: Vec<(f64, f64)>,
    /// (t s, error m).
    err: Vec<(f64, f64)>,
    /// (t s, ms).
    backend: Option<Vec<(f64, f64)>>,
    ate_rmse_m: f64,
}

pub(crate) fn decimate<T: Copy>(v: &[T]) -> Vec<T> {
    let stride = v.len().div_ceil(MAX_POINTS).max(1);
    let mut out: Vec<T> = v.iter().step_by(stride).copied().collect();
    // Keep the last point so the curve ends where the data does.
    if let Some(&last) = v.last() {
        if !(v.len() - 1).is_multiple_of(stride) {
            out.push(last);
        }
    }
    out
}

fn build(
    gt: &[StampedPose],
    est: &[StampedPose],
    report: &EvalReport,
    backend: Option<&[BackendSample]>,
    title: String,
) -> Figure {
    let t0_ns = gt.first().map_or(0, |p| p.t_ns);
    let rel = |t_ns: i64| (t_ns - t0_ns) as f64 * 1e-9;
    let tf = &report.transform;
    // (t s, x, y, z m) of the whole estimate mapped into w; its clock moved onto the ground
    // truth's by the evaluation offset.
    let est_w: Vec<(f64, f64, f64, f64)> = est
        .iter()
        .map(|p| {
            let q = tf.apply_position(&p.p_wb);
            (rel(p.t_ns) + report.t_offset_s, q.x, q.y, q.z)
        })
        .collect();
    let gt_span = (rel(t0_ns), gt.last().map_or(0.0, |p| rel(p.t_ns)));
    let backend = backend.map(|b| {
        let t0_s = t0_ns as f64 * 1e-9;
        let same_clock = b
            .first()
            .is_some_and(|s| s.t_s - t0_s >= gt_span.0 - 1.0 && s.t_s - t0_s <= gt_span.1 + 1.0);
        decimate(
            &b.iter()
                .map(|s| (if same_clock { s.t_s - t0_s } else { s.t_s }, s.backend_ms))
                .collect::<Vec<_>>(),
        )
    });
    Figure {
        title,
        est_label: format!("estimate ({} aligned)", report.alignment.name()),
        gt_xy: decimate(&gt.iter().map(|p| (p.p_wb.x, p.p_wb.y)).collect::<Vec<_>>()),
        est_xy: decimate(&est_w.iter().map(|&(_, x, y, _)| (x, y)).collect::<Vec<_>>()),
        gt_z: decimate(
            &gt.iter()
                .map(|p| (rel(p.t_ns), p.p_wb.z))
                .collect::<Vec<_>>(),
        ),
        est_z: decimate(&est_w.iter().map(|&(t, _, _, z)| (t, z)).collect::<Vec<_>>()),
        err: decimate(
            &report
                .matches
                .iter()
                .map(|m| (rel(m.gt.t_ns), m.pos_err_m))
                .collect::<Vec<_>>(),
        ),
        backend,
        ate_rmse_m: report.ate_pos_m.rmse,
    }
}

/// Range of `vals` with a margin; never empty.
pub(crate) fn padded(vals: impl Iterator<Item = f64>, frac: f64, include_zero: bool) -> Range<f64> {
    let (mut lo, mut hi) = vals.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
        (l.min(v), h.max(v))
    });
    if !lo.is_finite() || !hi.is_finite() {
        (lo, hi) = (0.0, 1.0);
    }
    if include_zero {
        lo = lo.min(0.0);
    }
    let span = (hi - lo).max(1e-3);
    let pad = span * frac;
    (if include_zero && lo >= 0.0 {
        0.0
    } else {
        lo - pad
    })..hi + pad
}

/// Grows the shorter range so one metre spans the same pixels on both axes.
pub(crate) fn equal_aspect(
    x: Range<f64>,
    y: Range<f64>,
    w_px: f64,
    h_px: f64,
) -> (Range<f64>, Range<f64>) {
    let (sx, sy) = ((x.end - x.start) / w_px, (y.end - y.start) / h_px);
    if sx > sy {
        let c = 0.5 * (y.start + y.end);
        let half = 0.5 * sx * h_px;
        (x, c - half..c + half)
    } else {
        let c = 0.5 * (x.start + x.end);
        let half = 0.5 * sy * w_px;
        (c - half..c + half, y)
    }
}

pub(crate) type DrawResult = Result<()>;

/// A polyline: legend label, points, colour, stroke width in pixels.
pub(crate) type Series<'a> = (&'a str, &'a [(f64, f64)], RGBColor, u32);

pub(crate) fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("drawing failed: {e}")
}

/// A line chart of several series on one panel.
pub(crate) fn line_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    caption: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[Series],
    x_range: Range<f64>,
    y_range: Range<f64>,
) -> DrawResult {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FONT, 24))
        .margin(12)
        .x_label_area_size(48)
        .y_label_area_size(72)
        .build_cartesian_2d(x_range, y_range)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 18))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(205, 205, 205))
        .draw()
        .map_err(err)?;
    for &(label, pts, color, width) in series {
        chart
            .draw_series(LineSeries::new(
                pts.iter().copied(),
                color.stroke_width(width),
            ))
            .map_err(err)?
            .label(label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(3))
            });
    }
    if !series.is_empty() {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font((FONT, 16))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(160, 160, 160))
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, fig: &Figure) -> DrawResult {
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(&fig.title, (FONT, 28)).map_err(err)?;
    let (top, bottom) = root.split_vertically(root.dim_in_pixel().1 / 2);
    let (top_left, top_right) = top.split_horizontally(top.dim_in_pixel().0 / 2);

    let est_label = fig.est_label.as_str();
    let (w, h) = top_left.dim_in_pixel();
    let (xr, yr) = equal_aspect(
        padded(
            fig.gt_xy.iter().chain(&fig.est_xy).map(|p| p.0),
            0.05,
            false,
        ),
        padded(
            fig.gt_xy.iter().chain(&fig.est_xy).map(|p| p.1),
            0.05,
            false,
        ),
        // Plot area without the label areas, margins and caption.
        f64::from(w.saturating_sub(72 + 24).max(1)),
        f64::from(h.saturating_sub(48 + 24 + 40).max(1)),
    );
    line_panel(
        &top_left,
        "top view",
        "x [m]",
        "y [m]",
        &[
            ("ground truth", &fig.gt_xy, GT_COLOR, 3),
            (est_label, &fig.est_xy, EST_COLOR, 1),
        ],
        xr,
        yr,
    )?;

    let t_range = padded(fig.gt_z.iter().chain(&fig.est_z).map(|p| p.0), 0.0, false);
    line_panel(
        &top_right,
        "height",
        "time [s]",
        "z [m]",
        &[
            ("ground truth", &fig.gt_z, GT_COLOR, 3),
            (est_label, &fig.est_z, EST_COLOR, 1),
        ],
        t_range.clone(),
        padded(fig.gt_z.iter().chain(&fig.est_z).map(|p| p.1), 0.1, false),
    )?;

    let err_caption = format!("position error (ATE rmse {:.3} m)", fig.ate_rmse_m);
    let err_series = [("|p_gt - p_est|", fig.err.as_slice(), ERR_COLOR, 1)];
    let err_y = padded(fig.err.iter().map(|p| p.1), 0.1, true);
    match &fig.backend {
        Some(b) => {
            let (bl, br) = bottom.split_horizontally(bottom.dim_in_pixel().0 / 2);
            line_panel(
                &bl,
                &err_caption,
                "time [s]",
                "error [m]",
                &err_series,
                t_range,
                err_y,
            )?;
            let mean = b.iter().map(|p| p.1).sum::<f64>() / b.len().max(1) as f64;
            line_panel(
                &br,
                &format!("back-end time per keyframe (mean {mean:.2} ms)"),
                "time [s]",
                "back-end [ms]",
                &[("back-end", b, BACKEND_COLOR, 1)],
                padded(b.iter().map(|p| p.0), 0.02, false),
                padded(b.iter().map(|p| p.1), 0.1, true),
            )?;
        }
        None => line_panel(
            &bottom,
            &err_caption,
            "time [s]",
            "error [m]",
            &err_series,
            t_range,
            err_y,
        )?,
    }
    root.present().map_err(err)
}

/// Evaluates `est` against `gt` with `opts` and draws the figure to `out` (`.svg` or `.png`).
/// Returns the evaluation so callers can print it too.
pub fn plot(
    gt: &[StampedPose],
    est: &[StampedPose],
    opts: &EvalOptions,
    backend: Option<&[BackendSample]>,
    title: &str,
    out: &Path,
) -> Result<EvalReport> {
    let report = evaluate(gt, est, opts)?;
    let fig = build(gt, est, &report, backend, title.to_string());
    register_font()?;
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("svg") => draw(SVGBackend::new(out, SIZE_PX).into_drawing_area(), &fig),
        Some("png") => draw(BitMapBackend::new(out, SIZE_PX).into_drawing_area(), &fig),
        _ => bail!("{}: the output must end in .svg or .png", out.display()),
    }
    .with_context(|| format!("writing {}", out.display()))?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimation_bounds_points_and_keeps_both_ends() {
        assert!(decimate::<u32>(&[]).is_empty());
        let short: Vec<u32> = (0..10).collect();
        assert_eq!(decimate(&short), short);
        let long: Vec<u32> = (0..10_001).collect();
        let d = decimate(&long);
        assert!(d.len() <= MAX_POINTS + 1, "{}", d.len());
        assert_eq!((d[0], d[d.len() - 1]), (0, 10_000));
    }

    #[test]
    fn equal_aspect_gives_equal_metres_per_pixel() {
        let (x, y) = equal_aspect(0.0..10.0, 0.0..1.0, 500.0, 250.0);
        assert_eq!(x, 0.0..10.0);
        assert!(((y.end - y.start) / 250.0 - 10.0 / 500.0).abs() < 1e-15);
        assert!((0.5 * (y.start + y.end) - 0.5).abs() < 1e-15);
        let r = padded(std::iter::empty(), 0.1, false);
        assert!(r.end > r.start);
    }
}
