//! `povins plot` output on real ground truth: the PNG decodes to the promised size with the
//! series' colours on it, the SVG names every panel and series.

use povins_core::math::Vec3;
use povins_host_tools::eval::{Alignment, EvalOptions};
use povins_host_tools::plot::{plot, read_stats_csv, BackendSample, SIZE_PX};
use povins_platform::trajectory::{read_trajectory, StampedPose};
use std::path::{Path, PathBuf};

/// The repository's copy (`tests/data`) when there is one, else `../shared/data` (tests on it
/// are `#[ignore]`d); fails when missing.
fn shared(rel: &str) -> PathBuf {
    let repo = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data")).join(rel);
    if repo.exists() {
        return repo;
    }
    let p = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data")).join(rel);
    assert!(
        p.exists(),
        "shared data not found at {} (clone the repo next to shared/)",
        p.display()
    );
    p
}

fn euroc_gt() -> Vec<StampedPose> {
    read_trajectory(&shared(
        "euroc-v101-30s-features/mav0/state_groundtruth_estimate0/data.csv",
    ))
    .unwrap()
}

/// The ground truth with a slow sinusoidal position error (up to 10 cm).
fn drifting_copy(gt: &[StampedPose]) -> Vec<StampedPose> {
    gt.iter()
        .enumerate()
        .map(|(k, p)| {
            let a = k as f64 * 0.02;
            StampedPose {
                p_wb: p.p_wb + Vec3::new(0.1 * a.sin(), 0.05 * a.cos(), 0.03 * (2.0 * a).sin()),
                ..*p
            }
        })
        .collect()
}

fn stats(gt: &[StampedPose]) -> Vec<BackendSample> {
    gt.iter()
        .step_by(4)
        .enumerate()
        .map(|(k, p)| BackendSample {
            t_s: p.t_ns as f64 * 1e-9,
            backend_ms: 5.0 + (k % 7) as f64,
        })
        .collect()
}

fn count_rgb(rgb: &[u8], c: (u8, u8, u8)) -> usize {
    rgb.chunks_exact(3)
        .filter(|p| (p[0], p[1], p[2]) == c)
        .count()
}

#[test]
fn png_decodes_with_expected_size_and_series_colours() {
    let gt = euroc_gt();
    let est = drifting_copy(&gt);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fig.png");
    let report = plot(
        &gt,
        &est,
        &EvalOptions::default(),
        Some(&stats(&gt)),
        "test",
        &out,
    )
    .unwrap();
    assert_eq!(report.matched_poses, gt.len());

    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&out).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), SIZE_PX);
    assert_eq!(info.color_type, png::ColorType::Rgb);
    let rgb = &buf[..info.buffer_size()];
    let total = (info.width * info.height) as usize;
    let white = count_rgb(rgb, (255, 255, 255));
    // Mostly white background, but clearly drawn on: grid, text and four panels of lines.
    assert!(
        white < total * 97 / 100 && white > total / 2,
        "white {white} of {total}"
    );
    // Each series' colour is on the canvas (ground truth, estimate, error, back-end).
    for (name, c, min) in [
        ("ground truth", (40, 40, 40), 2000),
        ("estimate", (214, 39, 40), 1000),
        ("error", (31, 119, 180), 500),
        ("back-end", (44, 160, 44), 300),
    ] {
        let n = count_rgb(rgb, c);
        assert!(n >= min, "{name}: only {n} pixels of {c:?}");
    }
}

#[test]
fn svg_names_panels_and_series() {
    let gt = euroc_gt();
    let est = drifting_copy(&gt);
    let dir = tempfile::tempdir().unwrap();
    let with = dir.path().join("with.svg");
    let without = dir.path().join("without.svg");
    let opts = EvalOptions {
        alignment: Alignment::Se3,
        ..EvalOptions::default()
    };
    plot(&gt, &est, &opts, Some(&stats(&gt)), "my title", &with).unwrap();
    plot(&gt, &est, &opts, None, "my title", &without).unwrap();
    let with = std::fs::read_to_string(with).unwrap();
    let without = std::fs::read_to_string(without).unwrap();
    for s in [&with, &without] {
        assert!(s.starts_with("<svg width=\"1600\" height=\"1100\""));
        for text in [
            "my title",
            "top view",
            "height",
            "position error (ATE rmse",
            "ground truth",
            "estimate (se3 aligned)",
            "x [m]",
            "z [m]",
            "time [s]",
            // Series strokes: ground truth, estimate, error.
            "stroke=\"#282828\"",
            "stroke=\"#D62728\"",
            "stroke=\"#1F77B4\"",
        ] {
            assert!(s.contains(text), "SVG lacks {text:?}");
        }
    }
    let b = stats(&gt);
    let mean = b.iter().map(|s| s.backend_ms).sum::<f64>() / b.len() as f64;
    let caption = format!("back-end time per keyframe (mean {mean:.2} ms)");
    assert!(with.contains(&caption), "SVG lacks {caption:?}");
    assert!(with.contains("stroke=\"#2CA02C\""));
    assert!(!without.contains("back-end"));
    // 5 data polylines + 5 legend lines without stats; one more of each with.
    let n = |s: &str| s.matches("<polyline").count();
    assert!(
        n(&without) >= 5 && n(&with) > n(&without),
        "{} {}",
        n(&without),
        n(&with)
    );
}

#[test]
fn stats_csv_and_output_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("stats.csv");
    std::fs::write(
        &p,
        "# frame,t_s,extra,backend_ms\n0,1.5,x,12.25\n1,1.6,y,13\n",
    )
    .unwrap();
    let rows = read_stats_csv(&p).unwrap();
    assert_eq!(
        rows,
        vec![
            BackendSample {
                t_s: 1.5,
                backend_ms: 12.25
            },
            BackendSample {
                t_s: 1.6,
                backend_ms: 13.0
            }
        ]
    );
    std::fs::write(&p, "t_s,frontend_ms\n1,2\n").unwrap();
    let e = read_stats_csv(&p).unwrap_err().to_string();
    assert!(e.contains("stats.csv:1") && e.contains("backend_ms"), "{e}");
    std::fs::write(&p, "t_s,backend_ms\n1,2\n2,fast\n").unwrap();
    let e = read_stats_csv(&p).unwrap_err().to_string();
    assert!(e.contains("stats.csv:3") && e.contains("\"fast\""), "{e}");

    let gt = euroc_gt();
    let e = plot(
        &gt,
        &gt,
        &EvalOptions::default(),
        None,
        "t",
        &dir.path().join("x.jpg"),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains(".svg or .png"), "{e}");
}
