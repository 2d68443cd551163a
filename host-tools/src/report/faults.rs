//! What `povins run` says when a run went wrong: why no camera data reached the estimator (the
//! true cause, from the stamps read and the counters), and the status line every run ends with.

use super::Summary;
use crate::runner::{Frontend, RunTotals};
use povins_platform::recording::Contents;

/// Nanoseconds per unit of the stamp units a camera stream may be written in by mistake.
const UNITS: [(f64, &str); 3] = [
    (1e3, "microseconds"),
    (1e6, "milliseconds"),
    (1e9, "seconds"),
];

/// How far outside the IMU's span a rescaled camera stamp may fall and still match, ns.
const UNIT_MATCH_MARGIN_NS: f64 = 5e9;

/// What the camera stream is called in the messages.
fn stream(frontend: Frontend) -> &'static str {
    match frontend {
        Frontend::Tracks => "feature tracks (EuRoC features0/data.csv, /cam0/features)",
        Frontend::Images => "camera images (EuRoC cam0/data.csv, /cam0/image_raw)",
    }
}

/// Why a camera stamp `t_ns` that no IMU sample of `imu0..=imu1` reaches was never used: a
/// stamp in another unit (named when rescaling it lands within the IMU's span), else another
/// clock.
fn stamp_cause(t_ns: i64, imu0: i64, imu1: i64) -> String {
    let within =
        |t: f64| t >= imu0 as f64 - UNIT_MATCH_MARGIN_NS && t <= imu1 as f64 + UNIT_MATCH_MARGIN_NS;
    for (ns, unit) in UNITS {
        if within(t_ns as f64 * ns) {
            return format!(
                "camera stamps look like {unit}, not nanoseconds: the first camera stamp \
                 {t_ns} x {ns:e} falls within the IMU's stamps {imu0}..{imu1} ns"
            );
        }
        if within(t_ns as f64 / ns) {
            return format!(
                "the IMU stamps look like {unit}, not nanoseconds: the first camera stamp \
                 {t_ns} / {ns:e} falls within the IMU's stamps {imu0}..{imu1}"
            );
        }
    }
    format!(
        "the camera stamps are outside the IMU's span: first camera stamp {t_ns} ns, IMU \
         stamps {imu0}..{imu1} ns (another clock?)"
    )
}

/// Why no camera data reached the estimator in a run that gave no keyframe, when that is the
/// cause; `None` when camera frames did reach it (the initializers' refusals are then the
/// reason, [`super::never_started_reason`]) or the recording has no camera.
pub fn camera_never_reached(
    has: &Contents,
    frontend: Frontend,
    s: &Summary,
    t: &RunTotals,
    camera: (u32, u32),
) -> Option<String> {
    let has_camera = match frontend {
        Frontend::Tracks => has.frames,
        Frontend::Images => has.images,
    };
    if !has_camera || s.keyframes > 0 {
        return None;
    }
    let c = &t.counters;
    let what = stream(frontend);
    let input = &t.input;
    let first = input.first_camera_read_ns.or(input.camera_pending_ns);
    let Some(first) = first else {
        return Some(format!(
            "the recording's {what} hold no frame (an empty file?)"
        ));
    };
    let offered = t.first_camera_ns.is_some();
    if !offered {
        return Some(match input.imu_span_ns {
            Some((i0, i1)) => stamp_cause(first, i0, i1),
            None => "no IMU sample was replayed".to_string(),
        });
    }
    if c.frames > 0 && c.frames_rejected_time + c.frames_dropped_no_imu >= c.frames {
        let cause = input
            .imu_span_ns
            .map(|(i0, i1)| stamp_cause(first, i0, i1))
            .unwrap_or_default();
        return Some(format!(
            "every camera frame was rejected for its stamp (counters.frames_rejected_time {}, \
             frames_dropped_no_imu {} of {} frames): {cause}",
            c.frames_rejected_time, c.frames_dropped_no_imu, c.frames
        ));
    }
    if frontend == Frontend::Images && t.camera_frames > 0 && t.image_failures >= t.camera_frames {
        let why = t
            .image_errors
            .first()
            .map_or(String::new(), |(_, e)| format!(": {e}"));
        return Some(format!(
            "every image was refused ({} of {}, counters.front_end.images_rejected {}){why}",
            t.image_failures, t.camera_frames, t.vio_counters.images_rejected
        ));
    }
    if frontend == Frontend::Tracks && c.frames > 0 && c.features_received == 0 {
        return Some(format!(
            "the {} camera frames carry no features (counters.features_received 0)",
            c.frames
        ));
    }
    if c.features_received > 0 && c.features_rejected >= c.features_received {
        return Some(format!(
            "every feature was rejected (counters.features_rejected {} of {}: outside the \
             {}x{} image of camera.width x camera.height, or non-finite)",
            c.features_rejected, c.features_received, camera.0, camera.1
        ));
    }
    None
}

/// The line a run ends with: resets, re-initializations, IMU gaps bridged, the IMU samples and
/// camera frames rejected, and the output's coverage.
pub fn status_line(s: &Summary) -> String {
    let n = |k: &str| s.counters[k].as_u64().unwrap_or(0);
    let imu = n("imu_rejected_nonfinite")
        + n("imu_rejected_range")
        + n("imu_rejected_time")
        + n("imu_dropped_queue_full")
        + n("imu_spikes_rejected");
    let frames = n("frames_rejected_time") + n("frames_dropped_no_imu");
    let coverage = s
        .judged_coverage()
        .map_or("coverage n/a".to_string(), |(c, of)| {
            format!("coverage {:.1}% {of}", 100.0 * c)
        });
    format!(
        "status    {} resets ({} turned and moved by the images), {} re-initializations, {} IMU gaps \
         bridged ({} long, {} posed from the images after it), {} clock jumps, {imu} IMU samples \
         rejected, {frames} camera frames rejected, {coverage}",
        n("resets"),
        n("outage_motion_from_images"),
        n("reinitializations"),
        n("imu_gaps_bridged"),
        n("imu_gaps_bridged_long"),
        n("imu_gap_poses_from_images"),
        n("clock_jumps"),
    )
}
