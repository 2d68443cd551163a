//! Camera projection and the feature-tracker model.
//!
//! Projection (the simulator's own forward model; [`unproject`], its exact inverse used by the
//! image renderer, only takes its starting point from the core's undistortion):
//! `x = X/Z, y = Y/Z`, then radial-tangential distortion
//!
//! ```text
//! r^2 = x^2 + y^2,  k = 1 + k1 r^2 + k2 r^4
//! x_d = k x + 2 p1 x y + p2 (r^2 + 2 x^2),   y_d = k y + p1 (r^2 + 2 y^2) + 2 p2 x y
//! u = fx x_d + cx,  v = fy y_d + cy
//! ```
//!
//! (equidistant: `theta = atan(r)`, `theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)`,
//! `(x_d, y_d) = theta_d / r (x, y)`).
//!
//! Tracker model, per frame: every live track is kept while its landmark stays in the image, in
//! front, within the depth range, not seen at a grazing angle and not occluded (ray cast), and
//! survives a random loss whose probability grows with its image motion. A new track (new id,
//! also when a landmark is re-detected) is started on free image cells until the cap is reached.
//! A small fraction of new tracks later jumps to another nearby landmark (a wrong track). Every
//! observation gets isotropic Gaussian pixel noise.

use super::rng::Rng;
use super::scene::Landmarks;
use super::trajectory::Kinematics;
use super::world::World;
use povins_core::camera::{Distortion, FeatureObs, PinholeCamera};
use povins_core::math::{Mat3, Vec3};
use povins_platform::dataset::{Extrinsic, FeatureFrame};

/// Largest normalized radius accepted before distortion (beyond it radtan can fold back).
const MAX_NORM_RADIUS: f64 = 1.6;

/// Applies the distortion model to normalized coordinates `(x, y)` (no radius check).
pub fn distort_normalized(cam: &PinholeCamera, x: f64, y: f64) -> [f64; 2] {
    let r2 = x * x + y * y;
    match cam.distortion {
        Distortion::None => [x, y],
        Distortion::RadTan { k1, k2, p1, p2 } => {
            let k = 1.0 + k1 * r2 + k2 * r2 * r2;
            [
                k * x + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                k * y + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
            ]
        }
        Distortion::Equidistant { k } => {
            let r = libm::sqrt(r2);
            if r < 1e-12 {
                [x, y]
            } else {
                let th = libm::atan(r);
                let t2 = th * th;
                let thd = th * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))));
                [x * thd / r, y * thd / r]
            }
        }
    }
}

/// Projects a camera-frame point to raw (distorted) pixels; `None` when behind the camera.
pub fn project(cam: &PinholeCamera, p_c: &Vec3) -> Option<[f64; 2]> {
    if p_c.z <= 1e-6 {
        return None;
    }
    let (x, y) = (p_c.x / p_c.z, p_c.y / p_c.z);
    if x * x + y * y > MAX_NORM_RADIUS * MAX_NORM_RADIUS {
        return None;
    }
    let [xd, yd] = distort_normalized(cam, x, y);
    Some([cam.fx * xd + cam.cx, cam.fy * yd + cam.cy])
}

/// The exact inverse of [`project`] for a raw pixel: normalized coordinates `(x, y)` of the
/// ray `(x, y, 1)` that projects to `(u, v)` to better than 1e-9 px, or `None` when no ray
/// within the accepted radius does (the core's undistortion seeds Newton steps on this module's
/// forward model, so the two models cannot drift apart).
pub fn unproject(cam: &PinholeCamera, u: f64, v: f64) -> Option<[f64; 2]> {
    let x0 = cam.undistort(u, v).ok()?;
    let target = [(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy];
    let (mut x, mut y) = (x0.x, x0.y);
    let h = 1e-7;
    for _ in 0..8 {
        let f = distort_normalized(cam, x, y);
        let (rx, ry) = (f[0] - target[0], f[1] - target[1]);
        if (rx * cam.fx).abs() < 1e-10 && (ry * cam.fy).abs() < 1e-10 {
            break;
        }
        let fx = distort_normalized(cam, x + h, y);
        let fy = distort_normalized(cam, x, y + h);
        let (a, b) = ((fx[0] - f[0]) / h, (fy[0] - f[0]) / h);
        let (c, d) = ((fx[1] - f[1]) / h, (fy[1] - f[1]) / h);
        let det = a * d - b * c;
        if det.abs() < 1e-12 {
            return None;
        }
        x -= (d * rx - b * ry) / det;
        y -= (a * ry - c * rx) / det;
    }
    let f = distort_normalized(cam, x, y);
    let ok =
        ((f[0] - target[0]) * cam.fx).abs() < 1e-9 && ((f[1] - target[1]) * cam.fy).abs() < 1e-9;
    (ok && x * x + y * y <= MAX_NORM_RADIUS * MAX_NORM_RADIUS).then_some([x, y])
}

/// Tracker parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerParams {
    /// Maximum number of tracked features per frame.
    pub max_features: usize,
    /// Minimum distance between a new detection and any tracked feature, px.
    pub min_dist_px: f64,
    /// Landmark distance range, m.
    pub depth_range_m: (f64, f64),
    /// Image border kept free, px.
    pub border_px: f64,
    /// Largest angle between the viewing ray and the surface normal, rad.
    pub max_incidence_rad: f64,
    /// Per-frame loss probability of a track.
    pub base_loss: f64,
    /// Extra loss probability per pixel of image motion since the previous frame.
    pub loss_per_px: f64,
    /// Fraction of new tracks that later jump to a wrong landmark.
    pub wrong_track_rate: f64,
    /// Pixel noise (1 sigma, each axis), px.
    pub pixel_noise_px: f64,
    /// Angular radius of the occlusion-boundary test around a landmark, rad.
    pub edge_angle_rad: f64,
    /// Longest track, frames (`None`: tracks live as long as the other rules allow).
    pub max_track_frames: Option<u32>,
}

