//! Ground truth for image tracking: where a pixel of one frame is in another frame, and depth
//! maps.
//!
//! A pixel is turned into its exact viewing ray ([`camera::unproject`](crate::sim::camera::unproject)), cast against the world
//! ([`World::raycast`], independent of the renderer's culling) and the surface point is projected
//! into the other frame with [`camera::project`](crate::sim::camera::project); the result is `None` when the point is out of
//! the other image, seen from behind or occluded there.

use super::{Renderer, View};
use crate::sim::camera::{project, unproject};
use crate::sim::world::World;
use crate::sim::SimOutput;
use povins_core::camera::PinholeCamera;
use povins_core::math::Vec3;
use povins_platform::dataset::Extrinsic;

/// Views of every camera frame of a simulated sequence, with the world to cast rays into.
pub struct ImageTruth<'w> {
    renderer: Renderer<'w>,
    stamps: Vec<i64>,
    views: Vec<View>,
}

/// Camera frames of a simulated sequence: `(stamp on the camera clock, trajectory time in s)`.
/// The trajectory time is the exposure instant on the IMU clock, `stamp - T0 + td` (the
/// simulator's clock convention; the frame's own `td` when the delay steps).
pub fn camera_frames(out: &SimOutput) -> Vec<(i64, f64)> {
    out.dataset
        .features
        .iter()
        .zip(&out.frames.t_s)
        .map(|(f, &t)| (f.t_ns, t))
        .collect()
}

impl<'w> ImageTruth<'w> {
    /// Truth for the camera frames of `out` (the frames of `dataset.features`, which are also
    /// the rendered images).
    pub fn new(out: &'w SimOutput) -> Self {
        let c = &out.dataset.calib;
        let renderer = Renderer::new(&out.world, c.camera, &c.t_bc);
        let frames = camera_frames(out);
        let views = frames
            .iter()
            .map(|&(_, t)| renderer.view(&out.trajectory.eval(t)))
            .collect();
        ImageTruth {
            renderer,
            stamps: frames.iter().map(|f| f.0).collect(),
            views,
        }
    }

    /// Truth for given camera poses (the renderer is built with an identity `T_bc`).
    pub fn with_views(
        world: &'w World,
        cam: PinholeCamera,
        stamps: Vec<i64>,
        views: Vec<View>,
    ) -> Self {
        ImageTruth {
            renderer: Renderer::new(world, cam, &Extrinsic::identity()),
            stamps,
            views,
        }
    }

    /// Frame stamps (camera clock), ns.
    pub fn stamps(&self) -> &[i64] {
        &self.stamps
    }

    /// Index of the frame stamped `t_ns`.
    pub fn frame_at(&self, t_ns: i64) -> Option<usize> {
        self.stamps.binary_search(&t_ns).ok()
    }

    /// The camera pose of frame `i`.
    pub fn view(&self, i: usize) -> Option<&View> {
        self.views.get(i)
    }

    /// The renderer (same camera and world).
    pub fn renderer(&self) -> &Renderer<'w> {
        &self.renderer
    }

    /// World point and outward normal seen at raw pixel `uv` of frame `i` (`None`: sky or no
    /// ray).
    pub fn surface_point(&self, i: usize, uv: [f64; 2]) -> Option<(Vec3, Vec3)> {
        let v = self.views.get(i)?;
        let xy = unproject(self.renderer.camera(), uv[0], uv[1])?;
        let d = (v.r_wc * Vec3::new(xy[0], xy[1], 1.0)).normalize();
        let hit = self.renderer.world().raycast(&v.o_w, &d, 1e5)?;
        Some((v.o_w + d * hit.t, hit.normal))
    }

    /// Raw pixel of world point `p_w` (on a surface with outward normal `n_w`) in frame `j`:
    /// `None` when outside the image's pixel-centre span, facing away or occluded.
    pub fn project_visible(&self, j: usize, p_w: &Vec3, n_w: &Vec3) -> Option<[f64; 2]> {
        let v = self.views.get(j)?;
        let to_cam = v.o_w - p_w;
        let dist = to_cam.norm();
        if n_w.dot(&to_cam) <= 1e-6 * dist {
            return None;
        }
        let cam = self.renderer.camera();
        let uv = project(cam, &(v.r_wc.transpose() * (p_w - v.o_w)))?;
        if !cam.in_image(uv[0], uv[1]) {
            return None;
        }
        let tol = 1e-3 + 1e-4 * dist;
        self.renderer
            .world()
            .line_of_sight(&v.o_w, p_w, tol)
            .then_some(uv)
    }

    /// True position in frame `j` of what raw pixel `uv` of frame `i` shows (`None`: sky,
    /// out of view, facing away or occluded in `j`).
    pub fn transfer(&self, i: usize, uv: [f64; 2], j: usize) -> Option<[f64; 2]> {
        let (p, n) = self.surface_point(i, uv)?;
        self.project_visible(j, &p, &n)
    }

    /// Depth map of frame `i` (camera-frame `z`, m, NaN for sky), row-major.
    pub fn depth_map(&self, i: usize) -> Option<Vec<f32>> {
        Some(self.renderer.depth(self.views.get(i)?))
    }
}
