//! A figure of an estimate without ground truth (`povins plot` without `--gt`): top view, height
//! and speed over time, and, from a run's `stats.csv`, the estimated camera-IMU delay per
//! keyframe (`td_ms`) or the back-end time. The numbers a person checks for plausibility (path
//! length, speed, height range) are returned too.

use crate::plot::{
    decimate, equal_aspect, err, line_panel, padded, register_font, DrawResult, BACKEND_COLOR,
    ERR_COLOR, EST_COLOR, FONT, SIZE_PX,
};
use anyhow::{anyhow, bail, Context, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use povins_platform::trajectory::StampedPose;
use std::path::Path;

/// Plausibility figures of a trajectory.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TrajectoryFigures {
    /// Duration, s.
    pub duration_s: f64,
    /// Path length, m.
    pub length_m: f64,
    /// Speed over 0.2 s windows: median, 90th percentile, maximum, m/s.
    pub speed_median_mps: f64,
    /// See `speed_median_mps`.
    pub speed_p90_mps: f64,
    /// See `speed_median_mps`.
    pub speed_max_mps: f64,
    /// Height range (max - min z), m.
    pub height_range_m: f64,
    /// Horizontal extent (x and y ranges), m.
    pub extent_xy_m: (f64, f64),
    /// Distance between the first and last position, m.
    pub start_end_m: f64,
}

/// `(t s, speed m/s)` over windows of `win_s` (positions sampled irregularly, duplicates fine).
pub fn speeds(est: &[StampedPose], win_s: f64) -> Vec<(f64, f64)> {
    let Some(t0) = est.first().map(|p| p.t_ns) else {
        return Vec::new();
    };
    let rel = |p: &StampedPose| (p.t_ns - t0) as f64 * 1e-9;
    let mut out = Vec::new();
    let mut a = 0usize;
    for (b, pb) in est.iter().enumerate() {
        while a < b && rel(pb) - rel(&est[a]) > win_s {
            a += 1;
        }
        if a > 0 {
            let pa = &est[a - 1];
            let dt = rel(pb) - rel(pa);
            if dt > 0.5 * win_s {
                out.push((rel(pb), (pb.p_wb - pa.p_wb).norm() / dt));
            }
        }
    }
    out
}

/// The plausibility figures of `est`.
pub fn figures(est: &[StampedPose]) -> TrajectoryFigures {
    let length_m = est.windows(2).map(|w| (w[1].p_wb - w[0].p_wb).norm()).sum();
    let mut v: Vec<f64> = speeds(est, 0.2).into_iter().map(|s| s.1).collect();
    v.sort_by(f64::total_cmp);
    let q = |p: f64| {
        if v.is_empty() {
            0.0
        } else {
            v[((p * v.len() as f64) as usize).min(v.len() - 1)]
        }
    };
    let range = |f: &dyn Fn(&StampedPose) -> f64| {
        let (lo, hi) = est
            .iter()
            .map(f)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
                (l.min(x), h.max(x))
            });
        if hi >= lo {
            hi - lo
        } else {
            0.0
        }
    };
    TrajectoryFigures {
        duration_s: match (est.first(), est.last()) {
            (Some(a), Some(b)) => (b.t_ns - a.t_ns) as f64 * 1e-9,
            _ => 0.0,
        },
        length_m,
        speed_median_mps: q(0.5),
        speed_p90_mps: q(0.9),
        speed_max_mps: v.last().copied().unwrap_or(0.0),
        height_range_m: range(&|p| p.p_wb.z),
        extent_xy_m: (range(&|p| p.p_wb.x), range(&|p| p.p_wb.y)),
        start_end_m: match (est.first(), est.last()) {
            (Some(a), Some(b)) => (b.p_wb - a.p_wb).norm(),
            _ => 0.0,
        },
    }
}

