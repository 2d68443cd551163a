//! LiDAR scan patterns and ray-cast sweeps with per-point times.
//!
//! - Livox-like rosette (Mid-70 / Avia): two Risley prisms rotating at incommensurate rates
//!   deflect the beam by the sum of two rotating vectors, `(az, el) = (a_h, a_v)/2 *
//!   (cos w1 t + cos w2 t, sin w1 t + sin w2 t)`, evaluated at the absolute time `t`, so the
//!   pattern never repeats and covers the field of view more densely over time.
//! - Ouster-like spinning 128-beam LiDAR: columns equally spaced in azimuth over one revolution,
//!   all beams of a column fired at the column time, elevations uniform over the vertical FoV.
//!
//! Each ray is cast from the LiDAR pose at its own time (interpolated on a 1 ms knot grid of
//! exact trajectory poses), so motion distortion is real. The true LiDAR mounting differs from
//! the nominal calibration by the configured extrinsic error. Returns get Gaussian range noise.
//! Edge points: a return near a depth discontinuity, i.e. one of its neighbour rays hits nothing
//! (sky) or another surface at a clearly different range (`> max(0.3 m, 10 %)`). Neighbours are
//! the previous/next ray of the sweep (0.2-0.35 deg away along the scan line) and two probe rays
//! at `edge_angle_rad` on either side across it.
//!
//! Mixed returns (the sensor models, [`LidarParams::footprint`]): a beam is a cone, not a ray.
//! At an edge point the footprint is sampled (its centre and 8 rays on the ellipse of the
//! divergence's half angles, at half the centre's intensity: a Gaussian beam's FWHM); each
//! sample's energy is `intensity x reflectivity x cos(incidence) / range^2`. Samples whose ranges
//! chain within [`Footprint::merge_m`] form one echo at their energy-weighted mean range (two
//! surfaces closer than that give one return *between* them: a mixed return); the strongest echo
//! is reported, along the beam's axis. So a beam grazing a foreground edge reports the
//! background, the foreground, or a point in mid-air between them, as real LiDARs do.

use super::rng::Rng;
use super::trajectory::Trajectory;
use super::world::{Hit, Material, Shape, World};
use povins_core::lidar::LidarPoint;
use povins_core::math::{Quat, Vec3};
use povins_platform::dataset::{Extrinsic, LidarScan};

/// Which scan pattern to simulate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LidarPattern {
    /// Non-repetitive rosette with horizontal and vertical FoV (full angles), rad.
    Rosette {
        /// Horizontal FoV, rad.
        fov_h: f64,
        /// Vertical FoV, rad.
        fov_v: f64,
        /// Points per sweep.
        points: usize,
    },
    /// Spinning multi-beam.
    Spinning {
        /// Number of beams.
        beams: usize,
        /// Columns per revolution.
        columns: usize,
        /// Vertical FoV (full angle, symmetric), rad.
        fov_v: f64,
    },
}

/// LiDAR parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LidarParams {
    /// Scan pattern.
    pub pattern: LidarPattern,
    /// Sweep rate, Hz.
    pub rate_hz: f64,
    /// Range noise (1 sigma), m.
    pub range_noise_m: f64,
    /// Minimum and maximum range, m.
    pub range_m: (f64, f64),
    /// Angular radius of the depth-discontinuity test around each return, rad.
    pub edge_angle_rad: f64,
    /// Probability that a ray passes through a foliage crown (gaps between leaves) instead of
    /// returning from a leaf, in `[0, 1]`; 0 makes foliage an opaque sphere.
    pub foliage_porosity: f64,
    /// The beam's footprint, for mixed returns at edges (`None`: a ray, one surface).
    pub footprint: Option<Footprint>,
}

/// A beam's cone and how its echoes merge (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    /// Full divergence (FWHM) along the sensor's horizontal, rad.
    pub div_h_rad: f64,
    /// Full divergence (FWHM) along the sensor's vertical, rad.
    pub div_v_rad: f64,
    /// Echoes closer than this in range merge into one return, m.
    pub merge_m: f64,
}

