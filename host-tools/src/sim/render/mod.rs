//! Grayscale camera images of the simulated world, with ground truth for image tracking.
//!
//! Each pixel centre has its exact viewing ray (the inverse of
//! [`camera::project`](crate::sim::camera::project), distortion included, see [`rays`]); the ray
//! is cast against the primitives that may be visible in its 16x16 tile ([`scene`]) and the
//! ground. The hit point's albedo is a world-fixed procedural texture ([`texture`]) filtered over
//! the pixel's footprint (ray differentials), shaded by a fixed sun plus ambient light; rays that
//! hit nothing see a sky gradient. Pixels whose neighbours see another surface or face (object
//! silhouettes, box edges) are rendered again with `edge_samples`^2 sub-pixel samples, so edges
//! are anti-aliased like textures; `supersample` > 1 samples every pixel that way.
//!
//! Options (all off by default, all deterministic from the seed): motion blur (average of
//! sub-frame renders over the exposure, the image stamp being mid-exposure), a smooth global
//! exposure/gain change over time, Gaussian pixel noise in grey levels. No shadows, no
//! reflections, no vignetting, global shutter.
//!
//! Images are rendered at the true pose of the frame (`T_wb(t) T_bc`, trajectory time
//! `t = stamp - T0 + td`), so the [`truth`] module's pixel transfer and depth maps are the
//! ground truth for tracking.

pub mod rays;
pub mod scene;
pub mod sequence;
pub mod texture;
pub mod truth;

#[cfg(test)]
mod tests;

use super::rng::Rng;
use super::trajectory::{Kinematics, Trajectory};
use super::world::{Hit, Material, Shape, World};
use povins_core::camera::PinholeCamera;
use povins_core::math::{Mat3, Vec3};
use povins_platform::dataset::Extrinsic;
use rays::RayTable;
pub use scene::View;
use scene::{bounding_sphere, surface_key, Visible};
pub use texture::Chart;

/// Ambient share of the lighting.
pub const AMBIENT: f64 = 0.5;
/// Direct (sun) share of the lighting.
pub const DIRECT: f64 = 0.5;

/// Unit direction towards the sun in `w`.
pub fn sun_direction() -> Vec3 {
    Vec3::new(0.35, -0.3, 0.88).normalize()
}

/// Rendering options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Samples per pixel side everywhere (1: one filtered sample per pixel).
    pub supersample: u32,
    /// Samples per pixel side on geometric edges (silhouettes, box edges).
    pub edge_samples: u32,
    /// Exposure time for motion blur, s (0 = off).
    pub motion_blur_s: f64,
    /// Sub-frames averaged for motion blur (0 = enough for about 1 px of image motion between
    /// sub-frames, 2 to 16).
    pub blur_subframes: u32,
    /// Standard deviation of the log exposure gain over time (0 = constant exposure).
    pub exposure_var: f64,
    /// Gaussian pixel noise, grey levels (1 sigma).
    pub noise_grey: f64,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            supersample: 1,
            edge_samples: 3,
            motion_blur_s: 0.0,
            blur_subframes: 0,
            exposure_var: 0.0,
            noise_grey: 0.0,
        }
    }
}

impl RenderOptions {
    /// Rejects options that cannot be rendered.
    pub fn check(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            (1..=8).contains(&self.supersample) && (1..=8).contains(&self.edge_samples),
            "samples per pixel side must be 1..=8"
        );
        anyhow::ensure!(
            self.motion_blur_s.is_finite() && (0.0..=0.2).contains(&self.motion_blur_s),
            "motion blur exposure must be in 0..=200 ms"
        );
        anyhow::ensure!(self.blur_subframes <= 64, "at most 64 blur sub-frames");
        anyhow::ensure!(
            self.exposure_var.is_finite() && (0.0..=2.0).contains(&self.exposure_var),
            "exposure variation must be in 0..=2"
        );
        anyhow::ensure!(
            self.noise_grey.is_finite() && (0.0..=100.0).contains(&self.noise_grey),
            "image noise must be in 0..=100 grey levels"
        );
        Ok(())
    }
}

/// Rows that share one culling in a rolling-shutter image ([`Renderer::radiance_rolling`]).
pub const ROLLING_SHUTTER_BAND_ROWS: usize = 16;

/// Random stream of the pixel noise (per frame) and the exposure curve.
const STREAM_IMAGE_NOISE: u64 = 7;
const STREAM_EXPOSURE: u64 = 8;

