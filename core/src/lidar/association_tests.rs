//! Unit tests of `association`, compiled only with `#[cfg(test)]` (the parent declares the module so).

extern crate std;
use super::*;
use crate::lidar::buffer::MAX_LIDAR_POINTS;
use crate::lidar::config::{LidarConfig, LidarExtrinsic};
use crate::lidar::testutil::{
    big_stack, cast, rosette_dir, spiral_cap, sweep_noisy, Motion, Shape,
};
use crate::lidar::LidarPoint;
use crate::math::{quat_exp, Mat3};
use nalgebra::Rotation3;
use std::vec::Vec;

const MS: i64 = 1_000_000;
type Buf = PointBuffer<MAX_LIDAR_POINTS>;
type Grid = SphereGrid<GRID_W, GRID_H>;

/// Body at rest, x forward / z up; LiDAR x forward, a little rotated and offset; camera
/// looking along body x, 0.15 m ahead of the LiDAR and 0.05 m to its right.
struct Rig {
    motion: Motion,
    cfg: LidarConfig,
    p_bc: Vec3,
    q_bc: Quat,
}

impl Rig {
    fn new(motion: Motion) -> Self {
        // Camera axes in the body: x_c = -y_b, y_c = -z_b, z_c = x_b.
        let r_bc = Mat3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
        Rig {
            motion,
            cfg: LidarConfig {
                extrinsic: LidarExtrinsic {
                    q_bl: quat_exp(&Vec3::new(0.01, -0.02, 0.03)),
                    p_bl: Vec3::new(0.05, 0.05, 0.1),
                },
                td_l_s: 0.004,
                ..LidarConfig::default()
            },
            p_bc: Vec3::new(0.2, 0.0, 0.1),
            q_bc: Quat::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r_bc)),
        }
    }

    fn still() -> Self {
        Self::new(Motion::still(Vec3::new(1.0, 2.0, 1.5), Quat::identity()))
    }

    fn camera(&self, t_ns: i64) -> (Vec3, Quat) {
        let (p_wb, q_wb) = self.motion.pose(t_ns);
        (p_wb + q_wb * self.p_bc, q_wb * self.q_bc)
    }

    /// A point `range` m in front of the camera at `t_ns`, along the optical axis, plus
    /// `lateral` in camera axes.
    fn ahead(&self, t_ns: i64, range: f64, lateral: Vec3) -> Vec3 {
        let (p, q) = self.camera(t_ns);
        p + q * (Vec3::z() * range + lateral)
    }

    /// Pushes `rays` (LiDAR clock) against `scene`, builds the grid at `t_kf_ns`.
    fn run(
        &self,
        scene: &[Shape],
        rays: impl IntoIterator<Item = (i64, Vec3)>,
        t_kf_ns: i64,
        buf: &mut Buf,
        grid: &mut Grid,
    ) -> GridStats {
        self.run_noisy(scene, rays, 0.0, t_kf_ns, buf, grid)
    }

    /// [`Rig::run`] with range noise.
    fn run_noisy(
        &self,
        scene: &[Shape],
        rays: impl IntoIterator<Item = (i64, Vec3)>,
        sigma_m: f64,
        t_kf_ns: i64,
        buf: &mut Buf,
        grid: &mut Grid,
    ) -> GridStats {
        let ins = self.motion.window::<256>(0, 1000 * MS, 5 * MS);
        let pts = sweep_noisy(&self.motion, &self.cfg, scene, rays, sigma_m);
        let st = buf.push_scan(&pts, &ins, &self.cfg);
        // Only returns beyond the 500 m gate (grazing planes) are refused.
        assert_eq!((st.rejected_nonfinite, st.rejected_time), (0, 0));
        assert_eq!((st.accepted + st.rejected_range) as usize, pts.len());
        let (p_wc, q_wc) = self.camera(t_kf_ns);
        grid.build(buf, &p_wc, &q_wc, t_kf_ns, &self.cfg.association)
    }

    /// Camera depth (z) of the scene along normalized coordinates `x_n`.
    fn true_depth(&self, scene: &[Shape], t_ns: i64, x_n: &Vec2) -> Option<f64> {
        let (p, q) = self.camera(t_ns);
        let b = Vec3::new(x_n.x, x_n.y, 1.0).normalize();
        cast(scene, &p, &(q * b)).map(|t| t * b.z)
    }
}

