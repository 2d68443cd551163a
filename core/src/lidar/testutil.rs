//! Synthetic scenes for the LiDAR tests: exact rigid motion, ray casting against planes, boxes
//! and cylinders, and sweeps generated through the sensor model the buffer inverts.

extern crate std;

use super::config::{LidarConfig, LidarExtrinsic};
use super::LidarPoint;
use crate::inertial::window::InsWindow;
use crate::inertial::NavState;
use crate::math::{quat_exp, Quat, Vec3};
use std::vec::Vec;

/// Body motion with constant velocity and constant angular velocity about world z:
/// `p(t) = p0 + v t`, `q(t) = Exp(yaw_rate t z) q0`. Sampled states interpolate exactly
/// (linear position, slerp about a fixed axis).
#[derive(Clone, Copy)]
pub(crate) struct Motion {
    pub(crate) p0: Vec3,
    pub(crate) v: Vec3,
    pub(crate) q0: Quat,
    pub(crate) yaw_rate: f64,
}

impl Motion {
    pub(crate) fn still(p0: Vec3, q0: Quat) -> Self {
        Motion {
            p0,
            v: Vec3::zeros(),
            q0,
            yaw_rate: 0.0,
        }
    }

    pub(crate) fn pose(&self, t_ns: i64) -> (Vec3, Quat) {
        let t = t_ns as f64 * 1e-9;
        (
            self.p0 + self.v * t,
            quat_exp(&Vec3::new(0.0, 0.0, self.yaw_rate * t)) * self.q0,
        )
    }

    /// INS window with states every `dt_ns` over `[t0_ns, t1_ns]`.
    pub(crate) fn window<const K: usize>(
        &self,
        t0_ns: i64,
        t1_ns: i64,
        dt_ns: i64,
    ) -> InsWindow<K> {
        let mut w = InsWindow::new();
        let mut t = t0_ns;
        while t <= t1_ns {
            let (p, q) = self.pose(t);
            w.push(NavState {
                p_wb: p,
                q_wb: q,
                v_wb: self.v,
                ..NavState::identity(t)
            })
            .unwrap();
            t += dt_ns;
        }
        w
    }
}

/// A surface to cast rays at.
#[derive(Clone, Copy)]
pub(crate) enum Shape {
    /// `n . p = d` (unit `n`).
    Plane { n: Vec3, d: f64 },
    /// The inside of an axis-aligned box (rays from inside hit its walls).
    RoomBox { min: Vec3, max: Vec3 },
    /// Infinite cylinder around the line `c + s axis` (unit `axis`).
    Cylinder { c: Vec3, axis: Vec3, radius: f64 },
    /// Rectangle `c + a u + b v`, `|a| <= half_u`, `|b| <= half_v` (unit, orthogonal `u`, `v`).
    Rect {
        c: Vec3,
        u: Vec3,
        v: Vec3,
        half_u: f64,
        half_v: f64,
    },
}

impl Shape {
    /// Smallest `t > 1e-9` with `o + t dir` on the shape (`dir` unit).
    pub(crate) fn cast(&self, o: &Vec3, dir: &Vec3) -> Option<f64> {
        match *self {
            Shape::Plane { n, d } => {
                let nd = n.dot(dir);
                let t = (d - n.dot(o)) / nd;
                (nd != 0.0 && t > 1e-9).then_some(t)
            }
            Shape::RoomBox { min, max } => {
                let mut best = f64::INFINITY;
                for a in 0..3 {
                    if dir[a] != 0.0 {
                        for f in [min[a], max[a]] {
                            let t = (f - o[a]) / dir[a];
                            if t > 1e-9 && t < best {
                                best = t;
                            }
                        }
                    }
                }
                best.is_finite().then_some(best)
            }
            Shape::Cylinder { c, axis, radius } => {
                let oc = o - c;
                let dp = dir - axis * axis.dot(dir);
                let op = oc - axis * axis.dot(&oc);
                let (a, b, cc) = (
                    dp.dot(&dp),
                    2.0 * dp.dot(&op),
                    op.dot(&op) - radius * radius,
                );
                let disc = b * b - 4.0 * a * cc;
                if a == 0.0 || disc < 0.0 {
                    return None;
                }
                let sq = libm::sqrt(disc);
                [(-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a)]
                    .into_iter()
                    .find(|&t| t > 1e-9)
            }
            Shape::Rect {
                c,
                u,
                v,
                half_u,
                half_v,
            } => {
                let n = u.cross(&v);
                let t = Shape::Plane { n, d: n.dot(&c) }.cast(o, dir)?;
                let q = o + dir * t - c;
                (q.dot(&u).abs() <= half_u && q.dot(&v).abs() <= half_v).then_some(t)
            }
        }
    }

