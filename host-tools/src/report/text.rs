//! The lines `povins run` (and `demo`) print.

use super::Summary;
use crate::frontend_stats::summary_lines;
use crate::runner::Frontend;
use std::path::Path;

/// Prints the human-readable result lines.
pub fn print_summary(s: &Summary, out_dir: &Path) {
    println!(
        "dataset   {} ({} mode, {:?} init, {} front end)",
        s.dataset,
        s.mode,
        s.init,
        match s.frontend {
            Frontend::Images => "image",
            Frontend::Tracks => "tracks",
        }
    );
    println!(
        "keyframes {} of {} camera frames",
        s.keyframes, s.camera_frames
    );
    if let Some(by) = &s.started_by {
        println!("started   by the {by} initializer");
    }
    match (s.ate_pos_rmse_m, s.ate_rot_rmse_deg) {
        (Some(p), Some(r)) => println!(
            "ATE       {p:.4} m, {r:.3} deg (posyaw-aligned, {} poses)",
            s.matched_poses.unwrap_or(0)
        ),
        _ => println!("ATE       n/a (no ground truth, or no estimate to compare)"),
    }
    if let Some(n) = &s.velocity_nees {
        println!(
            "NEES      velocity in the body {:.2} (median {:.2}), in the aligned world {:.2} ({:.2}); \
             3 (2.37) when the covariance is consistent; {} states",
            n.body.mean, n.body.median, n.world.mean, n.world.median, n.samples
        );
    }
    let n = |k: &str| s.counters[k].as_u64().unwrap_or(0);
    let coverage = s.coverage.map_or(String::new(), |c| {
        format!(
            "{:.1}% of the ground truth after it has an estimate; ",
            100.0 * c
        )
    });
    let start = s.start_after_camera_s.map_or(String::new(), |t| {
        format!("started {t:.3} s after the first camera frame; ")
    });
    println!(
        "coverage  {start}{coverage}{} full resets, {} re-initializations",
        n("resets"),
        n("reinitializations")
    );
    println!(
        "back end  median {:.3} ms, p99 {:.3} ms, max {:.3} ms per keyframe; {:.3} ms per camera frame",
        s.backend_ms_median, s.backend_ms_p99, s.backend_ms_max, s.backend_ms_per_camera_frame
    );
    let hits = n("solve_budget_hits");
    println!(
        "solve     work median {}, max {} per keyframe ([solve_budget] max_work's unit){}",
        s.solve_work_median,
        s.solve_work_max,
        if hits > 0 {
            format!("; {hits} keyframes ended by the budget")
        } else {
            String::new()
        }
    );
    if let Some(line) = s.window_use.line() {
        println!("{line}");
    }
    println!(
        "imu       white-noise densities x{:.2} (measured by the window), delay td {:.2} ms at the end",
        s.imu_noise_scale_end, s.td_end_ms
    );
    if let Some(e) = &s.extrinsic_end {
        let cm = |v: [f64; 3]| v.map(|x| format!("{:.2}", 100.0 * x)).join(", ");
        let deg = |v: [f64; 3]| v.map(|x| format!("{:.3}", x.to_degrees())).join(", ");
        println!(
            "extrinsic p_bc [{}] cm, sd [{}] cm (body axes); rotation sd [{}] deg (camera axes); \
             q_bc [x y z w] [{:.6}, {:.6}, {:.6}, {:.6}]",
            cm(e.p_bc_m),
            cm(e.p_bc_sd_m),
            deg(e.r_bc_sd_rad),
            e.q_bc_xyzw[0],
            e.q_bc_xyzw[1],
            e.q_bc_xyzw[2],
            e.q_bc_xyzw[3]
        );
    }
    if let Some(fe) = &s.image_frontend {
        for line in summary_lines(fe) {
            println!("{line}");
        }
    }
    if s.image_failures > 0 {
        println!(
            "images    {} could not be used (see the warnings)",
            s.image_failures
        );
    }
    if let (Some(m), Some(p90)) = (s.prediction_px_median, s.prediction_px_p90) {
        println!(
            "predict   {m:.2} px median, {p90:.2} px p90 from INS pose and landmark depths to the \
             tracked feature ({} features)",
            s.predictions
        );
    }
    for line in lidar_lines(s) {
        println!("{line}");
    }
    println!("output    {}", out_dir.display());
}

fn pct(x: Option<f64>) -> String {
    x.map_or("n/a".to_string(), |v| format!("{:.1}%", 100.0 * v))
}

/// The LiDAR lines of [`print_summary`].
pub fn lidar_lines(s: &Summary) -> Vec<String> {
    if s.lidar_scans == 0 {
        return vec!["LiDAR     none in the dataset".to_string()];
    }
    if !s.lidar {
        return vec![format!(
            "LiDAR     off ({} sweeps in the dataset ignored)",
            s.lidar_scans
        )];
    }
    let on = |b: bool| if b { "on" } else { "off" };
    let mut v = vec![
        format!(
            "LiDAR     {} sweeps, {} LDM, rejection {}, depth-only opt {}",
            s.lidar_scans,
            s.ldm.to_uppercase(),
            on(s.depth_outlier_rejection),
            on(s.depth_only_opt)
        ),
        format!(
            "depths    {:.1} associated, {:.1} rejected, {:.1} LDM per keyframe",
            s.depths_associated_per_kf, s.depths_rejected_per_kf, s.ldm_per_kf
        ),
        format!(
            "LiDAR ms  association {:.3}, rejection {:.3} (max {:.3}), depth-only opt {:.3} (max {:.3}) median per keyframe",
            s.association_ms_median,
            s.rejection_ms_median,
            s.rejection_ms_max,
            s.depth_opt_ms_median,
            s.depth_opt_ms_max
        ),
    ];
    let c = |k: &str| {
        s.counters
            .get(k)
            .and_then(serde_json::Value::as_u64)
            .unwrap_or(0)
    };
    v.push(format!(
        "points    {} received: {} stored, {} outside the camera's view (cropped), {} thinned \
         (a direction that took a point within a quarter of the association's span: the \
         LiDAR's rate overflows the buffer), {} rejected (non-finite, range, time); {} evicted younger than \
         the association's span (buffer too small for the LiDAR's rate)",
        c("lidar_points_received"),
        c("lidar_points_accepted"),
        c("lidar_points_outside_view"),
        c("lidar_points_thinned"),
        c("lidar_points_rejected"),
        c("lidar_points_evicted_in_span"),
    ));
    if let Some(a) = &s.assoc {
        v.push(format!(
            "assoc     {} checked vs truth: {} within 3 sigma_dr before rejection, {} after; edge features {} -> {}",
            a.assoc_checked,
            pct(a.assoc_within_3sigma_before),
            pct(a.assoc_within_3sigma_after),
            pct(a.edge_share_before),
            pct(a.edge_share_after)
        ));
    }
    v
}