/// `(t_s, value)` of column `name` of a CSV with a `t_s` column (`None` when it has no such
/// column).
pub fn read_column(path: &Path, name: &str) -> Result<Option<Vec<(f64, f64)>>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read stats file {}", path.display()))?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let Some(header) = lines.next() else {
        bail!("{}: empty stats file", path.display());
    };
    let cols: Vec<&str> = header
        .trim_start_matches('#')
        .split(',')
        .map(str::trim)
        .collect();
    let (Some(it), Some(iv)) = (
        cols.iter().position(|c| *c == "t_s"),
        cols.iter().position(|c| *c == name),
    ) else {
        return Ok(None);
    };
    let mut out = Vec::new();
    for l in lines {
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        let get = |k: usize| -> Result<f64> {
            f.get(k)
                .and_then(|s| s.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| anyhow!("{}: bad row {l:?}", path.display()))
        };
        out.push((get(it)?, get(iv)?));
    }
    Ok(Some(out))
}

/// Draws `est` (and the `td_ms` or `backend_ms` column of `stats`) to `out` (`.svg`/`.png`).
pub fn plot_estimate(
    est: &[StampedPose],
    stats: Option<&Path>,
    title: &str,
    out: &Path,
) -> Result<TrajectoryFigures> {
    if est.is_empty() {
        bail!("the estimate is empty");
    }
    let t0 = est[0].t_ns;
    let rel = |t_ns: i64| (t_ns - t0) as f64 * 1e-9;
    let xy = decimate(&est.iter().map(|p| (p.p_wb.x, p.p_wb.y)).collect::<Vec<_>>());
    let z = decimate(
        &est.iter()
            .map(|p| (rel(p.t_ns), p.p_wb.z))
            .collect::<Vec<_>>(),
    );
    let speed = decimate(&speeds(est, 0.2));
    let mut fourth = None;
    if let Some(p) = stats {
        let t0_s = t0 as f64 * 1e-9;
        for (col, label) in [
            ("td_ms", "estimated camera-IMU delay td [ms]"),
            ("backend_ms", "back-end time per keyframe [ms]"),
        ] {
            if let Some(v) = read_column(p, col)? {
                let v: Vec<(f64, f64)> = v.into_iter().map(|(t, x)| (t - t0_s, x)).collect();
                fourth = Some((label, v));
                break;
            }
        }
    }
    let fig = figures(est);
    register_font()?;
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let title = format!(
        "{title}: {:.1} m in {:.0} s, speed median {:.2} m/s (p90 {:.2}), height range {:.2} m",
        fig.length_m, fig.duration_s, fig.speed_median_mps, fig.speed_p90_mps, fig.height_range_m
    );
    let parts = Parts {
        title: &title,
        xy: &xy,
        z: &z,
        speed: &speed,
        fourth: fourth.as_ref().map(|(l, v)| (*l, v.as_slice())),
    };
    match ext.as_deref() {
        Some("svg") => draw(SVGBackend::new(out, SIZE_PX).into_drawing_area(), &parts),
        Some("png") => draw(BitMapBackend::new(out, SIZE_PX).into_drawing_area(), &parts),
        _ => bail!("{}: the output must end in .svg or .png", out.display()),
    }
    .with_context(|| format!("writing {}", out.display()))?;
    Ok(fig)
}