    /// Distance of `p` from the shape's surface (box: from the nearest wall plane).
    pub(crate) fn distance(&self, p: &Vec3) -> f64 {
        match *self {
            Shape::Plane { n, d } => (n.dot(p) - d).abs(),
            Shape::RoomBox { min, max } => (0..3)
                .flat_map(|a| [(p[a] - min[a]).abs(), (p[a] - max[a]).abs()])
                .fold(f64::INFINITY, f64::min),
            Shape::Cylinder { c, axis, radius } => {
                let q = p - c;
                ((q - axis * axis.dot(&q)).norm() - radius).abs()
            }
            Shape::Rect { c, u, v, .. } => u.cross(&v).dot(&(p - c)).abs(),
        }
    }
}

/// Nearest hit of a ray in a scene.
pub(crate) fn cast(scene: &[Shape], o: &Vec3, dir: &Vec3) -> Option<f64> {
    scene
        .iter()
        .filter_map(|s| s.cast(o, dir))
        .fold(None, |m: Option<f64>, t| Some(m.map_or(t, |m| m.min(t))))
}

/// The sweep a LiDAR with extrinsic/time offset of `cfg` records on `motion` in `scene`: one
/// return per `(t_lidar_ns, direction in l)`; rays that hit nothing give no return.
pub(crate) fn sweep(
    motion: &Motion,
    cfg: &LidarConfig,
    scene: &[Shape],
    rays: impl IntoIterator<Item = (i64, Vec3)>,
) -> Vec<LidarPoint> {
    sweep_noisy(motion, cfg, scene, rays, 0.0)
}

/// [`sweep`] with Gaussian range noise of `sigma_m` (deterministic pseudo-random sequence).
pub(crate) fn sweep_noisy(
    motion: &Motion,
    cfg: &LidarConfig,
    scene: &[Shape],
    rays: impl IntoIterator<Item = (i64, Vec3)>,
    sigma_m: f64,
) -> Vec<LidarPoint> {
    let td_ns = libm::round(cfg.td_l_s * 1e9) as i64;
    let LidarExtrinsic { q_bl, p_bl } = cfg.extrinsic;
    let mut rng = SplitMix(0x5eed);
    rays.into_iter()
        .filter_map(|(t_ns, d_l)| {
            let (p_wb, q_wb) = motion.pose(t_ns + td_ns);
            let (p_wl, q_wl) = (p_wb + q_wb * p_bl, q_wb * q_bl);
            let d_w = q_wl * d_l.normalize();
            let t = cast(scene, &p_wl, &d_w)? + sigma_m * rng.gauss();
            let p_l = q_wl.inverse() * (d_w * t);
            Some(LidarPoint {
                t_ns,
                p_l: [p_l.x as f32, p_l.y as f32, p_l.z as f32],
                intensity: 1.0,
            })
        })
        .collect()
}

/// SplitMix64 with Box-Muller normals.
struct SplitMix(u64);

impl SplitMix {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    fn gauss(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        libm::sqrt(-2.0 * libm::log(u1)) * libm::cos(2.0 * core::f64::consts::PI * u2)
    }
}

/// Livox-style rosette (two counter-rotating prisms): direction in `l` (x forward) at time
/// `t`, polar angle up to `half_fov_rad` from the x axis.
pub(crate) fn rosette_dir(t_s: f64, half_fov_rad: f64) -> Vec3 {
    let (w1, w2) = (
        2.0 * core::f64::consts::PI * 121.57,
        2.0 * core::f64::consts::PI * 77.73,
    );
    let zx = 0.5 * half_fov_rad * (libm::cos(w1 * t_s) + libm::cos(w2 * t_s));
    let zy = 0.5 * half_fov_rad * (libm::sin(w1 * t_s) - libm::sin(w2 * t_s));
    let rho = libm::sqrt(zx * zx + zy * zy);
    let phi = libm::atan2(zy, zx);
    Vec3::new(
        libm::cos(rho),
        libm::sin(rho) * libm::cos(phi),
        libm::sin(rho) * libm::sin(phi),
    )
}

/// Directions of a golden-angle spiral covering the cap of `half_angle_rad` around `axis`.
pub(crate) fn spiral_cap(n: usize, axis: &Vec3, half_angle_rad: f64) -> Vec<Vec3> {
    let a = axis.normalize();
    let u = a
        .cross(&if a.x.abs() < 0.9 {
            Vec3::x()
        } else {
            Vec3::y()
        })
        .normalize();
    let v = a.cross(&u);
    let cos_max = libm::cos(half_angle_rad);
    let golden = core::f64::consts::PI * (3.0 - libm::sqrt(5.0));
    (0..n)
        .map(|i| {
            let cz = 1.0 - (1.0 - cos_max) * (i as f64 + 0.5) / n as f64;
            let sz = libm::sqrt(1.0 - cz * cz);
            let ph = golden * i as f64;
            a * cz + (u * libm::cos(ph) + v * libm::sin(ph)) * sz
        })
        .collect()
}

/// Runs `f` on a thread with a stack big enough for the full-size buffer and grid.
pub(crate) fn big_stack<F: FnOnce() + Send + 'static>(f: F) {
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(f)
        .unwrap()
        .join()
        .unwrap();
}
