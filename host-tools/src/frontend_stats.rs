//! Per-frame statistics of the image front end (`frontend.csv` of `povins run`, `frames.csv` of
//! `povins track`) and their summary.

use crate::runner::{percentile, FrameLog};
use anyhow::{Context, Result};
use povins_core::frontend::image::RansacRun;
use std::io::Write;
use std::path::Path;

/// Header of the per-frame CSV.
pub const FRAMES_HEADER: &str = "t_s,frontend_ms,decode_ms,previous,tracked,seeded_prediction,seeded_rotation,seeded_previous,lost_small_eigen,lost_out_of_image,lost_residual,lost_nonfinite,lost_forward_backward,lost_ransac,lost_reference,lost_provisional,refined,reanchored,reference_median_shift_px,ransac,ransac_inliers,detected,total,lk_iterations,frame_error";

fn ransac_name(r: RansacRun) -> &'static str {
    match r {
        RansacRun::None => "none",
        RansacRun::TwoPoint => "two-point",
        RansacRun::EightPoint => "eight-point",
        RansacRun::SkippedLowFlow => "skipped-low-flow",
    }
}

/// Writes one row per frame.
pub fn write_frames_csv(path: &Path, frames: &[FrameLog]) -> Result<()> {
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?,
    );
    writeln!(f, "{FRAMES_HEADER}")?;
    for fr in frames {
        write_frame_row(&mut f, fr)?;
    }
    f.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

/// One row of the per-frame CSV (columns in [`FRAMES_HEADER`]).
pub fn write_frame_row(f: &mut impl Write, fr: &FrameLog) -> std::io::Result<()> {
    let s = fr.stats();
    writeln!(
        f,
        "{},{:.4},{:.3},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.4},{},{},{},{},{},{}",
        povins_platform::trajectory::ns_to_seconds_string(fr.t_ns),
        fr.frontend_ms(),
        fr.decode_ms,
        s.previous,
        s.tracked,
        s.seeded_prediction,
        s.seeded_rotation,
        s.seeded_previous,
        s.lost_small_eigen,
        s.lost_out_of_image,
        s.lost_residual,
        s.lost_nonfinite,
        s.lost_forward_backward,
        s.lost_ransac,
        s.lost_reference,
        s.lost_provisional,
        s.refined,
        s.reanchored,
        s.reference_median_shift_px,
        ransac_name(s.ransac_run),
        s.ransac.inliers,
        s.detected,
        s.total,
        s.lk_iterations,
        fr.report
            .frame_error
            .map_or(String::new(), |e| format!("{e:?}")),
    )
}

/// Front-end figures of a run.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct FrontendSummary {
    /// Images tracked.
    pub frames: usize,
    /// Front-end time per image (predictions, gyro, pyramid, LK, RANSAC, detection), median, ms.
    pub frontend_ms_median: f64,
    /// Mean, ms.
    pub frontend_ms_mean: f64,
    /// 90th percentile, ms.
    pub frontend_ms_p90: f64,
    /// Maximum, ms.
    pub frontend_ms_max: f64,
    /// Mean tracks per image after top-up.
    pub tracks_per_frame: f64,
    /// Mean features tracked from the previous image (after every check).
    pub tracked_per_frame: f64,
    /// Share of the previous image's features tracked.
    pub tracked_share: f64,
    /// Mean new features per image.
    pub detected_per_frame: f64,
    /// Mean features seeded by an INS prediction per image.
    pub seeded_prediction_per_frame: f64,
    /// Mean features seeded by the gyro rotation per image.
    pub seeded_rotation_per_frame: f64,
    /// Lost per image, by reason: LK (texture, border, residual, non-finite), forward-backward,
    /// RANSAC.
    pub lost_lk_per_frame: f64,
    /// See `lost_lk_per_frame`.
    pub lost_fb_per_frame: f64,
    /// See `lost_lk_per_frame`.
    pub lost_ransac_per_frame: f64,
    /// Lost per image: the anchored refinement disagreed with the frame-to-frame position.
    pub lost_reference_per_frame: f64,
    /// Lost per image: the first-steps check.
    pub lost_provisional_per_frame: f64,
    /// Tracks refined against their reference per image.
    pub refined_per_frame: f64,
    /// References re-anchored per image.
    pub reanchored_per_frame: f64,
    /// Median over the images of their median refinement shift, px.
    pub reference_median_shift_px: f64,
    /// Reading and decoding an image (helper thread), mean, ms.
    pub decode_ms_mean: f64,
}

/// Summarizes the frames (`None` without frames).
pub fn summarize_frames(frames: &[FrameLog]) -> Option<FrontendSummary> {
    let mut d = FrameDigest::default();
    for f in frames {
        d.push(f);
    }
    d.summary()
}