/// Rays on the footprint's FWHM ellipse, besides its centre.
const FOOTPRINT_RAYS: usize = 8;

/// Energy of an echo from `hit` along the unit ray `d_w`, per unit emitted intensity.
fn echo_energy(world: &World, hit: &Hit, d_w: &Vec3) -> f64 {
    let cos_inc = (-hit.normal.dot(d_w)).clamp(0.0, 1.0);
    world.material(hit).reflectivity() * cos_inc / (hit.t * hit.t).max(1e-6)
}

/// The range a beam reports when its footprint may span a depth discontinuity: `center` is the
/// axis ray's (range, energy); the rest of the footprint is cast from `o` with the sensor's
/// rotation `q` around `d_l` (LiDAR frame). Echoes beyond `r_max` return nothing.
fn footprint_range(
    world: &World,
    fp: &Footprint,
    (o, q, d_l): (&Vec3, &Quat, &Vec3),
    center: (f64, f64),
    t_cast: f64,
    r_max: f64,
) -> f64 {
    let h = Vec3::z().cross(d_l);
    let h = if h.norm() > 1e-9 {
        h.normalize()
    } else {
        Vec3::y()
    };
    let v = d_l.cross(&h);
    let (th, tv) = (libm::tan(0.5 * fp.div_h_rad), libm::tan(0.5 * fp.div_v_rad));
    let mut echoes = [(f64::INFINITY, 0.0); FOOTPRINT_RAYS + 1];
    echoes[0] = center;
    for (k, e) in echoes.iter_mut().skip(1).enumerate() {
        let a = 2.0 * core::f64::consts::PI * k as f64 / FOOTPRINT_RAYS as f64;
        let d_w = q * (d_l + h * (th * libm::cos(a)) + v * (tv * libm::sin(a))).normalize();
        if let Some(g) = world.raycast(o, &d_w, t_cast).filter(|g| g.t <= r_max) {
            *e = (g.t, 0.5 * echo_energy(world, &g, &d_w));
        }
    }
    echoes.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Chain the echoes into returns; keep the strongest's energy-weighted range.
    let (mut best, mut best_e) = (center.0, -1.0);
    let (mut sum_e, mut sum_et, mut last) = (0.0, 0.0, f64::NEG_INFINITY);
    for &(t, e) in echoes.iter().filter(|e| e.0.is_finite() && e.1 > 0.0) {
        if t - last >= fp.merge_m && sum_e > 0.0 {
            if sum_e > best_e {
                (best, best_e) = (sum_et / sum_e, sum_e);
            }
            (sum_e, sum_et) = (0.0, 0.0);
        }
        sum_e += e;
        sum_et += e * t;
        last = t;
    }
    if sum_e > best_e && sum_e > 0.0 {
        best = sum_et / sum_e;
    }
    best
}

/// Crowns a ray may pass through before the cast gives up (trees are 2-4 overlapping spheres).
const MAX_CROWNS: usize = 8;

/// Largest depth of a leaf return behind the crown's outer surface, m.
const MAX_LEAF_DEPTH_M: f64 = 0.4;

/// Casts a ray through porous foliage: at each crown the ray returns from a leaf with
/// probability `1 - porosity`, at a depth spread through the outer layer of the crown, or
/// passes through to what lies behind (trunk, wall, ground). The camera sees crowns as opaque,
/// so a feature on a crown can get LiDAR points of the background next to it: the paper's
/// "feature on the tree, LiDAR point on the wall" depth outlier.
fn cast_porous(
    world: &World,
    o: &Vec3,
    d: &Vec3,
    t_max: f64,
    porosity: f64,
    rng: &mut Rng,
) -> Option<Hit> {
    let mut start = 0.0;
    for _ in 0..MAX_CROWNS {
        let o_k = o + d * start;
        let mut h = world.raycast(&o_k, d, t_max - start)?;
        h.t += start;
        if porosity <= 0.0 || world.material(&h) != Material::Foliage {
            return Some(h);
        }
        let Some(Shape::Sphere { c, r }) = h
            .prim
            .and_then(|i| world.primitives().get(i as usize))
            .map(|p| p.shape)
        else {
            return Some(h);
        };
        // Far side of the crown along the ray (the entry is at `h.t`).
        let oc = o - c;
        let b = oc.dot(d);
        let t_exit = -b + libm::sqrt((b * b - oc.norm_squared() + r * r).max(0.0));
        if !rng.chance(porosity) {
            let leaf = rng.range(0.0, MAX_LEAF_DEPTH_M.min(0.5 * (t_exit - h.t)).max(0.0));
            h.t += leaf;
            return Some(h);
        }
        start = t_exit.max(h.t) + 1e-4;
        if start >= t_max {
            return None;
        }
    }
    None
}