struct Parts<'a> {
    title: &'a str,
    xy: &'a [(f64, f64)],
    z: &'a [(f64, f64)],
    speed: &'a [(f64, f64)],
    fourth: Option<(&'a str, &'a [(f64, f64)])>,
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, p: &Parts) -> DrawResult {
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(p.title, (FONT, 24)).map_err(err)?;
    let (top, bottom) = root.split_vertically(root.dim_in_pixel().1 / 2);
    let (tl, tr) = top.split_horizontally(top.dim_in_pixel().0 / 2);
    let (bl, br) = bottom.split_horizontally(bottom.dim_in_pixel().0 / 2);
    let (w, h) = tl.dim_in_pixel();
    let (xr, yr) = equal_aspect(
        padded(p.xy.iter().map(|q| q.0), 0.05, false),
        padded(p.xy.iter().map(|q| q.1), 0.05, false),
        f64::from(w.saturating_sub(72 + 24).max(1)),
        f64::from(h.saturating_sub(48 + 24 + 40).max(1)),
    );
    let start = p.xy.first().copied().unwrap_or((0.0, 0.0));
    let end = p.xy.last().copied().unwrap_or((0.0, 0.0));
    let start_pt = [start];
    let end_pt = [end];
    line_panel(
        &tl,
        "top view (world x-y; o start, x end)",
        "x [m]",
        "y [m]",
        &[("estimate", p.xy, EST_COLOR, 2)],
        xr.clone(),
        yr.clone(),
    )?;
    // Start and end markers on the same coordinates.
    {
        let mut chart = ChartBuilder::on(&tl)
            .caption(" ", (FONT, 24))
            .margin(12)
            .x_label_area_size(48)
            .y_label_area_size(72)
            .build_cartesian_2d(xr, yr)
            .map_err(err)?;
        chart
            .draw_series(
                start_pt
                    .iter()
                    .map(|&q| Circle::new(q, 7, BLACK.stroke_width(2))),
            )
            .map_err(err)?;
        chart
            .draw_series(
                end_pt
                    .iter()
                    .map(|&q| Cross::new(q, 7, BLACK.stroke_width(2))),
            )
            .map_err(err)?;
    }
    let t_range = padded(p.z.iter().map(|q| q.0), 0.0, false);
    line_panel(
        &tr,
        "height",
        "time [s]",
        "z [m]",
        &[("estimate", p.z, EST_COLOR, 1)],
        t_range.clone(),
        padded(p.z.iter().map(|q| q.1), 0.1, false),
    )?;
    line_panel(
        &bl,
        "speed (0.2 s windows)",
        "time [s]",
        "speed [m/s]",
        &[("estimate", p.speed, ERR_COLOR, 1)],
        t_range.clone(),
        padded(p.speed.iter().map(|q| q.1), 0.1, true),
    )?;
    if let Some((label, v)) = p.fourth {
        line_panel(
            &br,
            label,
            "time [s]",
            label.rsplit(' ').next().unwrap_or(""),
            &[("per keyframe", v, BACKEND_COLOR, 2)],
            t_range,
            padded(v.iter().map(|q| q.1), 0.1, true),
        )?;
    }
    root.present().map_err(err)
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::math::{Quat, Vec3};

    #[test]
    fn figures_of_a_walk() {
        // 1 m/s along x for 10 s at 100 Hz, with duplicated stamps 1 us apart.
        let mut est = Vec::new();
        for k in 0..=1000i64 {
            let p = Vec3::new(0.01 * k as f64, 0.0, 0.2 * (k as f64 * 0.01).sin());
            est.push(StampedPose {
                t_ns: k * 10_000_000,
                p_wb: p,
                q_wb: Quat::identity(),
            });
            if k % 7 == 0 {
                est.push(StampedPose {
                    t_ns: k * 10_000_000 + 1000,
                    p_wb: p,
                    q_wb: Quat::identity(),
                });
            }
        }
        let f = figures(&est);
        assert!((f.duration_s - 10.0).abs() < 1e-3);
        assert!((f.speed_median_mps - 1.0).abs() < 0.05, "{f:?}");
        assert!(f.speed_max_mps < 1.1, "{f:?}");
        assert!((f.height_range_m - 0.4).abs() < 0.01, "{f:?}");
        assert!((f.extent_xy_m.0 - 10.0).abs() < 1e-9);
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("e.svg");
        plot_estimate(&est, None, "walk", &out).unwrap();
        assert!(std::fs::metadata(&out).unwrap().len() > 1000);
    }
}