/// What [`FrontendSummary`] needs of the frames, accumulated one frame at a time: two `f64`s
/// per frame (for the medians) and running sums, in the frames' order.
#[derive(Debug, Clone, Default)]
pub struct FrameDigest {
    frontend_ms: Vec<f64>,
    reference_shift_px: Vec<f64>,
    /// Sums in frame order of: total, tracked, detected, seeded by prediction, seeded by
    /// rotation, lost LK, forward-backward, RANSAC, reference, provisional, refined,
    /// re-anchored, decode ms, previous (each term is +0.0 or more, so these equal
    /// `Iterator::sum`, which starts from -0.0, bit for bit).
    sums: [f64; 14],
}

impl FrameDigest {
    /// Adds a frame.
    pub fn push(&mut self, f: &FrameLog) {
        let s = f.stats();
        self.frontend_ms.push(f.frontend_ms());
        self.reference_shift_px
            .push(f64::from(s.reference_median_shift_px));
        let lost_lk = s.lost_small_eigen + s.lost_out_of_image + s.lost_residual + s.lost_nonfinite;
        let v = [
            f64::from(s.total),
            f64::from(s.tracked),
            f64::from(s.detected),
            f64::from(s.seeded_prediction),
            f64::from(s.seeded_rotation),
            f64::from(lost_lk),
            f64::from(s.lost_forward_backward),
            f64::from(s.lost_ransac),
            f64::from(s.lost_reference),
            f64::from(s.lost_provisional),
            f64::from(s.refined),
            f64::from(s.reanchored),
            f.decode_ms,
            f64::from(s.previous),
        ];
        for (a, x) in self.sums.iter_mut().zip(v) {
            *a += x;
        }
    }

    /// The summary (`None` without frames).
    pub fn summary(&self) -> Option<FrontendSummary> {
        if self.frontend_ms.is_empty() {
            return None;
        }
        let n = self.frontend_ms.len() as f64;
        let [total, tracked, detected, seeded_prediction, seeded_rotation, lost_lk, lost_fb, lost_ransac, lost_reference, lost_provisional, refined, reanchored, decode_ms, prev] =
            self.sums;
        let mut ms = self.frontend_ms.clone();
        ms.sort_by(f64::total_cmp);
        let mut shift = self.reference_shift_px.clone();
        shift.sort_by(f64::total_cmp);
        Some(FrontendSummary {
            frames: self.frontend_ms.len(),
            frontend_ms_median: percentile(&ms, 50.0),
            frontend_ms_mean: ms.iter().sum::<f64>() / n,
            frontend_ms_p90: percentile(&ms, 90.0),
            frontend_ms_max: ms.last().copied().unwrap_or(0.0),
            tracks_per_frame: total / n,
            tracked_per_frame: tracked / n,
            tracked_share: if prev > 0.0 { tracked / prev } else { 0.0 },
            detected_per_frame: detected / n,
            seeded_prediction_per_frame: seeded_prediction / n,
            seeded_rotation_per_frame: seeded_rotation / n,
            lost_lk_per_frame: lost_lk / n,
            lost_fb_per_frame: lost_fb / n,
            lost_ransac_per_frame: lost_ransac / n,
            lost_reference_per_frame: lost_reference / n,
            lost_provisional_per_frame: lost_provisional / n,
            refined_per_frame: refined / n,
            reanchored_per_frame: reanchored / n,
            reference_median_shift_px: percentile(&shift, 50.0),
            decode_ms_mean: decode_ms / n,
        })
    }
}

/// The human-readable lines of a summary.
pub fn summary_lines(s: &FrontendSummary) -> Vec<String> {
    vec![
        format!(
            "front end {} images: {:.3} ms median, {:.3} mean, {:.3} p90, {:.3} max per image (one thread)",
            s.frames, s.frontend_ms_median, s.frontend_ms_mean, s.frontend_ms_p90, s.frontend_ms_max
        ),
        format!(
            "tracks    {:.1} per image ({:.1} tracked from the previous, {:.1}%; {:.1} new); seeds: {:.1} INS, {:.1} gyro",
            s.tracks_per_frame,
            s.tracked_per_frame,
            100.0 * s.tracked_share,
            s.detected_per_frame,
            s.seeded_prediction_per_frame,
            s.seeded_rotation_per_frame
        ),
        format!(
            "lost      {:.1} LK, {:.1} forward-backward, {:.1} RANSAC, {:.1} reference, {:.1} first-steps per image; decoding {:.2} ms per image (helper thread)",
            s.lost_lk_per_frame,
            s.lost_fb_per_frame,
            s.lost_ransac_per_frame,
            s.lost_reference_per_frame,
            s.lost_provisional_per_frame,
            s.decode_ms_mean
        ),
        format!(
            "refined   {:.1} per image against their reference, {:.1} re-anchored; median shift from frame-to-frame {:.3} px",
            s.refined_per_frame, s.reanchored_per_frame, s.reference_median_shift_px
        ),
    ]
}
