//! Tests of the first-steps check (`provisional.rs` includes this file as its `#[cfg(test)]`
//! module; the attribute below repeats that for readers of this file alone).
#[cfg(test)]
extern crate std;
use super::super::pyramid::pyramid_bytes;
use super::super::testutil::{big_stack, render, test_camera as cam, texture};
use super::super::tracker::{FeatureTracker, TrackHints, TrackerConfig};
use super::super::DetectorConfig;
use super::*;
use crate::camera::FeatureObs;
use std::vec::Vec;

const W: usize = 320;
const H: usize = 240;
type Small = FeatureTracker<64, { pyramid_bytes(W, H, 4) }, 4>;

fn view(img: &[u8]) -> ImageView<'_> {
    ImageView::new(img, W, H, W).unwrap()
}

/// A second texture, unrelated to [`texture`] (the far plane).
fn far(x: f64, y: f64) -> f64 {
    texture(1.3 * y + 71.0, 37.0 - 1.1 * x)
}

/// Two textured planes: the near one covers `x < EDGE + near_dx` and moves by `(near_dx,
/// near_dy)`, the far one (behind, seen for `x >= EDGE + near_dx`) moves by `(far_dx, far_dy)`
/// (a translating camera: the near plane moves more).
const EDGE: f64 = 160.0;
fn two_planes(near: (f64, f64), farm: (f64, f64)) -> Vec<u8> {
    let a = render(W, H, near.0, near.1, texture);
    let b = render(W, H, farm.0, farm.1, far);
    let mut img = a;
    for y in 0..H {
        for x in 0..W {
            if x as f64 >= EDGE + near.0 {
                img[y * W + x] = b[y * W + x];
            }
        }
    }
    img
}

fn pc() -> ProvisionalConfig {
    ProvisionalConfig {
        enabled: true,
        ..ProvisionalConfig::default()
    }
}

#[test]
fn rejects_an_occlusion_edge_corner_and_keeps_a_one_plane_corner() {
    let cfg = pc();
    let rc = cfg.as_reference();
    let a = two_planes((0.0, 0.0), (0.0, 0.0));
    // One step of a translating camera: the near plane moves 2 px, the far one 0.5 px.
    let b = two_planes((2.0, 0.6), (0.5, 0.15));
    let mut refs = std::boxed::Box::new(References::<4>::new());
    // On the near plane, far from the edge: the point moved with the near plane.
    for p in [[100.0, 80.0], [60.0, 150.0], [130.0, 40.0]] {
        refs.capture(0, &view(&a), p, &rc);
        let moved = [p[0] + 2.0, p[1] + 0.6];
        assert_eq!(check(&mut refs, 0, &view(&a), p, &cfg, &rc), Verdict::Keep);
        assert_eq!(
            check(&mut refs, 0, &view(&b), moved, &cfg, &rc),
            Verdict::Keep,
            "{p:?}"
        );
    }
    // On the far plane, far from the edge.
    for p in [[230.0, 80.0], [270.0, 170.0]] {
        refs.capture(0, &view(&a), p, &rc);
        let moved = [p[0] + 0.5, p[1] + 0.15];
        assert_eq!(
            check(&mut refs, 0, &view(&b), moved, &cfg, &rc),
            Verdict::Keep,
            "{p:?}"
        );
    }
    // On the edge (the window straddles both planes): wherever the tracker put the point
    // (with either plane, or in between), one affine warp cannot explain the patch.
    for y in [50.0, 90.0, 130.0, 170.0] {
        for x in [EDGE - 2.0, EDGE, EDGE + 1.0] {
            for moved in [[x + 2.0, y + 0.6], [x + 0.5, y + 0.15], [x + 1.2, y + 0.4]] {
                refs.capture(0, &view(&a), [x, y], &rc);
                assert_eq!(
                    check(&mut refs, 0, &view(&b), moved, &cfg, &rc),
                    Verdict::Reject,
                    "corner at ({x}, {y}) tracked to {moved:?}"
                );
            }
        }
    }
}

#[test]
fn invalid_settings_are_refused_only_when_on() {
    assert!(ProvisionalConfig::PLACEHOLDER.validate().is_ok());
    assert!(pc().validate().is_ok());
    for bad in [
        ProvisionalConfig { window: 14, ..pc() },
        ProvisionalConfig { window: 23, ..pc() },
        ProvisionalConfig { frames: 0, ..pc() },
        ProvisionalConfig {
            max_misalignment_px: 0.0,
            ..pc()
        },
        ProvisionalConfig {
            max_shift_px: f32::NAN,
            ..pc()
        },
        ProvisionalConfig {
            relative_to_median: -1.0,
            ..pc()
        },
    ] {
        assert_eq!(bad.validate(), Err(Error::InvalidConfig), "{bad:?}");
    }
}