#[derive(Debug, Clone)]
struct Track {
    id: u64,
    lm: usize,
    age: u32,
    jump_at: Option<u32>,
    jumped: bool,
    reported: bool,
    last_uv: [f64; 2],
}

/// What the camera simulation records for evaluation.
#[derive(Debug, Clone, Default)]
pub struct CameraTruth {
    /// `(feature id, true landmark position)` at track creation, increasing ids.
    pub landmarks_w: Vec<(u64, Vec3)>,
    /// Ids of tracks that jumped to another landmark.
    pub wrong_tracks: Vec<u64>,
    /// Ids of tracks whose landmark was seen near an occlusion boundary.
    pub edge_features: Vec<u64>,
}

/// The tracker state across frames.
pub struct CameraSim<'a> {
    world: &'a World,
    lms: &'a Landmarks,
    cam: PinholeCamera,
    r_bc: Mat3,
    p_bc: Vec3,
    params: TrackerParams,
    tracks: Vec<Track>,
    tracked: Vec<bool>,
    edge_flag: Vec<bool>,
    next_id: u64,
    rng: Rng,
    /// Evaluation truth accumulated so far.
    pub truth: CameraTruth,
}

struct View {
    o_w: Vec3,
    r_cw: Mat3,
}

impl<'a> CameraSim<'a> {
    /// A tracker with no features yet.
    pub fn new(
        world: &'a World,
        lms: &'a Landmarks,
        cam: PinholeCamera,
        t_bc: &Extrinsic,
        params: TrackerParams,
        rng: Rng,
    ) -> Self {
        CameraSim {
            world,
            lms,
            cam,
            r_bc: t_bc.q_ab.to_rotation_matrix().into_inner(),
            p_bc: t_bc.p_ab,
            params,
            tracks: Vec::new(),
            tracked: vec![false; lms.len()],
            edge_flag: Vec::new(),
            next_id: 1,
            rng,
            truth: CameraTruth::default(),
        }
    }

    /// Noise-free pixel of landmark `i` when it passes every test except occlusion.
    fn visible_uv(&self, v: &View, i: usize) -> Option<[f64; 2]> {
        let p = self.lms.p_w[i];
        let d = p - v.o_w;
        let dist = d.norm();
        let (lo, hi) = self.params.depth_range_m;
        if dist < lo || dist > hi {
            return None;
        }
        // Facing test: the outward normal must point back at the camera.
        if -d.dot(&self.lms.n_w[i]) < dist * libm::cos(self.params.max_incidence_rad) {
            return None;
        }
        let uv = project(&self.cam, &(v.r_cw * d))?;
        let b = self.params.border_px;
        if uv[0] < b
            || uv[1] < b
            || uv[0] > self.cam.width as f64 - 1.0 - b
            || uv[1] > self.cam.height as f64 - 1.0 - b
        {
            return None;
        }
        Some(uv)
    }

    fn in_sight(&self, v: &View, i: usize) -> bool {
        let p = self.lms.p_w[i];
        let tol = 0.01 + 1e-4 * (p - v.o_w).norm();
        self.world.line_of_sight(&v.o_w, &p, tol)
    }