/// Renders one camera of one world.
pub struct Renderer<'w> {
    world: &'w World,
    cam: PinholeCamera,
    r_bc: Mat3,
    p_bc: Vec3,
    rays: RayTable,
    bounds: Vec<(Vec3, f64)>,
    sun: Vec3,
    ambient: f64,
    direct: f64,
    albedo: Option<AlbedoFn<'w>>,
}

/// A replacement for the procedural textures: albedo of a surface (material, surface id) at a
/// chart point with its footprint.
pub type AlbedoFn<'a> = Box<dyn Fn(Material, u32, &Chart) -> f64 + Send + Sync + 'a>;

/// Pixel-space derivatives of a sample's normalized ray: `[dx/du, dy/du]`, `[dx/dv, dy/dv]`.
type RayDiff = ([f64; 2], [f64; 2]);

impl<'w> Renderer<'w> {
    /// A renderer for `cam` mounted at `t_bc` (builds the ray table, about 0.2 s at 752x480).
    pub fn new(world: &'w World, cam: PinholeCamera, t_bc: &Extrinsic) -> Self {
        Renderer {
            world,
            cam,
            r_bc: t_bc.q_ab.to_rotation_matrix().into_inner(),
            p_bc: t_bc.p_ab,
            rays: RayTable::new(&cam),
            bounds: world
                .primitives()
                .iter()
                .map(|p| bounding_sphere(&p.shape))
                .collect(),
            sun: sun_direction(),
            ambient: AMBIENT,
            direct: DIRECT,
            albedo: None,
        }
    }

    /// Replaces the procedural textures (tests: markers of known shape).
    pub fn with_albedo(mut self, f: AlbedoFn<'w>) -> Self {
        self.albedo = Some(f);
        self
    }

    /// Replaces the lighting: radiance = albedo * (ambient + direct * max(0, n . sun)).
    pub fn with_lighting(mut self, ambient: f64, direct: f64) -> Self {
        self.ambient = ambient;
        self.direct = direct;
        self
    }

    /// The camera.
    pub fn camera(&self) -> &PinholeCamera {
        &self.cam
    }

    /// The ray table.
    pub fn rays(&self) -> &RayTable {
        &self.rays
    }