/// `n` rays over 0.1..0.5 s, filling the LiDAR's cone of `half_deg` around its x axis.
fn dense_rays(n: usize, half_deg: f64) -> Vec<(i64, Vec3)> {
    spiral_cap(n, &Vec3::x(), half_deg.to_radians())
        .into_iter()
        .enumerate()
        .map(|(i, d)| (100 * MS + (i as i64 * 400 * MS) / n as i64, d))
        .collect()
}

fn grid_cells(n: usize) -> impl Iterator<Item = (f64, f64)> {
    let k = n as i32;
    (-k..=k).flat_map(move |i| (-k..=k).map(move |j| (i as f64, j as f64)))
}

#[test]
fn oblique_wall_depth_is_the_ray_plane_z() {
    big_stack(|| {
        let rig = Rig::still();
        let t_kf = 500 * MS;
        // Wall 6 m ahead, turned 35 deg about the vertical.
        let n_w = quat_exp(&Vec3::new(0.0, 0.0, 35f64.to_radians())) * -Vec3::x();
        let on = rig.ahead(t_kf, 6.0, Vec3::zeros());
        let wall = [Shape::Plane {
            n: n_w,
            d: n_w.dot(&on),
        }];
        let (mut buf, mut grid) = (Buf::new(), Grid::new());
        let st = rig.run(&wall, dense_rays(50_000, 45.0), t_kf, &mut buf, &mut grid);
        assert_eq!((st.points, st.in_view), (50_000, 50_000));
        assert!(st.cells_filled > 20_000, "{st:?}");
        let cfg = AssociationConfig::default();
        let n_c = rig.camera(t_kf).1.inverse_transform_vector(&n_w);
        let mut worst = 0.0f64;
        for (i, j) in grid_cells(6) {
            let x_n = Vec2::new(0.1 * i, 0.07 * j);
            let d = grid.associate(&x_n, &cfg).unwrap();
            let truth = rig.true_depth(&wall, t_kf, &x_n).unwrap();
            worst = worst.max((d.depth_m - truth).abs());
            // The incidence is the ray's against the wall's normal.
            let b = Vec3::new(x_n.x, x_n.y, 1.0).normalize();
            assert!((d.incidence_cos - n_c.dot(&b).abs()).abs() < 1e-3, "{d:?}");
            // Range along the ray = depth |(x_n, 1)|.
            let k = Vec3::new(x_n.x, x_n.y, 1.0).norm();
            assert!((d.range_m - d.depth_m * k).abs() < 1e-9);
            assert!(d.plane_rms_m < 1e-3 && usize::from(d.neighbours) == cfg.neighbours);
        }
        assert!(worst < 0.01, "worst depth error {worst} m");
        // Off-axis the depth is not the range.
        let d = grid.associate(&Vec2::new(0.5, 0.3), &cfg).unwrap();
        assert!(d.range_m - d.depth_m > 0.5, "{d:?}");
    });
}

