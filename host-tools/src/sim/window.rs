//! Where a simulated sequence starts and how its camera delay changes over time.
//!
//! - [`SimConfig::start_s`](super::SimConfig::start_s): the sequence is simulated from the
//!   carrier's rest as always, then everything before `T0 + start_s` (on the IMU clock) is
//!   dropped: IMU samples, ground truth, LiDAR sweeps (by their start stamp) and camera frames
//!   (by their exposure instant on the IMU clock, `t_cam + td`). Stamps are not shifted, so the
//!   kept data is exactly the tail of the full sequence (the rendered images too: a frame's
//!   image noise is drawn from its index in the full sequence).
//! - [`TdStep`]: the camera-IMU delay becomes `td + step` for the frames exposed from `at_s` on.
//!
//! [`motion_start_s`] is the start that puts a sequence in full motion: the scenario's rest plus
//! its ramp to full path speed.

use super::scenario::{self, Scenario};
use super::T0_NS;
use povins_platform::dataset::{Dataset, FeatureFrame};

/// A step of the true camera-IMU delay during the run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TdStep {
    /// Added to the delay, s.
    pub step_s: f64,
    /// Exposure time (IMU clock, seconds from the first IMU sample) from which the delay is
    /// `td + step_s`, s.
    pub at_s: f64,
}

/// Seconds from the first IMU sample to full motion: the scenario's time at rest (`static_s`)
/// plus its ramp to full path speed (robot, handheld, flight, fast: `static_s` + 2 s; vehicle:
/// `static_s` + 8 s).
pub fn motion_start_s(sc: Scenario, static_s: f64) -> f64 {
    let w = scenario::preset(sc, static_s).trajectory.warp;
    w.t_static + w.t_ramp
}

/// The delay of the frame exposed at `t_rel_ns` (IMU clock, from the first IMU sample), ns.
pub(super) fn frame_td_ns(td_ns: i64, step: Option<&TdStep>, t_rel_ns: i64) -> i64 {
    match step {
        Some(s) if t_rel_ns >= secs_to_ns(s.at_s) => td_ns + secs_to_ns(s.step_s),
        _ => td_ns,
    }
}

/// Seconds to whole nanoseconds (rounded).
pub(super) fn secs_to_ns(s: f64) -> i64 {
    (s * 1e9).round() as i64
}

/// Checks that the camera stamps of `frames` strictly increase (a positive delay step larger
/// than the frame period would send the stamps back in time).
pub(super) fn check_stamps(frames: &[FeatureFrame]) -> anyhow::Result<()> {
    match frames.windows(2).position(|w| w[1].t_ns <= w[0].t_ns) {
        Some(k) => anyhow::bail!(
            "the delay step makes camera frame {} ({} ns) no later than frame {} ({} ns): \
             the step must be smaller than the frame period",
            k + 1,
            frames[k + 1].t_ns,
            k,
            frames[k].t_ns
        ),
        None => Ok(()),
    }
}

/// What [`crop`] kept of the camera frames.
#[derive(Debug, Clone, PartialEq)]
pub struct KeptFrames {
    /// Index in the full sequence of the first kept frame.
    pub first: usize,
    /// Exposure instant of each kept frame on the IMU clock, seconds from the first IMU sample.
    pub t_s: Vec<f64>,
}

/// Drops from `ds` everything before `T0 + start_s`. `frame_t_rel_ns` holds each frame's
/// exposure instant on the IMU clock relative to [`T0_NS`].
pub(super) fn crop(ds: &mut Dataset, frame_t_rel_ns: &[i64], start_s: f64) -> KeptFrames {
    let start_ns = secs_to_ns(start_s);
    let t_start_ns = T0_NS + start_ns;
    ds.imu.retain(|s| s.t_ns >= t_start_ns);
    ds.ground_truth.retain(|s| s.t_ns >= t_start_ns);
    // Sweeps by their start on the IMU clock (`t_imu = t_lidar + td_l`).
    let td_l_ns = secs_to_ns(ds.calib.td_l_s);
    let first_sweep = ds
        .lidar
        .partition_point(|s| s.t_ns.saturating_add(td_l_ns) < t_start_ns);
    ds.lidar.drain(..first_sweep);
    if let Some(truth) = ds.sim_truth.as_mut() {
        let n = first_sweep.min(truth.lidar_edge_points.len());
        truth.lidar_edge_points.drain(..n);
    }
    let first = frame_t_rel_ns.partition_point(|&t| t < start_ns);
    ds.features.drain(..first.min(ds.features.len()));
    if start_ns > 0 {
        // The truth by feature id keeps the ids that are still observed.
        if let Some(truth) = ds.sim_truth.as_mut() {
            let mut seen: Vec<u64> = ds
                .features
                .iter()
                .flat_map(|f| f.obs.iter().map(|o| o.id))
                .collect();
            seen.sort_unstable();
            seen.dedup();
            let kept = |id: &u64| seen.binary_search(id).is_ok();
            truth.landmarks_w.retain(|(id, _)| kept(id));
            truth.wrong_tracks.retain(kept);
            truth.edge_features.retain(kept);
        }
    }
    KeptFrames {
        first,
        t_s: frame_t_rel_ns[first..]
            .iter()
            .map(|&t| t as f64 * 1e-9)
            .collect(),
    }
}
