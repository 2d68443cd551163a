//! Per-frame visibility: primitives culled against each tile's cone, and the ray tracer that
//! walks a tile's list in order of distance.

use super::rays::RayTable;
use crate::sim::world::{Hit, Shape, World};
use povins_core::math::{Mat3, Vec3};

/// A camera pose: origin and orientation in `w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Camera centre in `w`, m.
    pub o_w: Vec3,
    /// Rotation camera -> world.
    pub r_wc: Mat3,
}

/// Bounding sphere of a shape: centre and radius.
pub fn bounding_sphere(s: &Shape) -> (Vec3, f64) {
    match *s {
        Shape::Box { min, max } => ((min + max) * 0.5, (max - min).norm() * 0.5),
        Shape::Cylinder { cx, cy, r, z0, z1 } => (
            Vec3::new(cx, cy, 0.5 * (z0 + z1)),
            (r * r + 0.25 * (z1 - z0) * (z1 - z0)).sqrt(),
        ),
        Shape::Sphere { c, r } => (c, r),
    }
}

/// Surface key of a hit: 0 for the sky, else one value per primitive face (box faces, cylinder
/// side and caps, sphere) and for the ground. Pixels whose neighbours have another key lie on a
/// geometric or shading edge.
pub fn surface_key(hit: Option<&Hit>) -> u32 {
    let Some(h) = hit else { return 0 };
    let face = if h.normal.x.abs() > 0.5 {
        1 + u32::from(h.normal.x > 0.0)
    } else if h.normal.y.abs() > 0.5 {
        3 + u32::from(h.normal.y > 0.0)
    } else if h.normal.z.abs() > 0.5 {
        5 + u32::from(h.normal.z > 0.0)
    } else {
        0
    };
    (h.surface_id() + 1) * 8 + face
}

/// Primitives that may be visible in each tile, nearest first.
pub struct Visible {
    start: Vec<u32>,
    items: Vec<u32>,
    /// Distance from the camera to each primitive's bounding sphere (indexed by primitive).
    near: Vec<f64>,
}

impl Visible {
    /// Culls the world's primitives for a view.
    pub fn new(world: &World, bounds: &[(Vec3, f64)], rays: &RayTable, view: &View) -> Self {
        Self::with_margin(world, bounds, rays, view, 0.0, 0.0)
    }

    /// Culls for every view within `dtheta_rad` of `view`'s rotation and `dpos_m` of its origin
    /// (a rolling shutter's rows): each bounding sphere grows by `dtheta dist + dpos`, which
    /// covers a point seen from such a view (`asin(r / d) + dtheta <= asin((r + dtheta d) / d)`).
    pub fn with_margin(
        world: &World,
        bounds: &[(Vec3, f64)],
        rays: &RayTable,
        view: &View,
        dtheta_rad: f64,
        dpos_m: f64,
    ) -> Self {
        let r_cw = view.r_wc.transpose();
        let mut near = vec![f64::INFINITY; bounds.len()];
        let mut cand: Vec<(u32, Vec3, f64, f64)> = Vec::new();
        for (k, &(c, r)) in bounds.iter().enumerate() {
            let p = r_cw * (c - view.o_w);
            let dist = p.norm();
            let r = r + dtheta_rad * dist + dpos_m;
            if rays.image_cone.meets_sphere(&p, dist, r) {
                near[k] = (dist - r).max(0.0);
                cand.push((k as u32, p, dist, r));
            }
        }
        cand.sort_by(|a, b| {
            near[a.0 as usize]
                .total_cmp(&near[b.0 as usize])
                .then(a.0.cmp(&b.0))
        });
        let mut start = Vec::with_capacity(rays.cones.len() + 1);
        let mut items = Vec::new();
        start.push(0);
        for cone in &rays.cones {
            for &(k, p, dist, r) in &cand {
                if cone.meets_sphere(&p, dist, r) {
                    items.push(k);
                }
            }
            start.push(items.len() as u32);
        }
        debug_assert_eq!(world.primitives().len(), bounds.len());
        Visible { start, items, near }
    }

    /// Nearest hit of the unit world ray `o + t d` among the tile's primitives and the ground.
    #[inline]
    pub fn trace(&self, world: &World, tile: usize, o: &Vec3, d: &Vec3) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut best_t = f64::INFINITY;
        if d.z < 0.0 && o.z > 0.0 {
            best_t = -o.z / d.z;
            best = Some(Hit {
                t: best_t,
                normal: Vec3::z(),
                prim: None,
            });
        }
        let prims = world.primitives();
        let inv = Vec3::new(1.0 / d.x, 1.0 / d.y, 1.0 / d.z);
        let (a, b) = (self.start[tile] as usize, self.start[tile + 1] as usize);
        for &k in &self.items[a..b] {
            if self.near[k as usize] >= best_t {
                break;
            }
            let shape = &prims[k as usize].shape;
            let hit = match shape {
                Shape::Box { min, max } => box_hit(min, max, o, &inv),
                _ => shape.intersect(o, d),
            };
            if let Some((t, n)) = hit {
                if t < best_t {
                    best_t = t;
                    best = Some(Hit {
                        t,
                        normal: n,
                        prim: Some(k),
                    });
                }
            }
        }
        best
    }
}

/// Slab test with the ray's inverse direction (same result as [`Shape::intersect`] for boxes).
#[inline]
fn box_hit(min: &Vec3, max: &Vec3, o: &Vec3, inv: &Vec3) -> Option<(f64, Vec3)> {
    let (mut t_near, mut t_far) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut axis, mut sign) = (0, 1.0);
    for k in 0..3 {
        let (mut t0, mut t1) = ((min[k] - o[k]) * inv[k], (max[k] - o[k]) * inv[k]);
        let mut s = -1.0;
        if t0 > t1 {
            core::mem::swap(&mut t0, &mut t1);
            s = 1.0;
        }
        if t0 > t_near {
            t_near = t0;
            axis = k;
            sign = s;
        }
        t_far = t_far.min(t1);
    }
    if t_near > t_far || t_near <= 1e-6 {
        return None;
    }
    let mut n = Vec3::zeros();
    n[axis] = sign;
    Some((t_near, n))
}