#[test]
fn pole_in_front_of_a_wall_never_gets_the_wall_depth() {
    big_stack(|| {
        let rig = Rig::still();
        let t_kf = 500 * MS;
        let (p_wc, q_wc) = rig.camera(t_kf);
        let scene = [
            Shape::Plane {
                n: -Vec3::x(),
                d: -(p_wc.x + 7.0),
            },
            Shape::Cylinder {
                c: rig.ahead(t_kf, 3.0, Vec3::zeros()),
                axis: q_wc * Vec3::y(),
                radius: 0.15,
            },
        ];
        let (mut buf, mut grid) = (Buf::new(), Grid::new());
        rig.run(&scene, dense_rays(50_000, 45.0), t_kf, &mut buf, &mut grid);
        let cfg = AssociationConfig::default();
        let edge = 0.15 / libm::sqrt(9.0 - 0.15 * 0.15); // silhouette from the camera
        let (mut wall_ok, mut pole_ok, mut edge_rejected) = (0, 0, 0);
        for k in -80..=80 {
            let x_n = Vec2::new(k as f64 * 0.0025, 0.1);
            let truth = rig.true_depth(&scene, t_kf, &x_n).unwrap();
            let on_pole = truth < 4.0;
            match grid.associate(&x_n, &cfg) {
                Ok(d) => {
                    assert!(
                        (d.depth_m - truth).abs() < 0.03,
                        "x {}: depth {} truth {truth}",
                        x_n.x,
                        d.depth_m
                    );
                    if on_pole {
                        pole_ok += 1;
                    } else {
                        wall_ok += 1;
                    }
                }
                Err(e) => {
                    // Only near the silhouette may a bearing lose its depth.
                    let near_edge = (x_n.x.abs() - edge).abs() < 0.02;
                    assert!(near_edge, "x {} rejected: {e:?}", x_n.x);
                    if near_edge {
                        edge_rejected += 1;
                    }
                }
            }
            // Interior of the pole and open wall: always a depth.
            if x_n.x.abs() < 0.03 || x_n.x.abs() > 0.08 {
                assert!(grid.associate(&x_n, &cfg).is_ok(), "x {}", x_n.x);
            }
        }
        assert!(pole_ok >= 20 && wall_ok >= 100, "{pole_ok} {wall_ok}");
        assert!(edge_rejected >= 4, "{edge_rejected}");
        // Exactly on the silhouette foreground and background mix: the range spread says
        // so, and without that guard the plane fit (or the incidence) still does.
        let no_spread = AssociationConfig {
            max_range_spread: 1e9,
            ..cfg
        };
        for x in [-edge, edge] {
            let x_n = Vec2::new(x, 0.1);
            assert_eq!(grid.associate(&x_n, &cfg), Err(AssocReject::RangeSpread));
            let r = grid.associate(&x_n, &no_spread);
            assert!(
                matches!(r, Err(AssocReject::PlaneFit | AssocReject::Incidence)),
                "{r:?}"
            );
        }
    });
}

#[test]
fn step_edge_depths_are_from_one_side_or_rejected() {
    // A board 0.5 m in front of a wall 6 m away (range ratio 9%: under the spread gate),
    // with its right edge on the optical axis; 2 cm range noise.
    big_stack(|| {
        let rig = Rig::still();
        let t_kf = 500 * MS;
        let (p_wc, q_wc) = rig.camera(t_kf);
        let scene = [
            Shape::Plane {
                n: -Vec3::x(),
                d: -(p_wc.x + 6.0),
            },
            Shape::Rect {
                c: rig.ahead(t_kf, 5.5, Vec3::new(-1.0, 0.0, 0.0)),
                u: q_wc * Vec3::x(),
                v: q_wc * Vec3::y(),
                half_u: 1.0,
                half_v: 1.0,
            },
        ];
        let (mut buf, mut grid) = (Buf::new(), Grid::new());
        rig.run_noisy(
            &scene,
            dense_rays(50_000, 45.0),
            0.02,
            t_kf,
            &mut buf,
            &mut grid,
        );
        let cfg = AssociationConfig::default();
        let (mut ok, mut far_rejected, mut worst) = (0, 0, 0.0f64);
        for i in -40i32..=40 {
            for j in -3..=3 {
                let x_n = Vec2::new(i as f64 * 0.002, j as f64 * 0.05);
                let truth = rig.true_depth(&scene, t_kf, &x_n).unwrap();
                match grid.associate(&x_n, &cfg) {
                    Ok(d) => {
                        ok += 1;
                        worst = worst.max((d.depth_m - truth).abs());
                        assert!(i != 0, "a depth on the edge itself: {d:?}");
                    }
                    Err(_) => far_rejected += usize::from(i.abs() > 10),
                }
            }
        }
        assert!(worst < 0.1, "a depth {worst} m off across the step");
        // Away from the edge (> 1.1 deg) only noise costs a depth now and then.
        assert!(ok > 450 && far_rejected <= 5, "{ok} {far_rejected}");
    });
}