/// Rosette prism rates, Hz (incommensurate so the pattern does not repeat).
const ROSETTE_F1_HZ: f64 = 76.3;
const ROSETTE_F2_HZ: f64 = -117.1;

impl LidarPattern {
    /// Number of rays per sweep.
    pub fn rays(&self) -> usize {
        match *self {
            LidarPattern::Rosette { points, .. } => points,
            LidarPattern::Spinning { beams, columns, .. } => beams * columns,
        }
    }

    /// Unit direction in the LiDAR frame (x forward, y left, z up) and time offset in the sweep
    /// of ray `i`; `t_abs_s` is the absolute sweep start time (keeps the rosette non-repetitive).
    fn ray(&self, i: usize, sweep_s: f64, t_abs_s: f64) -> (Vec3, f64) {
        match *self {
            LidarPattern::Rosette {
                fov_h,
                fov_v,
                points,
            } => {
                let dt = sweep_s * i as f64 / points.max(1) as f64;
                let t = t_abs_s + dt;
                let (a1, a2) = (
                    2.0 * core::f64::consts::PI * ROSETTE_F1_HZ * t,
                    2.0 * core::f64::consts::PI * ROSETTE_F2_HZ * t,
                );
                let az = 0.25 * fov_h * (libm::cos(a1) + libm::cos(a2));
                let el = 0.25 * fov_v * (libm::sin(a1) + libm::sin(a2));
                let ce = libm::cos(el);
                (
                    Vec3::new(ce * libm::cos(az), ce * libm::sin(az), libm::sin(el)),
                    dt,
                )
            }
            LidarPattern::Spinning {
                beams,
                columns,
                fov_v,
            } => {
                let (c, b) = (i / beams.max(1), i % beams.max(1));
                let dt = sweep_s * c as f64 / columns.max(1) as f64;
                let az = -2.0 * core::f64::consts::PI * c as f64 / columns.max(1) as f64;
                let el = 0.5 * fov_v - fov_v * b as f64 / (beams.max(2) - 1) as f64;
                let ce = libm::cos(el);
                (
                    Vec3::new(ce * libm::cos(az), ce * libm::sin(az), libm::sin(el)),
                    dt,
                )
            }
        }
    }

    /// Unit direction (LiDAR frame) across the scan line at ray `i`: horizontal for a spinning
    /// pattern (its sequence runs down a column), normal to the curve for the rosette.
    fn across(&self, i: usize, d_l: &Vec3, sweep_s: f64, t_abs_s: f64) -> Vec3 {
        let v = match *self {
            LidarPattern::Spinning { .. } => Vec3::z().cross(d_l),
            LidarPattern::Rosette { points, .. } => {
                let prev = self.ray(i.saturating_sub(1), sweep_s, t_abs_s).0;
                let next = self
                    .ray((i + 1).min(points.saturating_sub(1)), sweep_s, t_abs_s)
                    .0;
                d_l.cross(&(next - prev))
            }
        };
        let n = v.norm();
        if n > 1e-12 {
            v / n
        } else {
            d_l.cross(&Vec3::x()).normalize()
        }
    }
}

/// One sweep plus its per-point edge flags.
pub struct SweepOut {
    /// The scan.
    pub scan: LidarScan,
    /// Per point: near a depth discontinuity.
    pub edge: Vec<bool>,
    /// Returns the beam's footprint moved more than 5 cm off its axis ray's surface (mixed, or
    /// the stronger of two surfaces).
    pub footprint_moved: usize,
}

