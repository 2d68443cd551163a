//! LiDAR returns lie on the ray-cast world surfaces when placed with the true (perturbed)
//! mounting at their own time, with the configured range noise.

use povins_core::math::Vec3;
use povins_host_tools::sim::lidar::lidar_pose;
use povins_host_tools::sim::world::Material;
use povins_host_tools::sim::{simulate, LidarKind, Scenario, SimConfig, T0_NS};

struct Stats {
    n: usize,
    range_res_std: f64,
    range_res_mean: f64,
    surf_rms: f64,
    surf_rms_nominal: f64,
    big: usize,
}

fn check(sc: Scenario, kind: LidarKind) -> Stats {
    let mut cfg = SimConfig::new(sc, 5, 4.0);
    cfg.lidar = Some(kind);
    cfg.max_features = Some(20);
    let out = simulate(&cfg, &|_, _, _| {}).expect("simulate");
    let ds = &out.dataset;
    let t_bl = out.t_bl_true.expect("true mounting");
    let t_bl_nom = ds.calib.t_bl.expect("nominal mounting");
    let edges = &ds.sim_truth.as_ref().expect("truth").lidar_edge_points;
    assert_eq!(edges.len(), ds.lidar.len());
    let sweep_ns = 100_000_000;
    let (mut n, mut s1, mut s2, mut d2, mut d2n, mut big) = (0usize, 0.0, 0.0, 0.0, 0.0, 0usize);
    for (scan, e) in ds.lidar.iter().zip(edges) {
        assert_eq!(scan.points.len(), e.len());
        let mut prev_t = scan.t_ns;
        for (i, p) in scan.points.iter().enumerate() {
            assert!(
                p.t_ns >= scan.t_ns && p.t_ns < scan.t_ns + sweep_ns,
                "point time outside its sweep"
            );
            assert!(p.t_ns >= prev_t, "point times not sorted");
            prev_t = p.t_ns;
            if i % 5 != 0 || e[i] {
                continue;
            }
            let t = (p.t_ns - T0_NS) as f64 * 1e-9;
            let p_l = Vec3::new(p.p_l[0] as f64, p.p_l[1] as f64, p.p_l[2] as f64);
            let r = p_l.norm();
            let d_l = p_l / r;
            let (o, q) = lidar_pose(&out.trajectory, &t_bl, t);
            let hit = out
                .world
                .raycast(&o, &(q * d_l), 1e3)
                .expect("a return must come from a surface");
            let res = r - hit.t;
            n += 1;
            s1 += res;
            s2 += res * res;
            big += usize::from(res.abs() > 0.1);
            let dist = out.world.surface_distance(&(o + q * p_l));
            d2 += dist * dist;
            let (on, qn) = lidar_pose(&out.trajectory, &t_bl_nom, t);
            let dn = out.world.surface_distance(&(on + qn * p_l));
            d2n += dn * dn;
        }
    }
    let mean = s1 / n as f64;
    Stats {
        n,
        range_res_std: (s2 / n as f64 - mean * mean).sqrt(),
        range_res_mean: mean,
        surf_rms: (d2 / n as f64).sqrt(),
        surf_rms_nominal: (d2n / n as f64).sqrt(),
        big,
    }
}

#[test]
fn points_lie_on_surfaces_with_the_range_noise() {
    for (sc, kind) in [
        (Scenario::Robot, LidarKind::Livox),
        (Scenario::Vehicle, LidarKind::Ouster),
        (Scenario::Handheld, LidarKind::Livox),
    ] {
        let s = check(sc, kind);
        eprintln!(
            "{sc:?}/{kind:?}: n {} range std {:.4} mean {:.5} surf rms {:.4} nominal {:.4} big {}",
            s.n, s.range_res_std, s.range_res_mean, s.surf_rms, s.surf_rms_nominal, s.big
        );
        assert!(s.n > 5_000, "{sc:?}: too few points {}", s.n);
        // Range residual along the true ray from the exact pose: N(0, 2 cm).
        assert!(
            (s.range_res_std / 0.02 - 1.0).abs() < 0.1,
            "{sc:?}: range noise std {}",
            s.range_res_std
        );
        assert!(
            s.range_res_mean.abs() < 0.002,
            "{sc:?}: range bias {}",
            s.range_res_mean
        );
        assert!(
            s.big * 1000 < s.n,
            "{sc:?}: {} of {} points > 10 cm off",
            s.big,
            s.n
        );
        // Distance to the nearest surface is at most the range error.
        assert!(
            s.surf_rms <= 0.021,
            "{sc:?}: surface distance rms {}",
            s.surf_rms
        );
        // The nominal calibration is off by the configured extrinsic error.
        assert!(
            s.surf_rms_nominal > 2.0 * s.surf_rms,
            "{sc:?}: nominal {} vs true {}",
            s.surf_rms_nominal,
            s.surf_rms
        );
    }
}

/// Points whose opaque ray meets a tree crown, and how many of them return from behind it.
fn crown_rays(porosity: f64) -> (usize, usize, usize) {
    let mut cfg = SimConfig::new(Scenario::Handheld, 7, 3.0);
    cfg.foliage_porosity = porosity;
    cfg.max_features = Some(20);
    let out = simulate(&cfg, &|_, _, _| {}).expect("simulate");
    let t_bl = out.t_bl_true.expect("true mounting");
    let (mut crown, mut behind, mut all) = (0, 0, 0);
    for scan in &out.dataset.lidar {
        for p in scan.points.iter().step_by(3) {
            all += 1;
            let t = (p.t_ns - T0_NS) as f64 * 1e-9;
            let p_l = Vec3::new(p.p_l[0] as f64, p.p_l[1] as f64, p.p_l[2] as f64);
            let r = p_l.norm();
            let (o, q) = lidar_pose(&out.trajectory, &t_bl, t);
            let Some(hit) = out.world.raycast(&o, &(q * (p_l / r)), 1e3) else {
                continue;
            };
            if out.world.material(&hit) == Material::Foliage {
                crown += 1;
                // Leaf returns lie at most 0.4 m inside the crown (plus range noise).
                behind += usize::from(r > hit.t + 0.5);
            }
        }
    }
    (crown, behind, all)
}

#[test]
fn porous_foliage_lets_the_lidar_see_behind_tree_crowns() {
    let (crown0, behind0, all0) = crown_rays(0.0);
    let (crown1, behind1, all1) = crown_rays(1.0);
    eprintln!("opaque: {crown0} crown rays, {behind0} behind; porous: {crown1}, {behind1}");
    assert!(
        crown0 > 200,
        "the scene must show tree crowns to the LiDAR: {crown0}"
    );
    assert_eq!(behind0, 0, "opaque crowns return from their surface");
    // Fully porous: every ray through a crown returns from what lies behind it (or nothing);
    // a ray grazing a crown can meet a trunk or another crown within 0.5 m of its entry.
    assert!(
        crown1 > 200 && behind1 * 1000 >= crown1 * 999,
        "{behind1} of {crown1}"
    );
    assert!(
        all1 <= all0,
        "rays through crowns into the sky give no return"
    );
    let mut cfg = SimConfig::new(Scenario::Handheld, 7, 1.0);
    cfg.foliage_porosity = 1.5;
    let Err(err) = simulate(&cfg, &|_, _, _| {}) else {
        panic!("a porosity of 1.5 was accepted");
    };
    assert!(format!("{err:#}").contains("foliage porosity"), "{err:#}");
}