#[test]
fn grazing_plane_is_rejected_for_incidence() {
    big_stack(|| {
        let rig = Rig::still();
        let t_kf = 500 * MS;
        let (p_wc, q_wc) = rig.camera(t_kf);
        // The optical axis meets the plane 5 m ahead at 81 deg from its normal.
        let n_w = q_wc
            * Vec3::new(
                libm::sin(81f64.to_radians()),
                0.0,
                -libm::cos(81f64.to_radians()),
            );
        let on = p_wc + q_wc * Vec3::new(0.0, 0.0, 5.0);
        let plane = [Shape::Plane {
            n: n_w,
            d: n_w.dot(&on),
        }];
        let (mut buf, mut grid) = (Buf::new(), Grid::new());
        rig.run(&plane, dense_rays(50_000, 45.0), t_kf, &mut buf, &mut grid);
        let cfg = AssociationConfig::default();
        let r = grid.associate(&Vec2::new(0.0, 0.0), &cfg);
        assert_eq!(r, Err(AssocReject::Incidence));
        // Steeper than about 85 deg the neighbours' ranges (spread ~ 2 dtheta tan(theta))
        // already fail the range-spread guard; either way no depth.
        for deg in [79.0f64, 84.0, 87.0] {
            let x = libm::tan((deg - 81.0).to_radians());
            let r = grid.associate(&Vec2::new(x, 0.0), &cfg);
            assert!(
                matches!(r, Err(AssocReject::Incidence | AssocReject::RangeSpread)),
                "{deg}: {r:?}"
            );
        }
        // The same plane met at 60 deg (bearing turned 21 deg) is fine.
        let x = libm::tan(21f64.to_radians());
        let ok = grid.associate(&Vec2::new(-x, 0.0), &cfg);
        assert!(ok.is_ok(), "{ok:?}");
    });
}

#[test]
fn no_points_or_outside_the_grid_gives_no_neighbours() {
    big_stack(|| {
        let rig = Rig::still();
        let t_kf = 500 * MS;
        let room = [Shape::RoomBox {
            min: Vec3::new(-10.0, -10.0, -3.0),
            max: Vec3::new(10.0, 10.0, 6.0),
        }];
        let cfg = AssociationConfig::default();
        let (mut buf, mut grid) = (Buf::new(), Grid::new());
        // Before any build.
        assert_eq!(
            grid.associate(&Vec2::new(0.0, 0.0), &cfg),
            Err(AssocReject::NoNeighbours)
        );
        // LiDAR rays only to the left (+y in l): the right of the image is empty sky.
        let left: Vec<(i64, Vec3)> = dense_rays(50_000, 60.0)
            .into_iter()
            .filter(|(_, d)| d.y > 0.2)
            .collect();
        rig.run(&room, left, t_kf, &mut buf, &mut grid);
        assert!(grid.associate(&Vec2::new(-0.5, 0.0), &cfg).is_ok());
        assert_eq!(
            grid.associate(&Vec2::new(0.3, 0.0), &cfg),
            Err(AssocReject::NoNeighbours)
        );
        // All around: points exist at 72 deg, but the grid ends at 64 deg.
        buf.clear();
        let all = spiral_cap(50_000, &Vec3::x(), 3.0)
            .into_iter()
            .enumerate()
            .map(|(i, d)| (100 * MS + i as i64 * 8_000, d));
        rig.run(&room, all, t_kf, &mut buf, &mut grid);
        assert!(grid.associate(&Vec2::new(1.5, 0.0), &cfg).is_ok());
        for x_n in [
            Vec2::new(3.0, 0.0),
            Vec2::new(0.0, 2.0),
            Vec2::new(-1e300, 0.0),
            Vec2::new(1e300, -1e300),
            Vec2::new(0.0, f64::MAX),
        ] {
            assert_eq!(
                grid.associate(&x_n, &cfg),
                Err(AssocReject::NoNeighbours),
                "{x_n:?}"
            );
        }
        for x_n in [Vec2::new(f64::NAN, 0.0), Vec2::new(0.0, f64::INFINITY)] {
            assert_eq!(grid.associate(&x_n, &cfg), Err(AssocReject::NonFinite));
        }
        // A non-finite camera pose leaves the grid empty.
        let st = grid.build(
            &buf,
            &Vec3::new(f64::NAN, 0.0, 0.0),
            &Quat::identity(),
            t_kf,
            &cfg,
        );
        assert_eq!(st, GridStats::default());
        assert_eq!(
            grid.associate(&Vec2::new(0.0, 0.0), &cfg),
            Err(AssocReject::NoNeighbours)
        );
    });
}