/// A return before edge classification: (range, direction in `l`, time offset ns, intensity,
/// probe rays found a discontinuity).
type Return = (f64, Vec3, i64, f32, bool);

/// `T_wl` at trajectory time `t_s` for the true mounting `t_bl`.
pub fn lidar_pose(traj: &Trajectory, t_bl: &Extrinsic, t_s: f64) -> (Vec3, Quat) {
    let k = traj.eval(t_s);
    (k.p_wb + k.q_wb * t_bl.p_ab, k.q_wb * t_bl.q_ab)
}

/// Simulates the sweep starting at trajectory time `t_start_s` (stamp `t_start_ns`).
pub fn simulate_sweep(
    world: &World,
    traj: &Trajectory,
    t_bl_true: &Extrinsic,
    params: &LidarParams,
    t_start_s: f64,
    t_start_ns: i64,
    rng: &mut Rng,
) -> SweepOut {
    let sweep_s = 1.0 / params.rate_hz;
    let sweep_ns = (1e9 / params.rate_hz).round() as i64;
    let n_knots = ((sweep_s / 1e-3).ceil() as usize).max(1);
    let knot_dt = sweep_s / n_knots as f64;
    let knots: Vec<(Vec3, Quat)> = (0..=n_knots)
        .map(|k| lidar_pose(traj, t_bl_true, t_start_s + k as f64 * knot_dt))
        .collect();
    let n = params.pattern.rays();
    // Per ray: the true hit (cast beyond the maximum range so that ground or walls just past it
    // still count as the same surface for the edge test) and the return, if any.
    let mut hits: Vec<Option<(f64, u32)>> = Vec::with_capacity(n);
    let mut rets: Vec<Option<Return>> = Vec::with_capacity(n);
    // Per ray with a footprint: origin, rotation, and the axis ray's (range, energy).
    let mut beams: Vec<(Vec3, Quat, f64, f64)> = Vec::new();
    let tan_edge = libm::tan(params.edge_angle_rad);
    let t_cast = 2.0 * params.range_m.1;
    for i in 0..n {
        let (d_l, dt) = params.pattern.ray(i, sweep_s, t_start_s);
        let x = (dt / knot_dt).min(n_knots as f64 - 1e-9);
        let k = x as usize;
        let f = x - k as f64;
        let (p0, q0) = knots[k];
        let (p1, q1) = knots[k + 1];
        let o = p0 + (p1 - p0) * f;
        let q = q0.slerp(&q1, f);
        let d_w = q * d_l;
        let hit = cast_porous(world, &o, &d_w, t_cast, params.foliage_porosity, rng);
        hits.push(hit.map(|h| (h.t, h.surface_id())));
        if params.footprint.is_some() {
            let e = hit.map_or(0.0, |h| echo_energy(world, &h, &d_w));
            beams.push((o, q, hit.map_or(f64::INFINITY, |h| h.t), e));
        }
        rets.push(hit.and_then(|h| {
            let r = h.t + params.range_noise_m * rng.normal();
            if h.t > params.range_m.1 || r < params.range_m.0 {
                return None;
            }
            let cos_inc = (-h.normal.dot(&d_w)).clamp(0.0, 1.0);
            let inten = (255.0 * world.material(&h).reflectivity() * (0.3 + 0.7 * cos_inc)) as f32;
            let dt_ns = (dt * 1e9).round() as i64;
            // Probes on both sides across the scan line (the sequence neighbours cover along it).
            let across = q * params.pattern.across(i, &d_l, sweep_s, t_start_s) * tan_edge;
            let probe_edge = [1.0, -1.0].iter().any(|sgn| {
                let d = (d_w + across * *sgn).normalize();
                match world.raycast(&o, &d, t_cast) {
                    None => true,
                    Some(g) => {
                        g.surface_id() != h.surface_id()
                            && (g.t - h.t).abs() > (0.3f64).max(0.1 * h.t)
                    }
                }
            });
            Some((r, d_l, dt_ns.min(sweep_ns - 1), inten, probe_edge))
        }));
    }
    let nb = [-1isize, 1];
    // Ring neighbours (+-1) must stay in the same column of a spinning pattern.
    let column_len = match params.pattern {
        LidarPattern::Spinning { beams, .. } => beams.max(1),
        LidarPattern::Rosette { .. } => usize::MAX,
    };
    let mut points = Vec::with_capacity(n);
    let mut edge = Vec::with_capacity(n);
    let mut footprint_moved = 0;
    for i in 0..n {
        let (Some((mut r, d_l, dt_ns, inten, probe_edge)), Some((_, s))) = (rets[i], hits[i])
        else {
            continue;
        };
        let is_edge = probe_edge
            || nb.iter().any(|&o| {
                let j = i as isize + o;
                if j < 0 || j >= n as isize {
                    return false;
                }
                if column_len != usize::MAX && (j as usize) / column_len != i / column_len {
                    return false;
                }
                match hits[j as usize] {
                    None => true,
                    Some((rj, sj, ..)) => sj != s && (rj - r).abs() > (0.3f64).max(0.1 * r),
                }
            });
        if let (true, Some(fp), Some(&(o, q, t0, e0))) = (is_edge, &params.footprint, beams.get(i))
        {
            let t = footprint_range(
                world,
                fp,
                (&o, &q, &d_l),
                (t0, e0),
                t_cast,
                params.range_m.1,
            );
            if (t - t0).abs() > 0.05 {
                footprint_moved += 1;
            }
            // The same noise sample on the footprint's range.
            r += t - t0;
        }
        let p = d_l * r;
        points.push(LidarPoint {
            t_ns: t_start_ns + dt_ns,
            p_l: [p.x as f32, p.y as f32, p.z as f32],
            intensity: inten,
        });
        edge.push(is_edge);
    }
    SweepOut {
        scan: LidarScan {
            t_ns: t_start_ns,
            points,
        },
        edge,
        footprint_moved,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::world::Primitive;

    /// A crown of radius 1 m centred 10 m ahead (x) at 2 m height, a wall at x = 20 m behind it.
    fn tree_before_wall() -> World {
        let prims = vec![
            Primitive {
                shape: Shape::Sphere {
                    c: Vec3::new(10.0, 0.0, 2.0),
                    r: 1.0,
                },
                material: Material::Foliage,
            },
            Primitive {
                shape: Shape::Box {
                    min: Vec3::new(20.0, -10.0, 0.0),
                    max: Vec3::new(21.0, 10.0, 8.0),
                },
                material: Material::Building,
            },
        ];
        World::new(prims, [-5.0, -15.0, 30.0, 15.0], 5.0)
    }

    const O: Vec3 = Vec3::new(0.0, 0.0, 2.0);

    /// A wall at x = 20 m and a box whose face at `x_box` covers y >= 0 (its edge at y = 0).
    fn edge_before_wall(x_box: f64) -> World {
        let building = |min, max| Primitive {
            shape: Shape::Box { min, max },
            material: Material::Building,
        };
        let prims = vec![
            building(
                Vec3::new(x_box, 0.0, 0.0),
                Vec3::new(x_box + 0.2, 10.0, 8.0),
            ),
            building(Vec3::new(20.0, -10.0, 0.0), Vec3::new(21.0, 10.0, 8.0)),
        ];
        World::new(prims, [-5.0, -15.0, 30.0, 15.0], 5.0)
    }

    /// The range a beam at azimuth `az_deg` (from the x axis towards +y) reports.
    fn beam_range(w: &World, fp: &Footprint, az_deg: f64) -> (f64, f64) {
        let a = az_deg.to_radians();
        let d = Vec3::new(libm::cos(a), libm::sin(a), 0.0);
        let h = w.raycast(&O, &d, 200.0).expect("hit");
        let center = (h.t, echo_energy(w, &h, &d));
        let q = Quat::identity();
        (
            h.t,
            footprint_range(w, fp, (&O, &q, &d), center, 200.0, 120.0),
        )
    }

    #[test]
    fn a_beam_across_an_edge_reports_the_stronger_surface_or_a_mixed_range() {
        let os1 = crate::sim::scenario::lidar_footprint(crate::sim::LidarKind::Os1_128).unwrap();
        // Far apart (10 m): the axis on the wall, most of the cone's near side on the box: the
        // nearer, brighter box is the strongest echo.
        let w = edge_before_wall(10.0);
        let (axis, r) = beam_range(&w, &os1, -0.03);
        assert!(
            (axis - 20.0).abs() < 0.01 && (r - 10.0).abs() < 0.01,
            "{axis} {r}"
        );
        // Wholly on the wall or on the box: the axis's range (to the cone's spread in range).
        for az in [-1.0, 1.0] {
            let (axis, r) = beam_range(&w, &os1, az);
            assert!((axis - r).abs() < 1e-3, "{axis} {r}");
        }
        // Surfaces 0.5 m apart (under the 1 m a return resolves): one echo between them.
        let w = edge_before_wall(19.5);
        let (axis, r) = beam_range(&w, &os1, -0.03);
        assert!((axis - 20.0).abs() < 0.01, "{axis}");
        assert!(r > 19.55 && r < 19.95, "mixed return {r}");
        // A ray (no divergence) would have stayed on the wall: the cone's width matters.
        let thin = Footprint {
            div_h_rad: 1e-6,
            div_v_rad: 1e-6,
            ..os1
        };
        assert!((beam_range(&w, &thin, -0.03).1 - axis).abs() < 1e-6);
    }

    #[test]
    fn opaque_crown_returns_its_surface() {
        let w = tree_before_wall();
        let mut rng = Rng::new(1);
        let h = cast_porous(&w, &O, &Vec3::x(), 100.0, 0.0, &mut rng).expect("hit");
        assert!((h.t - 9.0).abs() < 1e-9, "{}", h.t);
        assert_eq!(w.material(&h), Material::Foliage);
        // Opaque: the same as the plain ray cast, and no random draw.
        assert_eq!(Some(h), w.raycast(&O, &Vec3::x(), 100.0));
        assert_eq!(rng.next_u64(), Rng::new(1).next_u64());
    }

    #[test]
    fn fully_porous_crown_shows_the_wall_behind() {
        let w = tree_before_wall();
        let mut rng = Rng::new(2);
        for d in [Vec3::x(), Vec3::new(1.0, 0.05, 0.03).normalize()] {
            let h = cast_porous(&w, &O, &d, 100.0, 1.0, &mut rng).expect("hit");
            assert_eq!(w.material(&h), Material::Building);
            // The wall face at x = 20 along d.
            assert!((h.t - 20.0 / d.x).abs() < 1e-6, "{}", h.t);
        }
        // Past the crown with nothing behind within range: no return.
        assert!(cast_porous(&w, &O, &Vec3::x(), 15.0, 1.0, &mut rng).is_none());
    }

    #[test]
    fn porosity_is_the_share_of_rays_through_and_leaves_lie_in_the_outer_crown() {
        let w = tree_before_wall();
        let mut rng = Rng::new(3);
        let n = 4000;
        let (mut wall, mut leaf) = (0usize, 0usize);
        for k in 0..n {
            // Rays spread over the central part of the crown (chord > 1 m).
            let a = 0.03 * ((k % 20) as f64 / 19.0 - 0.5);
            let b = 0.03 * ((k / 20 % 20) as f64 / 19.0 - 0.5);
            let d = Vec3::new(1.0, a, b).normalize();
            let entry = w.raycast(&O, &d, 100.0).expect("crown").t;
            let h = cast_porous(&w, &O, &d, 100.0, 0.3, &mut rng).expect("hit");
            match w.material(&h) {
                Material::Foliage => {
                    leaf += 1;
                    assert!(h.t >= entry && h.t <= entry + MAX_LEAF_DEPTH_M, "{}", h.t);
                }
                Material::Building => wall += 1,
                m => panic!("unexpected {m:?}"),
            }
        }
        assert_eq!(wall + leaf, n);
        let share = wall as f64 / n as f64;
        // Binomial(4000, 0.3): sd 0.007.
        assert!((share - 0.3).abs() < 0.03, "{share}");
    }
}