    /// The world.
    pub fn world(&self) -> &'w World {
        self.world
    }

    /// Camera pose for a body state.
    pub fn view(&self, kin: &Kinematics) -> View {
        View {
            o_w: kin.p_wb + kin.r_wb * self.p_bc,
            r_wc: kin.r_wb * self.r_bc,
        }
    }

    /// One sample: radiance and surface key of the ray `(x, y, 1)` with its pixel differentials.
    fn sample(
        &self,
        vis: &Visible,
        view: &View,
        tile: usize,
        xy: [f64; 2],
        dj: RayDiff,
    ) -> (f64, u32) {
        let r = view.r_wc * Vec3::new(xy[0], xy[1], 1.0);
        let rn = r.norm();
        let d = r / rn;
        let hit = vis.trace(self.world, tile, &view.o_w, &d);
        let key = surface_key(hit.as_ref());
        match hit {
            None => (texture::sky(&d), key),
            Some(h) => (self.shade(view, &h, &r, rn, dj), key),
        }
    }

    /// Shaded radiance of a hit of the (unnormalized) ray `r`.
    fn shade(&self, view: &View, h: &Hit, r: &Vec3, rn: f64, dj: RayDiff) -> f64 {
        let n = h.normal;
        let p = view.o_w + r * (h.t / rn);
        // Ray differentials: how the hit point moves per pixel along u and v.
        let ndr = n.dot(r);
        let ndr = if ndr.abs() < 1e-9 * rn {
            -1e-9 * rn
        } else {
            ndr
        };
        let tr = h.t / rn;
        let diff = |j: [f64; 2]| {
            let rd = view.r_wc * Vec3::new(j[0], j[1], 0.0);
            (rd - r * (n.dot(&rd) / ndr)) * tr
        };
        let (pu, pv) = (diff(dj.0), diff(dj.1));
        let planar = |a: usize, b: usize| Chart::Plane {
            st: [p[a], p[b]],
            fp: [pu[a].abs() + pv[a].abs(), pu[b].abs() + pv[b].abs()],
            period: 0.0,
        };
        let (material, chart) = match h.prim {
            None => (Material::Ground, planar(0, 1)),
            Some(k) => {
                let prim = &self.world.primitives()[k as usize];
                let chart = match prim.shape {
                    Shape::Box { .. } => {
                        if n.x.abs() > 0.5 {
                            planar(1, 2)
                        } else if n.y.abs() > 0.5 {
                            planar(0, 2)
                        } else {
                            planar(0, 1)
                        }
                    }
                    Shape::Cylinder { cx, cy, r: rad, .. } => {
                        if n.z.abs() > 0.5 {
                            planar(0, 1)
                        } else {
                            let phi = libm::atan2(p.y - cy, p.x - cx);
                            let tan = Vec3::new(-n.y, n.x, 0.0);
                            Chart::Plane {
                                st: [rad * phi, p.z],
                                fp: [
                                    tan.dot(&pu).abs() + tan.dot(&pv).abs(),
                                    pu.z.abs() + pv.z.abs(),
                                ],
                                period: 2.0 * core::f64::consts::PI * rad,
                            }
                        }
                    }
                    Shape::Sphere { .. } => Chart::Solid {
                        p: [p.x, p.y, p.z],
                        fp: pu.norm().max(pv.norm()),
                    },
                };
                (prim.material, chart)
            }
        };
        let a = match &self.albedo {
            Some(f) => f(material, h.surface_id(), &chart),
            None => texture::albedo(material, h.surface_id(), &chart),
        };
        a * (self.ambient + self.direct * n.dot(&self.sun).max(0.0))
    }

    /// Mean radiance of `s` x `s` samples of pixel `(col, row)`, with the key of the first.
    fn pixel(
        &self,
        vis: &Visible,
        view: &View,
        col: usize,
        row: usize,
        s: u32,
    ) -> Option<(f64, u32)> {
        let c = self.rays.center(col, row)?;
        let j = self.rays.jacobian(col, row);
        let tile = self.rays.tile_of(col, row);
        if s <= 1 {
            return Some(self.sample(vis, view, tile, c, ([j[0], j[1]], [j[2], j[3]])));
        }
        let inv = 1.0 / s as f64;
        let dj = ([j[0] * inv, j[1] * inv], [j[2] * inv, j[3] * inv]);
        let (mut acc, mut key) = (0.0, None);
        for b in 0..s {
            let dv = (b as f64 + 0.5) * inv - 0.5;
            for a in 0..s {
                let du = (a as f64 + 0.5) * inv - 0.5;
                let xy = [c[0] + j[0] * du + j[2] * dv, c[1] + j[1] * du + j[3] * dv];
                let (l, k) = self.sample(vis, view, tile, xy, dj);
                acc += l;
                key.get_or_insert(k);
            }
        }
        Some((acc * inv * inv, key.unwrap_or(0)))
    }

    /// Anti-aliased edge pixel: `e` x `e` sub-samples find the surfaces (traced only); each
    /// surface is shaded once, at the mean position of its samples with a footprint of its share
    /// of the pixel, and weighted by its sample count.
    fn edge_pixel(
        &self,
        vis: &Visible,
        view: &View,
        col: usize,
        row: usize,
        e: u32,
    ) -> Option<f64> {
        let c = self.rays.center(col, row)?;
        let j = self.rays.jacobian(col, row);
        let tile = self.rays.tile_of(col, row);
        let inv = 1.0 / e as f64;
        // (key, count, sum du, sum dv, first du, first dv) per surface.
        let mut groups: Vec<(u32, u32, f64, f64, f64, f64)> = Vec::with_capacity(4);
        for b in 0..e {
            let dv = (b as f64 + 0.5) * inv - 0.5;
            for a in 0..e {
                let du = (a as f64 + 0.5) * inv - 0.5;
                let xy = [c[0] + j[0] * du + j[2] * dv, c[1] + j[1] * du + j[3] * dv];
                let r = view.r_wc * Vec3::new(xy[0], xy[1], 1.0);
                let key = surface_key(
                    vis.trace(self.world, tile, &view.o_w, &r.normalize())
                        .as_ref(),
                );
                match groups.iter_mut().find(|g| g.0 == key) {
                    Some(g) => {
                        g.1 += 1;
                        g.2 += du;
                        g.3 += dv;
                    }
                    None => groups.push((key, 1, du, dv, du, dv)),
                }
            }
        }
        let mut acc = 0.0;
        for &(key, n, su, sv, fu, fv) in &groups {
            let f = (n as f64).sqrt() * inv;
            let dj = ([j[0] * f, j[1] * f], [j[2] * f, j[3] * f]);
            let at =
                |du: f64, dv: f64| [c[0] + j[0] * du + j[2] * dv, c[1] + j[1] * du + j[3] * dv];
            let (mu, mv) = (su / n as f64, sv / n as f64);
            let (mut l, k) = self.sample(vis, view, tile, at(mu, mv), dj);
            if k != key {
                // The mean position of a non-convex group fell on another surface.
                l = self.sample(vis, view, tile, at(fu, fv), dj).0;
            }
            acc += l * n as f64;
        }
        Some(acc * inv * inv)
    }

    /// Linear radiance image (row-major, nominally in `[0, 1]`; 0 where a pixel has no ray).
    pub fn radiance(&self, view: &View, opts: &RenderOptions) -> Vec<f32> {
        let vis = Visible::new(self.world, &self.bounds, &self.rays, view);
        self.radiance_with(&|_| (&vis, view), opts)
    }

    /// [`Self::radiance`] of a rolling shutter whose middle row is seen at trajectory time
    /// `t_s`: row `r` from the pose at `t_s + row_time_s(r)`
    /// ([`PinholeCamera::row_time_s`]), each row's rays cast from its own view; the culling is
    /// shared by bands of [`ROLLING_SHUTTER_BAND_ROWS`] rows and widened to cover their views.
    pub fn radiance_rolling(&self, traj: &Trajectory, t_s: f64, opts: &RenderOptions) -> Vec<f32> {
        let h = self.rays.height;
        let views: Vec<View> = (0..h)
            .map(|r| self.view(&traj.eval(t_s + self.cam.row_time_s(r as f64))))
            .collect();
        let band = ROLLING_SHUTTER_BAND_ROWS;
        let culls: Vec<Visible> = (0..h)
            .step_by(band)
            .map(|r0| {
                let rows = &views[r0..(r0 + band).min(h)];
                let mid = &rows[rows.len() / 2];
                let (mut dth, mut dp) = (0.0f64, 0.0f64);
                for v in rows {
                    let c = ((mid.r_wc.transpose() * v.r_wc).trace() - 1.0) * 0.5;
                    dth = dth.max(c.clamp(-1.0, 1.0).acos());
                    dp = dp.max((v.o_w - mid.o_w).norm());
                }
                // acos loses precision near 0: a margin of 1e-6 rad and 1e-6 m on top.
                let (dth, dp) = (dth + 1e-6, dp + 1e-6);
                Visible::with_margin(self.world, &self.bounds, &self.rays, mid, dth, dp)
            })
            .collect();
        self.radiance_with(&|row| (&culls[row / band], &views[row]), opts)
    }

    /// The radiance image with the culling and the view of each row from `row_view`.
    fn radiance_with<'v>(
        &self,
        row_view: &dyn Fn(usize) -> (&'v Visible, &'v View),
        opts: &RenderOptions,
    ) -> Vec<f32> {
        let (w, h) = (self.rays.width, self.rays.height);
        let s = opts.supersample.max(1);
        let mut img = vec![0.0f32; w * h];
        let mut keys = vec![u32::MAX; w * h];
        for row in 0..h {
            let (vis, view) = row_view(row);
            for col in 0..w {
                if let Some((l, k)) = self.pixel(vis, view, col, row, s) {
                    img[row * w + col] = l as f32;
                    keys[row * w + col] = k;
                }
            }
        }
        let e = opts.edge_samples;
        if e > s {
            for row in 0..h {
                let (vis, view) = row_view(row);
                for col in 0..w {
                    let k = keys[row * w + col];
                    let edge = (col > 0 && keys[row * w + col - 1] != k)
                        || (col + 1 < w && keys[row * w + col + 1] != k)
                        || (row > 0 && keys[(row - 1) * w + col] != k)
                        || (row + 1 < h && keys[(row + 1) * w + col] != k);
                    if edge {
                        if let Some(l) = self.edge_pixel(vis, view, col, row, e) {
                            img[row * w + col] = l as f32;
                        }
                    }
                }
            }
        }
        img
    }

    /// Depth map: camera-frame `z` of the surface seen by each pixel centre, m (NaN for sky or
    /// no ray).
    pub fn depth(&self, view: &View) -> Vec<f32> {
        let (w, h) = (self.rays.width, self.rays.height);
        let vis = Visible::new(self.world, &self.bounds, &self.rays, view);
        let mut out = vec![f32::NAN; w * h];
        for row in 0..h {
            for col in 0..w {
                let Some(c) = self.rays.center(col, row) else {
                    continue;
                };
                let r = view.r_wc * Vec3::new(c[0], c[1], 1.0);
                let rn = r.norm();
                if let Some(hit) = vis.trace(
                    self.world,
                    self.rays.tile_of(col, row),
                    &view.o_w,
                    &(r / rn),
                ) {
                    out[row * w + col] = (hit.t / rn) as f32;
                }
            }
        }
        out
    }

    /// The radiance image whose middle row is seen at trajectory time `t_s`: one view for a
    /// global shutter, one per row for a rolling shutter.
    fn radiance_at(&self, traj: &Trajectory, t_s: f64, opts: &RenderOptions) -> Vec<f32> {
        if self.cam.readout_s > 0.0 {
            self.radiance_rolling(traj, t_s, opts)
        } else {
            self.radiance(&self.view(&traj.eval(t_s)), opts)
        }
    }

    /// Renders the 8-bit image of a frame at trajectory time `t_s` (mid-exposure of its middle
    /// row), the
    /// `index`-th of the sequence (selects its noise stream).
    pub fn render_frame(
        &self,
        traj: &Trajectory,
        t_s: f64,
        index: u64,
        seed: u64,
        opts: &RenderOptions,
    ) -> Vec<u8> {
        let radiance = if opts.motion_blur_s > 0.0 {
            let n = blur_subframes(traj, t_s, self.cam.fx.max(self.cam.fy), opts);
            let mut acc = vec![0.0f32; self.rays.width * self.rays.height];
            for k in 0..n {
                let tk = t_s + opts.motion_blur_s * ((k as f64 + 0.5) / n as f64 - 0.5);
                let img = self.radiance_at(traj, tk, opts);
                for (a, v) in acc.iter_mut().zip(img) {
                    *a += v;
                }
            }
            let inv = 1.0 / n as f32;
            acc.iter_mut().for_each(|a| *a *= inv);
            acc
        } else {
            self.radiance_at(traj, t_s, opts)
        };
        let gain = 255.0 * exposure_gain(seed, opts.exposure_var, t_s);
        let mut rng = Rng::stream(seed, STREAM_IMAGE_NOISE, index);
        radiance
            .iter()
            .map(|&l| {
                let mut v = gain * f64::from(l);
                if opts.noise_grey > 0.0 {
                    v += opts.noise_grey * rng.normal();
                }
                v.round().clamp(0.0, 255.0) as u8
            })
            .collect()
    }
}