#[test]
fn a_cell_keeps_its_nearest_point_and_the_span_selects_times() {
    big_stack(|| {
        let rig = Rig::still();
        let ins = rig.motion.window::<256>(0, 1000 * MS, 5 * MS);
        let dir = [1.0f32, 0.06, 0.04];
        let at = |t_ms: i64, r: f32| LidarPoint {
            t_ns: t_ms * MS,
            p_l: dir.map(|c| c * r),
            intensity: 0.0,
        };
        let cfg = AssociationConfig::default();
        let (p_wc, q_wc) = rig.camera(0);
        let nearest = |grid: &Grid| -> Vec<f32> {
            grid.cells
                .iter()
                .flatten()
                .filter(|c| c.r2 != f32::INFINITY)
                .map(|c| libm::sqrtf(c.r2))
                .collect()
        };
        for order in [[(100, 9.0), (450, 5.0)], [(100, 5.0), (450, 9.0)]] {
            let mut buf = PointBuffer::<64>::new();
            let mut grid = Grid::new();
            let pts = order.map(|(t, r)| at(t, r));
            buf.push_scan(&pts, &ins, &rig.cfg);
            let st = grid.build(&buf, &p_wc, &q_wc, 500 * MS, &cfg);
            assert_eq!((st.points, st.in_view, st.cells_filled), (2, 2, 1));
            // 5 m from the LiDAR, about 4.8 m from the camera 0.2 m ahead of it.
            let r = nearest(&grid);
            assert!(r.len() == 1 && r[0] > 4.7 && r[0] < 4.9, "{r:?}");
            // Span 0.2 s: only the point at 450 ms.
            let short = AssociationConfig { span_s: 0.2, ..cfg };
            let st = grid.build(&buf, &p_wc, &q_wc, 500 * MS, &short);
            assert_eq!(st.points, 1);
            let want = if order[1].1 < 6.0 { 4.8 } else { 8.8 };
            assert!((nearest(&grid)[0] - want).abs() < 0.1);
            // Keyframe at 300 ms: the later point is not used.
            let st = grid.build(&buf, &p_wc, &q_wc, 300 * MS, &cfg);
            assert_eq!(st.points, 1);
        }
    });
}

/// Livox-like rosette: 10k points per 0.1 s sweep, 70.4 deg FoV, five sweeps.
fn rosette_rays() -> Vec<(i64, Vec3)> {
    (0..50_000i64)
        .map(|i| {
            (
                i * 10_000,
                rosette_dir(i as f64 * 1e-5, 35.2f64.to_radians()),
            )
        })
        .collect()
}

type Outcome = (Vec2, Option<f64>, Result<DepthMeasurement, AssocReject>);

/// Moving rig in front of a tilted wall, range noise `sigma_m`; every bearing of a 25 x 19
/// image grid with its true depth and association.
fn rosette_run(sigma_m: f64, cfg: &AssociationConfig) -> (GridStats, Vec<Outcome>) {
    let rig = Rig::new(Motion {
        p0: Vec3::new(1.0, 2.0, 1.5),
        v: Vec3::new(0.8, 0.1, 0.0),
        q0: quat_exp(&Vec3::new(0.02, 0.01, 0.3)),
        yaw_rate: 0.2,
    });
    let t_kf = 500 * MS;
    let n_w = quat_exp(&Vec3::new(0.1, 0.0, 0.5)) * -Vec3::x();
    let on = rig.ahead(t_kf, 6.0, Vec3::zeros());
    let wall = [Shape::Plane {
        n: n_w,
        d: n_w.dot(&on),
    }];
    let (mut buf, mut grid) = (Buf::new(), Grid::new());
    let st = rig.run_noisy(&wall, rosette_rays(), sigma_m, t_kf, &mut buf, &mut grid);
    let out = (-12..=12)
        .flat_map(|i| (-9..=9).map(move |j| Vec2::new(0.05 * i as f64, 0.05 * j as f64)))
        .map(|x_n| {
            let truth = rig.true_depth(&wall, t_kf, &x_n);
            (x_n, truth, grid.associate(&x_n, cfg))
        })
        .collect();
    (st, out)
}