    /// True when a ray within `edge_angle_rad` of the landmark's direction hits another surface
    /// at a clearly different depth (or nothing): the landmark sits on an occlusion boundary.
    fn on_edge(&self, v: &View, i: usize) -> bool {
        let p = self.lms.p_w[i];
        let dv = p - v.o_w;
        let dist = dv.norm();
        let d = dv / dist;
        let a = if d.x.abs() < 0.9 {
            Vec3::x()
        } else {
            Vec3::y()
        };
        let e1 = d.cross(&a).normalize();
        let e2 = d.cross(&e1);
        let tan = libm::tan(self.params.edge_angle_rad);
        let surf = self.lms.surface[i];
        let jump = (0.3f64).max(0.1 * dist);
        for k in 0..8 {
            let ang = k as f64 * core::f64::consts::FRAC_PI_4;
            let r = (d + (e1 * libm::cos(ang) + e2 * libm::sin(ang)) * tan).normalize();
            match self.world.raycast(&v.o_w, &r, dist * 3.0 + 50.0) {
                None => return true,
                Some(h) => {
                    if h.surface_id() != surf && (h.t - dist).abs() > jump {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// Where a rolling shutter sees landmark `lm`, first seen at `uv` by the stamp's view: the
    /// row time moves the pose, which moves the row; three fixed-point steps (each shrinks the
    /// row's error by the image motion per row times the readout per row, 0.06 on the hand-held
    /// rig at 30 ms) end within 0.02 px of the fixed point. `uv` itself for a global shutter or
    /// when a step leaves the image.
    fn rolling_shutter_uv(
        &self,
        lm: usize,
        uv: [f64; 2],
        at_row: &dyn Fn(f64) -> Kinematics,
    ) -> [f64; 2] {
        if self.cam.readout_s == 0.0 {
            return uv;
        }
        let mut cur = uv;
        for _ in 0..3 {
            let kin = at_row(self.cam.row_time_s(cur[1]));
            let r_wc = kin.r_wb * self.r_bc;
            let o_w = kin.p_wb + kin.r_wb * self.p_bc;
            match project(&self.cam, &(r_wc.transpose() * (self.lms.p_w[lm] - o_w))) {
                Some(next) => cur = next,
                None => return uv,
            }
        }
        cur
    }

    /// Simulates one image whose middle row is taken at the true time of `kin`, stamped
    /// `stamp_ns` (camera clock); `at_row(dt)` is the body's state `dt` s after that time (a
    /// rolling shutter's rows, [`PinholeCamera::row_time_s`]). Which tracks live and where new
    /// ones start is decided at the middle row's pose; the reported pixels are the rows' own.
    pub fn step(
        &mut self,
        kin: &Kinematics,
        stamp_ns: i64,
        at_row: &dyn Fn(f64) -> Kinematics,
    ) -> FeatureFrame {
        let r_wc = kin.r_wb * self.r_bc;
        let view = View {
            o_w: kin.p_wb + kin.r_wb * self.p_bc,
            r_cw: r_wc.transpose(),
        };
        // Candidates: landmarks passing every cheap test, in a fixed then shuffled order.
        let mut cand: Vec<(usize, [f64; 2])> = Vec::new();
        self.lms
            .for_each_near(&view.o_w, self.params.depth_range_m.1, |i| {
                if let Some(uv) = self.visible_uv(&view, i) {
                    cand.push((i, uv));
                }
            });

        let mut obs = Vec::with_capacity(self.params.max_features);
        let mut tracks = core::mem::take(&mut self.tracks);
        let mut kept = Vec::with_capacity(tracks.len());
        for mut tr in tracks.drain(..) {
            tr.age += 1;
            // Scheduled wrong-track jump: lock onto a nearby, visible, untracked landmark.
            // The jump target must be clearly away from where the true landmark is now.
            let here = project(&self.cam, &(view.r_cw * (self.lms.p_w[tr.lm] - view.o_w)));
            if let (false, true, Some(here)) =
                (tr.jumped, tr.jump_at.is_some_and(|a| tr.age >= a), here)
            {
                let mut best: Option<usize> = None;
                for &(j, uv) in &cand {
                    let dpx = libm::hypot(uv[0] - here[0], uv[1] - here[1]);
                    if !self.tracked[j] && (8.0..40.0).contains(&dpx) && self.in_sight(&view, j) {
                        best = Some(j);
                        break;
                    }
                }
                if let Some(j) = best {
                    self.tracked[tr.lm] = false;
                    self.tracked[j] = true;
                    tr.lm = j;
                    tr.jumped = true;
                }
            }
            let uv = match self.visible_uv(&view, tr.lm) {
                Some(uv) if self.in_sight(&view, tr.lm) => uv,
                _ => {
                    self.tracked[tr.lm] = false;
                    continue;
                }
            };
            if self.params.max_track_frames.is_some_and(|m| tr.age >= m) {
                self.tracked[tr.lm] = false;
                continue;
            }
            let motion = libm::hypot(uv[0] - tr.last_uv[0], uv[1] - tr.last_uv[1]);
            let p_loss = (self.params.base_loss + self.params.loss_per_px * motion).min(0.9);
            if self.rng.chance(p_loss) {
                self.tracked[tr.lm] = false;
                continue;
            }
            tr.last_uv = uv;
            kept.push(tr);
        }
        self.tracks = kept;

        // Detector: fill free cells of a min-distance occupancy grid.
        let cell = self.params.min_dist_px.max(1.0);
        let gw = (self.cam.width as f64 / cell).ceil() as usize + 1;
        let gh = (self.cam.height as f64 / cell).ceil() as usize + 1;
        let mut occ = vec![false; gw * gh];
        let cell_of = |uv: [f64; 2]| {
            let cx = ((uv[0] / cell) as usize).min(gw - 1);
            let cy = ((uv[1] / cell) as usize).min(gh - 1);
            cy * gw + cx
        };
        for tr in &self.tracks {
            occ[cell_of(tr.last_uv)] = true;
        }
        self.rng.shuffle(&mut cand);
        for &(i, uv) in &cand {
            if self.tracks.len() >= self.params.max_features {
                break;
            }
            let c = cell_of(uv);
            if self.tracked[i] || occ[c] || !self.in_sight(&view, i) {
                continue;
            }
            occ[c] = true;
            self.tracked[i] = true;
            let id = self.next_id;
            self.next_id += 1;
            let jump_at = if self.rng.chance(self.params.wrong_track_rate) {
                Some(2 + self.rng.below(8) as u32)
            } else {
                None
            };
            self.truth.landmarks_w.push((id, self.lms.p_w[i]));
            self.edge_flag.push(false);
            self.tracks.push(Track {
                id,
                lm: i,
                age: 0,
                jump_at,
                jumped: false,
                reported: false,
                last_uv: uv,
            });
        }

        for k in 0..self.tracks.len() {
            let (id, lm, jumped, uv) = {
                let t = &self.tracks[k];
                (t.id, t.lm, t.jumped, t.last_uv)
            };
            let slot = (id - 1) as usize;
            // A wrong track counts once it has produced an observation of the wrong landmark.
            if jumped && !self.tracks[k].reported {
                self.tracks[k].reported = true;
                self.truth.wrong_tracks.push(id);
            }
            if !jumped && !self.edge_flag[slot] && self.on_edge(&view, lm) {
                self.edge_flag[slot] = true;
                self.truth.edge_features.push(id);
            }
            let uv = self.rolling_shutter_uv(lm, uv, at_row);
            let s = self.params.pixel_noise_px;
            obs.push(FeatureObs {
                id,
                u_px: uv[0] + s * self.rng.normal(),
                v_px: uv[1] + s * self.rng.normal(),
            });
        }
        FeatureFrame {
            t_ns: stamp_ns,
            obs,
        }
    }

    /// Finishes: sorted, duplicate-free truth lists.
    pub fn finish(mut self) -> CameraTruth {
        self.truth.wrong_tracks.sort_unstable();
        self.truth.edge_features.sort_unstable();
        self.truth
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radtan_projection_matches_hand_computation() {
        let cam = PinholeCamera {
            readout_s: 0.0,
            width: 752,
            height: 480,
            fx: 450.0,
            fy: 460.0,
            cx: 370.0,
            cy: 250.0,
            distortion: Distortion::RadTan {
                k1: -0.28,
                k2: 0.07,
                p1: 2e-4,
                p2: 2e-5,
            },
        };
        let uv = project(&cam, &Vec3::new(0.4, -0.2, 2.0)).unwrap();
        let (x, y) = (0.2f64, -0.1f64);
        let r2 = x * x + y * y;
        let k = 1.0 - 0.28 * r2 + 0.07 * r2 * r2;
        let xd = k * x + 2.0 * 2e-4 * x * y + 2e-5 * (r2 + 2.0 * x * x);
        let yd = k * y + 2e-4 * (r2 + 2.0 * y * y) + 2.0 * 2e-5 * x * y;
        assert!((uv[0] - (450.0 * xd + 370.0)).abs() < 1e-12);
        assert!((uv[1] - (460.0 * yd + 250.0)).abs() < 1e-12);
        assert!(project(&cam, &Vec3::new(0.0, 0.0, -1.0)).is_none());
    }
}
