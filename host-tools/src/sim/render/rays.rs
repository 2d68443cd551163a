//! Per-camera ray table: the exact viewing ray of every pixel centre (inverse of
//! [`camera::project`](crate::sim::camera::project), distortion included), its derivatives with
//! respect to the pixel coordinates (for sub-pixel samples and ray differentials), and one
//! bounding cone per tile of pixels (for culling primitives).

use crate::sim::camera::{distort_normalized, unproject};
use povins_core::camera::PinholeCamera;
use povins_core::math::Vec3;

/// Tile side, px.
pub const TILE: usize = 16;

/// A cone of directions in the camera frame: unit axis and half-angle (cosine, sine).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cone {
    /// Unit axis.
    pub axis: Vec3,
    /// Cosine of the half-angle (> 1 for an empty cone).
    pub cos: f64,
    /// Sine of the half-angle.
    pub sin: f64,
}

impl Cone {
    /// True when the sphere of radius `r` centred at `p` (camera frame, `dist = |p|`) meets the
    /// cone (conservative: exact for the infinite cone).
    #[inline]
    pub fn meets_sphere(&self, p: &Vec3, dist: f64, r: f64) -> bool {
        if self.cos > 1.0 {
            return false;
        }
        if dist <= r {
            return true;
        }
        let sin_s = r / dist;
        let cos_s = (1.0 - sin_s * sin_s).sqrt();
        let cos_e = self.cos * cos_s - self.sin * sin_s;
        p.dot(&self.axis) >= cos_e * dist
    }
}

/// Rays of every pixel centre of one camera.
#[derive(Debug, Clone)]
pub struct RayTable {
    /// Image width, px.
    pub width: usize,
    /// Image height, px.
    pub height: usize,
    /// Normalized `(x, y)` of the ray `(x, y, 1)` of each pixel centre (NaN: no ray).
    xy: Vec<[f64; 2]>,
    /// `[dx/du, dy/du, dx/dv, dy/dv]` at each pixel centre.
    jac: Vec<[f32; 4]>,
    /// Tiles per row.
    pub tiles_x: usize,
    /// Tile rows.
    pub tiles_y: usize,
    /// Bounding cone of each tile (pixels extended by half a pixel on every side).
    pub cones: Vec<Cone>,
    /// Bounding cone of the whole image.
    pub image_cone: Cone,
}

/// `d(x, y)/d(u, v)` at normalized `(x, y)`: the inverse of the distortion Jacobian, scaled.
fn inverse_jacobian(cam: &PinholeCamera, x: f64, y: f64) -> [f64; 4] {
    let h = 1e-6;
    let f0 = distort_normalized(cam, x, y);
    let fx = distort_normalized(cam, x + h, y);
    let fy = distort_normalized(cam, x, y + h);
    let (a, b) = ((fx[0] - f0[0]) / h, (fy[0] - f0[0]) / h);
    let (c, d) = ((fx[1] - f0[1]) / h, (fy[1] - f0[1]) / h);
    let det = a * d - b * c;
    // inverse [[d, -b], [-c, a]] / det times diag(1/fx, 1/fy).
    [
        d / det / cam.fx,
        -c / det / cam.fx,
        -b / det / cam.fy,
        a / det / cam.fy,
    ]
}

fn unit_ray(xy: [f64; 2]) -> Vec3 {
    Vec3::new(xy[0], xy[1], 1.0).normalize()
}

fn cone_of(rays: &[Vec3], margin: f64) -> Cone {
    if rays.is_empty() {
        return Cone {
            axis: Vec3::z(),
            cos: 2.0,
            sin: 0.0,
        };
    }
    let axis = rays.iter().fold(Vec3::zeros(), |a, r| a + r).normalize();
    let min_cos = rays
        .iter()
        .map(|r| r.dot(&axis))
        .fold(1.0f64, f64::min)
        .clamp(-1.0, 1.0);
    let ang = (min_cos.acos() + margin).min(core::f64::consts::PI);
    Cone {
        axis,
        cos: ang.cos(),
        sin: ang.sin(),
    }
}

impl RayTable {
    /// Builds the table (about 0.2 s for 752x480).
    pub fn new(cam: &PinholeCamera) -> Self {
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut xy = Vec::with_capacity(w * h);
        let mut jac = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                match unproject(cam, u as f64, v as f64) {
                    Some(p) => {
                        xy.push(p);
                        let j = inverse_jacobian(cam, p[0], p[1]);
                        jac.push([j[0] as f32, j[1] as f32, j[2] as f32, j[3] as f32]);
                    }
                    None => {
                        xy.push([f64::NAN; 2]);
                        jac.push([0.0; 4]);
                    }
                }
            }
        }
        let (tiles_x, tiles_y) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let mut t = RayTable {
            width: w,
            height: h,
            xy,
            jac,
            tiles_x,
            tiles_y,
            cones: Vec::with_capacity(tiles_x * tiles_y),
            image_cone: cone_of(&[], 0.0),
        };
        let mut all = Vec::new();
        for ty in 0..tiles_y {
            for tx in 0..tiles_x {
                let border = t.tile_border_rays(tx, ty);
                let c = cone_of(&border, 1e-4);
                all.extend(border);
                t.cones.push(c);
            }
        }
        t.image_cone = cone_of(&all, 1e-4);
        t
    }

    /// Unit rays through the outer edges of the border pixels of a tile.
    fn tile_border_rays(&self, tx: usize, ty: usize) -> Vec<Vec3> {
        let (c0, r0) = (tx * TILE, ty * TILE);
        let (c1, r1) = (
            (c0 + TILE).min(self.width) - 1,
            (r0 + TILE).min(self.height) - 1,
        );
        let mut out = Vec::new();
        for r in r0..=r1 {
            for c in c0..=c1 {
                if !(r == r0 || r == r1 || c == c0 || c == c1) {
                    continue;
                }
                let du = if c == c0 { -0.5 } else { 0.5 };
                let dv = if r == r0 { -0.5 } else { 0.5 };
                for (a, b) in [(du, dv), (-du, dv), (du, -dv)] {
                    if let Some(p) = self.sub_ray(c, r, a, b) {
                        out.push(unit_ray(p));
                    }
                }
            }
        }
        out
    }

    /// Normalized `(x, y)` of pixel `(col, row)`'s centre, `None` without a ray.
    #[inline]
    pub fn center(&self, col: usize, row: usize) -> Option<[f64; 2]> {
        let p = *self.xy.get(row * self.width + col)?;
        (!p[0].is_nan()).then_some(p)
    }

    /// `[dx/du, dy/du, dx/dv, dy/dv]` at pixel `(col, row)`.
    #[inline]
    pub fn jacobian(&self, col: usize, row: usize) -> [f64; 4] {
        let j = self.jac[row * self.width + col];
        [j[0] as f64, j[1] as f64, j[2] as f64, j[3] as f64]
    }

    /// Normalized `(x, y)` at `(col + du, row + dv)` by the first-order expansion around the
    /// pixel centre (error about 1e-3 px at half a pixel for EuRoC's lens).
    #[inline]
    pub fn sub_ray(&self, col: usize, row: usize, du: f64, dv: f64) -> Option<[f64; 2]> {
        let p = self.center(col, row)?;
        let j = self.jacobian(col, row);
        Some([p[0] + j[0] * du + j[2] * dv, p[1] + j[1] * du + j[3] * dv])
    }

    /// Tile index of a pixel.
    #[inline]
    pub fn tile_of(&self, col: usize, row: usize) -> usize {
        (row / TILE) * self.tiles_x + col / TILE
    }
}