/// Fraction of in-cone bearings with a depth, and the RMS and worst depth errors.
fn rosette_score(out: &[Outcome]) -> (usize, f64, f64, f64) {
    // Bearings inside the LiDAR cone (35.2 deg) with a neighbour radius to spare; the LiDAR
    // looks along the camera z within 2 deg, so the test is done in the camera.
    let cone_cos = libm::cos(33f64.to_radians());
    let (mut inside, mut ok, mut sum2, mut worst) = (0usize, 0usize, 0.0, 0.0f64);
    for (x_n, truth, r) in out {
        if Vec3::new(x_n.x, x_n.y, 1.0).normalize().z < cone_cos {
            continue;
        }
        inside += 1;
        if let (Ok(d), Some(t)) = (r, truth) {
            ok += 1;
            sum2 += (d.depth_m - t) * (d.depth_m - t);
            worst = worst.max((d.depth_m - t).abs());
        }
    }
    let frac = ok as f64 / inside.max(1) as f64;
    (inside, frac, libm::sqrt(sum2 / ok.max(1) as f64), worst)
}

#[test]
fn rosette_density_gives_most_bearings_a_depth() {
    big_stack(|| {
        let (st, out) = rosette_run(0.0, &AssociationConfig::default());
        assert_eq!((st.points, st.in_view), (50_000, 50_000));
        let (inside, frac, _, worst) = rosette_score(&out);
        assert!(inside > 300, "{inside}");
        assert!(frac > 0.9, "{frac} of {inside} bearings got a depth");
        assert!(worst < 0.01, "worst depth error {worst}");
        // With the 2 cm range noise of a Mid-70.
        let (_, out) = rosette_run(0.02, &AssociationConfig::default());
        let (_, frac, rms, worst) = rosette_score(&out);
        assert!(frac > 0.9, "noisy: {frac} got a depth");
        // Measured: 98% with a depth, RMS 1.8 cm, worst 9.9 cm (5 sigma).
        assert!(
            rms < 0.025 && worst < 0.12,
            "noisy: rms {rms} worst {worst}"
        );
        // Five neighbours 5 cm apart with 2 cm noise tilt the plane wildly at times; the
        // range-bracket check keeps the error bounded (0.33 m without it).
        let five = AssociationConfig {
            neighbours: 5,
            ..AssociationConfig::default()
        };
        let (_, out) = rosette_run(0.02, &five);
        let (_, frac, _, worst) = rosette_score(&out);
        assert!(
            frac > 0.8 && worst < 0.15,
            "5 neighbours: {frac} worst {worst}"
        );
    });
}

#[test]
fn same_input_gives_identical_bits() {
    big_stack(|| {
        let (st1, a) = rosette_run(0.02, &AssociationConfig::default());
        let (st2, b) = rosette_run(0.02, &AssociationConfig::default());
        assert_eq!(st1, st2);
        let bits = |r: &Result<DepthMeasurement, AssocReject>| match r {
            Ok(d) => Ok((
                d.depth_m.to_bits(),
                d.range_m.to_bits(),
                d.plane_rms_m.to_bits(),
                d.neighbours,
            )),
            Err(e) => Err(*e),
        };
        assert!(a.iter().zip(&b).all(|(x, y)| bits(&x.2) == bits(&y.2)));
        assert!(a.iter().filter(|x| x.2.is_ok()).count() > 300);
    });
}