/// Sub-frames for motion blur: the option, or enough for about 1 px of image motion between
/// them (rotation, plus translation seen at 2 m), 2 to 16.
fn blur_subframes(traj: &Trajectory, t_s: f64, f_px: f64, opts: &RenderOptions) -> u32 {
    if opts.blur_subframes > 0 {
        return opts.blur_subframes;
    }
    let k = traj.eval(t_s);
    let rate = k.omega_b.norm() + k.v_wb.norm() / 2.0;
    ((rate * f_px * opts.motion_blur_s).ceil() as u32 + 1).clamp(2, 16)
}

/// Global exposure gain at time `t_s`: `exp(var * g(t))` with `g` a smooth, unit-variance sum of
/// three slow sinusoids (0.03 to 0.3 Hz) whose frequencies and phases come from the seed.
pub fn exposure_gain(seed: u64, var: f64, t_s: f64) -> f64 {
    if var <= 0.0 {
        return 1.0;
    }
    let mut r = Rng::stream(seed, STREAM_EXPOSURE, 0);
    let amps = [1.0, 0.6, 0.35];
    let norm = (amps.iter().map(|a| a * a * 0.5).sum::<f64>()).sqrt();
    let g: f64 = amps
        .iter()
        .map(|a| {
            let f = r.range(0.03, 0.3);
            let ph = r.range(0.0, 2.0 * core::f64::consts::PI);
            a * libm::sin(2.0 * core::f64::consts::PI * f * t_s + ph)
        })
        .sum();
    libm::exp(var * g / norm)
}
