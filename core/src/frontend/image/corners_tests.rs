//! Tests of `corners.rs` (included as its `#[cfg(test)]` module).
extern crate std;
use super::super::testutil::{checkerboard, noise};
use super::*;
use std::vec::Vec;

const W: usize = 200;
const H: usize = 160;

fn detect(
    img: &[u8],
    cfg: &DetectorConfig,
    existing: &[FeatureObs],
    wanted: usize,
) -> (Vec<Corner>, DetectStats) {
    let view = ImageView::new(img, W, H, W).unwrap();
    let mut d = std::boxed::Box::new(GridDetector::new());
    let mut out = [Corner::default(); 64];
    let st = d.detect(&view, cfg, existing, wanted, &mut out).unwrap();
    (out[..st.detected as usize].to_vec(), st)
}

fn cfg() -> DetectorConfig {
    DetectorConfig {
        grid_cols: 4,
        grid_rows: 4,
        max_per_cell: 8,
        min_distance_px: 10.0,
        border_px: 8,
        ..DetectorConfig::default()
    }
}

/// Inner vertices of the 20-px checkerboard at least `border + 2` px inside.
fn vertices() -> Vec<(f64, f64)> {
    let mut v = Vec::new();
    for ky in 1..H / 20 {
        for kx in 1..W / 20 {
            v.push((kx as f64 * 20.0 - 0.5, ky as f64 * 20.0 - 0.5));
        }
    }
    v
}

#[test]
fn finds_checkerboard_vertices() {
    let img = checkerboard(W, H, 20);
    let (corners, st) = detect(&img, &cfg(), &[], 64);
    let verts = vertices();
    // Every corner sits on a vertex (integer pixel next to the true x.5 position).
    for c in &corners {
        let d = verts
            .iter()
            .map(|&(x, y)| libm::hypot(f64::from(c.x) - x, f64::from(c.y) - y))
            .fold(f64::INFINITY, f64::min);
        assert!(
            d <= 0.75,
            "corner {c:?} is {d:.2} px from the nearest vertex"
        );
    }
    // Every vertex is found once.
    for &(x, y) in &verts {
        let n = corners
            .iter()
            .filter(|c| libm::hypot(f64::from(c.x) - x, f64::from(c.y) - y) <= 0.75)
            .count();
        assert_eq!(n, 1, "vertex ({x}, {y}) found {n} times");
    }
    assert_eq!(corners.len(), verts.len());
    assert_eq!(st.cells_scanned, 16);
    assert!(st.best_response > 1000.0, "{}", st.best_response);
}

#[test]
fn respects_existing_tracks_and_scans_only_needy_cells() {
    let img = checkerboard(W, H, 20);
    // Tracks on the vertices of the left half: no new corner within 10 px of them.
    let existing: Vec<FeatureObs> = vertices()
        .iter()
        .filter(|v| v.0 < 100.0)
        .enumerate()
        .map(|(i, &(x, y))| FeatureObs {
            id: i as u64,
            u_px: x,
            v_px: y,
        })
        .collect();
    let (corners, _) = detect(&img, &cfg(), &existing, 64);
    assert!(!corners.is_empty());
    for c in &corners {
        assert!(f64::from(c.x) > 100.0, "{c:?} is next to a track");
    }
    // Cells already holding max_per_cell features are not scanned at all.
    let c = DetectorConfig {
        max_per_cell: 1,
        ..cfg()
    };
    let one_per_cell: Vec<FeatureObs> = (0..16)
        .map(|i| FeatureObs {
            id: i,
            u_px: (i % 4) as f64 * 50.0 + 25.0,
            v_px: (i / 4) as f64 * 40.0 + 20.0,
        })
        .collect();
    let (corners, st) = detect(&img, &c, &one_per_cell, 10);
    assert_eq!((corners.len(), st.cells_scanned, st.pixels), (0, 0, 0));
    // Wanting few corners scans few cells.
    let (corners, st) = detect(&img, &cfg(), &[], 2);
    assert_eq!(corners.len(), 2);
    assert_eq!(st.cells_scanned, 1);
}

#[test]
fn flat_and_noise_images() {
    let flat = std::vec![128u8; W * H];
    let (corners, st) = detect(&flat, &cfg(), &[], 64);
    assert!(corners.is_empty());
    assert_eq!(st.best_response, 0.0);
    // Noise has corners everywhere; the detector still honours the spacing and the cap.
    let n = noise(W, H, 7);
    let (corners, _) = detect(&n, &cfg(), &[], 64);
    assert!(corners.len() >= 32, "{}", corners.len());
    for (i, a) in corners.iter().enumerate() {
        for b in &corners[i + 1..] {
            let d = libm::hypot(
                f64::from(a.x) - f64::from(b.x),
                f64::from(a.y) - f64::from(b.y),
            );
            assert!(d >= 10.0 - 1.5, "{a:?} {b:?} {d}");
        }
    }
    // Invalid settings are refused.
    let bad = DetectorConfig {
        border_px: 2,
        ..cfg()
    };
    let view = ImageView::new(&n, W, H, W).unwrap();
    let mut d = std::boxed::Box::new(GridDetector::new());
    let mut out = [Corner::default(); 4];
    assert_eq!(
        d.detect(&view, &bad, &[], 4, &mut out),
        Err(Error::InvalidConfig)
    );
    let coarse = DetectorConfig {
        grid_cols: 1,
        grid_rows: 1,
        ..cfg()
    };
    let wide = std::vec![0u8; 600 * 10];
    let view = ImageView::new(&wide, 600, 10, 600).unwrap();
    assert_eq!(
        d.detect(&view, &coarse, &[], 4, &mut out),
        Err(Error::InvalidConfig)
    );
}

#[test]
fn occupancy_mask() {
    let mut m = OccupancyMask::new();
    m.reset(752, 480);
    assert_eq!(m.block_px(), 3);
    assert!(m.is_free(100, 100));
    m.mark_disc(100.0, 100.0, 20.0);
    assert!(!m.is_free(100, 100));
    // Blocks of 3 px: distances are measured to block centres (within ~2 px).
    assert!(!m.is_free(113, 113)); // block centre (112, 112), 17 px away
    assert!(m.is_free(118, 118)); // 25 px away
    assert!(m.is_free(100, 124));
    assert!(!m.is_free(752, 0)); // outside
    m.mark_disc(f64::NAN, 1.0, 5.0);
    m.mark_disc(-50.0, -50.0, 5.0);
    m.mark_disc(1e9, 1e9, 1e12);
}

mod sqrt_tests {
    use super::super::score::sqrt_newton;

    #[test]
    fn newton_sqrt_matches_the_correctly_rounded_one() {
        let mut worst = 0.0f64;
        let mut x = 0.0f32;
        while x < 1.0e15 {
            let e = f64::from(sqrt_newton(x));
            let t = libm::sqrt(f64::from(x));
            if t > 0.0 {
                worst = worst.max((e - t).abs() / t);
            }
            x = x * 1.37 + 0.11;
        }
        assert!(worst < 3.0e-7, "{worst}");
        assert!(sqrt_newton(0.0) < 1.0e-19);
        assert_eq!(sqrt_newton(576.0 * 576.0), 576.0);
    }
}