fn tcfg(on: bool) -> TrackerConfig {
    TrackerConfig {
        max_features: 60,
        detector: DetectorConfig {
            grid_cols: 8,
            grid_rows: 6,
            max_per_cell: 4,
            min_distance_px: 10.0,
            ..DetectorConfig::default()
        },
        provisional: ProvisionalConfig {
            enabled: on,
            ..ProvisionalConfig::default()
        },
        ..TrackerConfig::default()
    }
}

/// Runs 5 frames of the two planes (near 1.5 px per frame, far 0.4 px); returns the tracks of
/// the first frame and the tracks alive after each later frame.
fn run(on: bool) -> (Vec<FeatureObs>, Vec<Vec<FeatureObs>>) {
    let mut t = Small::new(tcfg(on)).unwrap();
    let mut after = Vec::new();
    let mut first = Vec::new();
    for k in 0..5 {
        let kf = k as f64;
        let img = two_planes((1.5 * kf, 0.3 * kf), (0.4 * kf, 0.1 * kf));
        t.track(k * 50_000_000, &view(&img), &TrackHints::NONE, &cam())
            .unwrap();
        if k == 0 {
            first = t.features().to_vec();
        } else {
            after.push(t.features().to_vec());
        }
    }
    (first, after)
}

#[test]
fn tracker_ends_edge_tracks_and_keeps_plane_tracks_and_is_unchanged_when_off() {
    big_stack(|| {
        let (first_off, after_off) = run(false);
        let (first_on, after_on) = run(true);
        // Detection is the same either way.
        assert_eq!(first_off, first_on);
        let edge = |f: &FeatureObs| (f.u_px - EDGE).abs() <= 4.0;
        let plane = |f: &FeatureObs| (f.u_px - EDGE).abs() >= 12.0;
        let n_edge = first_on.iter().filter(|f| edge(f)).count();
        let n_plane = first_on.iter().filter(|f| plane(f)).count();
        assert!(n_edge >= 3, "{n_edge} corners on the edge");
        // How many of the first frame's corners of a kind are still tracked in the last frame.
        let survivors = |first: &[FeatureObs],
                         after: &[Vec<FeatureObs>],
                         kind: &dyn Fn(&FeatureObs) -> bool| {
            let last = after.last().unwrap();
            first
                .iter()
                .filter(|f| kind(f) && last.iter().any(|g| g.id == f.id))
                .count()
        };
        // Off: corners on the edge survive (they are tracked consistently); on: none does.
        let edge_off = survivors(&first_off, &after_off, &edge);
        let edge_on = survivors(&first_on, &after_on, &edge);
        assert!(
            edge_off >= 1,
            "off: {edge_off} of {n_edge} edge tracks survive"
        );
        assert_eq!(edge_on, 0, "on: {edge_on} of {n_edge} edge tracks survive");
        // Plane corners survive either way (a few near the border may leave).
        let plane_on = survivors(&first_on, &after_on, &plane);
        let plane_off = survivors(&first_off, &after_off, &plane);
        assert!(
            plane_on + 2 >= plane_off,
            "{plane_on} vs {plane_off} of {n_plane}"
        );
        assert!(plane_on * 10 >= n_plane * 8, "{plane_on} of {n_plane}");
    });
}

#[test]
fn relative_threshold_still_ends_edge_tracks() {
    big_stack(|| {
        let mut c = tcfg(true);
        c.provisional.relative_to_median = 2.0;
        let mut t = Small::new(c).unwrap();
        let mut first = Vec::new();
        for k in 0..5 {
            let kf = k as f64;
            let img = two_planes((1.5 * kf, 0.3 * kf), (0.4 * kf, 0.1 * kf));
            t.track(k * 50_000_000, &view(&img), &TrackHints::NONE, &cam())
                .unwrap();
            if k == 0 {
                first = t.features().to_vec();
            }
        }
        let edge = |f: &FeatureObs| (f.u_px - EDGE).abs() <= 4.0;
        let alive = |f: &FeatureObs| t.features().iter().any(|g| g.id == f.id);
        let n_edge = first.iter().filter(|f| edge(f)).count();
        let edge_alive = first.iter().filter(|f| edge(f) && alive(f)).count();
        assert!(n_edge >= 3 && edge_alive == 0, "{edge_alive} of {n_edge}");
        let plane = |f: &FeatureObs| (f.u_px - EDGE).abs() >= 12.0;
        let n_plane = first.iter().filter(|f| plane(f)).count();
        let plane_alive = first.iter().filter(|f| plane(f) && alive(f)).count();
        assert!(
            plane_alive * 10 >= n_plane * 8,
            "{plane_alive} of {n_plane}"
        );
    });
}
