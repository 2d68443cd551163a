//! World geometry and ray casting.
//!
//! The world is the ground plane `z = 0` plus axis-aligned boxes (buildings, walls, parked
//! vehicles), vertical cylinders (trunks, poles) and spheres (foliage). Every sensor sees the same
//! geometry: camera occlusion tests and LiDAR returns are both ray casts against it.
//!
//! Acceleration structure: a uniform 2-D grid over `(x, y)`; each cell lists the primitives whose
//! footprint overlaps it. A ray walks the cells in order (Amanatides-Woo DDA) and stops as soon
//! as the best hit lies before the exit of the current cell. Rays are also clipped at the height
//! of the tallest primitive (above it only the ground can be hit, and rays going up never do).

use povins_core::math::Vec3;

/// Smallest accepted ray parameter, m (avoids self-hits at the origin surface).
const T_EPS: f64 = 1e-6;

/// Geometric shape of a primitive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Axis-aligned box.
    Box {
        /// Minimum corner, m.
        min: Vec3,
        /// Maximum corner, m.
        max: Vec3,
    },
    /// Vertical (z-axis) cylinder with flat caps.
    Cylinder {
        /// Axis position, m.
        cx: f64,
        /// Axis position, m.
        cy: f64,
        /// Radius, m.
        r: f64,
        /// Bottom height, m.
        z0: f64,
        /// Top height, m.
        z1: f64,
    },
    /// Sphere.
    Sphere {
        /// Centre, m.
        c: Vec3,
        /// Radius, m.
        r: f64,
    },
}

/// Surface class (drives landmark density and LiDAR intensity).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Material {
    /// The ground plane.
    Ground,
    /// Building facades and walls.
    Building,
    /// Parked vehicles.
    Vehicle,
    /// Tree trunks.
    Trunk,
    /// Foliage.
    Foliage,
    /// Poles and posts.
    Pole,
}

impl Material {
    /// Diffuse reflectivity in `[0, 1]` (used for LiDAR intensity).
    pub fn reflectivity(self) -> f64 {
        match self {
            Material::Ground => 0.15,
            Material::Building => 0.45,
            Material::Vehicle => 0.7,
            Material::Trunk => 0.25,
            Material::Foliage => 0.35,
            Material::Pole => 0.6,
        }
    }
}

/// One solid object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Primitive {
    /// Geometry in `w`.
    pub shape: Shape,
    /// Surface class.
    pub material: Material,
}

/// A ray hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray, m.
    pub t: f64,
    /// Outward unit normal at the hit, in `w`.
    pub normal: Vec3,
    /// Index of the primitive hit; `None` for the ground.
    pub prim: Option<u32>,
}

impl Hit {
    /// Stable surface id: 0 for the ground, `1 + index` for primitives.
    pub fn surface_id(&self) -> u32 {
        self.prim.map_or(0, |i| i + 1)
    }
}

impl Shape {
    /// Nearest intersection with `t > T_EPS` along the unit ray `o + t d`.
    pub fn intersect(&self, o: &Vec3, d: &Vec3) -> Option<(f64, Vec3)> {
        match *self {
            Shape::Box { min, max } => {
                let mut t_near = f64::NEG_INFINITY;
                let mut t_far = f64::INFINITY;
                let mut axis = 0;
                let mut sign = 1.0;
                for k in 0..3 {
                    if d[k].abs() < 1e-15 {
                        if o[k] < min[k] || o[k] > max[k] {
                            return None;
                        }
                        continue;
                    }
                    let inv = 1.0 / d[k];
                    let (mut t0, mut t1) = ((min[k] - o[k]) * inv, (max[k] - o[k]) * inv);
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
                if t_near > t_far || t_near <= T_EPS {
                    return None;
                }
                let mut n = Vec3::zeros();
                n[axis] = sign;
                Some((t_near, n))
            }
            Shape::Cylinder { cx, cy, r, z0, z1 } => {
                let mut best: Option<(f64, Vec3)> = None;
                let (ox, oy) = (o.x - cx, o.y - cy);
                let a = d.x * d.x + d.y * d.y;
                if a > 1e-15 {
                    let b = 2.0 * (ox * d.x + oy * d.y);
                    let c = ox * ox + oy * oy - r * r;
                    let disc = b * b - 4.0 * a * c;
                    if disc >= 0.0 {
                        let t = (-b - libm::sqrt(disc)) / (2.0 * a);
                        let z = o.z + t * d.z;
                        if t > T_EPS && z >= z0 && z <= z1 {
                            let n = Vec3::new(ox + t * d.x, oy + t * d.y, 0.0) / r;
                            best = Some((t, n));
                        }
                    }
                }
                if d.z.abs() > 1e-15 {
                    for (zc, nz) in [(z1, 1.0), (z0, -1.0)] {
                        let t = (zc - o.z) / d.z;
                        // Only the outside of a cap counts (rays from above the top, below the bottom).
                        if t > T_EPS && (o.z - zc) * nz > 0.0 {
                            let (x, y) = (ox + t * d.x, oy + t * d.y);
                            if x * x + y * y <= r * r && best.is_none_or(|b| t < b.0) {
                                best = Some((t, Vec3::new(0.0, 0.0, nz)));
                            }
                        }
                    }
                }
                best
            }
            Shape::Sphere { c, r } => {
                let oc = o - c;
                let b = oc.dot(d);
                let cc = oc.norm_squared() - r * r;
                let disc = b * b - cc;
                if disc < 0.0 {
                    return None;
                }
                let t = -b - libm::sqrt(disc);
                if t <= T_EPS {
                    return None;
                }
                Some((t, (oc + d * t) / r))
            }
        }
    }

    /// Unsigned distance from `p` to the surface, m.
    pub fn surface_distance(&self, p: &Vec3) -> f64 {
        match *self {
            Shape::Box { min, max } => {
                let outside = Vec3::new(
                    (min.x - p.x).max(p.x - max.x).max(0.0),
                    (min.y - p.y).max(p.y - max.y).max(0.0),
                    (min.z - p.z).max(p.z - max.z).max(0.0),
                );
                let o = outside.norm();
                if o > 0.0 {
                    return o;
                }
                let mut inside = f64::INFINITY;
                for k in 0..3 {
                    inside = inside.min(p[k] - min[k]).min(max[k] - p[k]);
                }
                inside
            }
            Shape::Cylinder { cx, cy, r, z0, z1 } => {
                let dr = libm::hypot(p.x - cx, p.y - cy) - r;
                let dz = (z0 - p.z).max(p.z - z1);
                if dr > 0.0 && dz > 0.0 {
                    libm::hypot(dr, dz)
                } else if dr > 0.0 || dz > 0.0 {
                    dr.max(dz)
                } else {
                    (-dr).min(-dz)
                }
            }
            Shape::Sphere { c, r } => ((p - c).norm() - r).abs(),
        }
    }

    /// True when `p` is strictly inside the solid.
    pub fn contains(&self, p: &Vec3) -> bool {
        match *self {
            Shape::Box { min, max } => (0..3).all(|k| p[k] > min[k] && p[k] < max[k]),
            Shape::Cylinder { cx, cy, r, z0, z1 } => {
                p.z > z0 && p.z < z1 && libm::hypot(p.x - cx, p.y - cy) < r
            }
            Shape::Sphere { c, r } => (p - c).norm() < r,
        }
    }

    /// Footprint `(xmin, ymin, xmax, ymax)` and top height.
    pub fn footprint(&self) -> ([f64; 4], f64) {
        match *self {
            Shape::Box { min, max } => ([min.x, min.y, max.x, max.y], max.z),
            Shape::Cylinder { cx, cy, r, z1, .. } => ([cx - r, cy - r, cx + r, cy + r], z1),
            Shape::Sphere { c, r } => ([c.x - r, c.y - r, c.x + r, c.y + r], c.z + r),
        }
    }
}

/// Primitives plus the 2-D cell grid that accelerates ray casts.
#[derive(Debug, Clone)]
pub struct World {
    prims: Vec<Primitive>,
    x0: f64,
    y0: f64,
    cell_m: f64,
    nx: usize,
    ny: usize,
    /// CSR layout: primitives of cell `c` are `cell_items[cell_start[c]..cell_start[c + 1]]`.
    cell_start: Vec<u32>,
    cell_items: Vec<u32>,
    max_height: f64,
}

impl World {
    /// Builds the grid over `bounds = (xmin, ymin, xmax, ymax)` (grown to cover every primitive).
    pub fn new(prims: Vec<Primitive>, bounds: [f64; 4], cell_m: f64) -> Self {
        let mut b = bounds;
        let mut max_height: f64 = 0.0;
        for p in &prims {
            let (f, h) = p.shape.footprint();
            b = [
                b[0].min(f[0]),
                b[1].min(f[1]),
                b[2].max(f[2]),
                b[3].max(f[3]),
            ];
            max_height = max_height.max(h);
        }
        let cell_m = cell_m.max(0.5);
        let nx = (((b[2] - b[0]) / cell_m).ceil() as usize).max(1);
        let ny = (((b[3] - b[1]) / cell_m).ceil() as usize).max(1);
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); nx * ny];
        for (i, p) in prims.iter().enumerate() {
            let (f, _) = p.shape.footprint();
            let ix0 =
                (((f[0] - b[0]) / cell_m).floor() as isize).clamp(0, nx as isize - 1) as usize;
            let ix1 =
                (((f[2] - b[0]) / cell_m).floor() as isize).clamp(0, nx as isize - 1) as usize;
            let iy0 =
                (((f[1] - b[1]) / cell_m).floor() as isize).clamp(0, ny as isize - 1) as usize;
            let iy1 =
                (((f[3] - b[1]) / cell_m).floor() as isize).clamp(0, ny as isize - 1) as usize;
            for iy in iy0..=iy1 {
                for ix in ix0..=ix1 {
                    lists[iy * nx + ix].push(i as u32);
                }
            }
        }
        let mut cell_start = Vec::with_capacity(nx * ny + 1);
        let mut cell_items = Vec::new();
        cell_start.push(0);
        for l in &lists {
            cell_items.extend_from_slice(l);
            cell_start.push(cell_items.len() as u32);
        }
        World {
            prims,
            x0: b[0],
            y0: b[1],
            cell_m,
            nx,
            ny,
            cell_start,
            cell_items,
            max_height,
        }
    }

    /// The primitives.
    pub fn primitives(&self) -> &[Primitive] {
        &self.prims
    }

    /// Grid bounds `(xmin, ymin, xmax, ymax)`.
    pub fn bounds(&self) -> [f64; 4] {
        [
            self.x0,
            self.y0,
            self.x0 + self.nx as f64 * self.cell_m,
            self.y0 + self.ny as f64 * self.cell_m,
        ]
    }

    /// Material of a hit.
    pub fn material(&self, hit: &Hit) -> Material {
        hit.prim
            .and_then(|i| self.prims.get(i as usize))
            .map_or(Material::Ground, |p| p.material)
    }

    fn test_cell(&self, cell: usize, o: &Vec3, d: &Vec3, best: &mut Option<Hit>, best_t: &mut f64) {
        let (a, b) = (
            self.cell_start[cell] as usize,
            self.cell_start[cell + 1] as usize,
        );
        for &i in &self.cell_items[a..b] {
            if let Some((t, n)) = self.prims[i as usize].shape.intersect(o, d) {
                if t < *best_t {
                    *best_t = t;
                    *best = Some(Hit {
                        t,
                        normal: n,
                        prim: Some(i),
                    });
                }
            }
        }
    }

    /// Nearest hit of the unit ray `o + t d` with `t < t_max`.
    pub fn raycast(&self, o: &Vec3, d: &Vec3, t_max: f64) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut best_t = t_max;
        if d.z < 0.0 && o.z > 0.0 {
            let t = -o.z / d.z;
            if t < best_t {
                best_t = t;
                best = Some(Hit {
                    t,
                    normal: Vec3::z(),
                    prim: None,
                });
            }
        }
        // Above the tallest primitive only the ground can be hit.
        let mut t_lim = best_t;
        if d.z > 0.0 {
            if o.z >= self.max_height {
                return best;
            }
            t_lim = t_lim.min((self.max_height - o.z) / d.z);
        }
        // Clip the ray to the grid rectangle.
        let [xmin, ymin, xmax, ymax] = self.bounds();
        let mut t0: f64 = 0.0;
        let mut t1 = t_lim;
        for (oc, dc, lo, hi) in [(o.x, d.x, xmin, xmax), (o.y, d.y, ymin, ymax)] {
            if dc.abs() < 1e-15 {
                if oc < lo || oc > hi {
                    return best;
                }
            } else {
                let (mut a, mut b) = ((lo - oc) / dc, (hi - oc) / dc);
                if a > b {
                    core::mem::swap(&mut a, &mut b);
                }
                t0 = t0.max(a);
                t1 = t1.min(b);
            }
        }
        if t0 > t1 {
            return best;
        }
        let px = o.x + d.x * t0;
        let py = o.y + d.y * t0;
        let mut ix =
            (((px - self.x0) / self.cell_m).floor() as isize).clamp(0, self.nx as isize - 1);
        let mut iy =
            (((py - self.y0) / self.cell_m).floor() as isize).clamp(0, self.ny as isize - 1);
        let (sx, sy) = (
            if d.x >= 0.0 { 1 } else { -1 },
            if d.y >= 0.0 { 1 } else { -1 },
        );
        let next_edge = |i: isize, s: isize, org: f64, base: f64, dc: f64| -> (f64, f64) {
            if dc.abs() < 1e-15 {
                return (f64::INFINITY, f64::INFINITY);
            }
            let edge = base + (i + if s > 0 { 1 } else { 0 }) as f64 * self.cell_m;
            ((edge - org) / dc, self.cell_m / dc.abs())
        };
        let (mut tmx, tdx) = next_edge(ix, sx, o.x, self.x0, d.x);
        let (mut tmy, tdy) = next_edge(iy, sy, o.y, self.y0, d.y);
        loop {
            self.test_cell(
                iy as usize * self.nx + ix as usize,
                o,
                d,
                &mut best,
                &mut best_t,
            );
            let cell_exit = tmx.min(tmy);
            if best_t <= cell_exit || cell_exit >= t1 {
                break;
            }
            if tmx < tmy {
                ix += sx;
                tmx += tdx;
            } else {
                iy += sy;
                tmy += tdy;
            }
            if ix < 0 || iy < 0 || ix >= self.nx as isize || iy >= self.ny as isize {
                break;
            }
        }
        best
    }

    /// Same as [`World::raycast`] by testing every primitive (reference for tests).
    pub fn raycast_brute(&self, o: &Vec3, d: &Vec3, t_max: f64) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut best_t = t_max;
        if d.z < 0.0 && o.z > 0.0 {
            let t = -o.z / d.z;
            if t < best_t {
                best_t = t;
                best = Some(Hit {
                    t,
                    normal: Vec3::z(),
                    prim: None,
                });
            }
        }
        for (i, p) in self.prims.iter().enumerate() {
            if let Some((t, n)) = p.shape.intersect(o, d) {
                if t < best_t {
                    best_t = t;
                    best = Some(Hit {
                        t,
                        normal: n,
                        prim: Some(i as u32),
                    });
                }
            }
        }
        best
    }

    /// True when the straight segment from `from` to `to` is free up to `to` (the surface the
    /// target lies on does not count: hits within `tol_m` of the target are accepted).
    pub fn line_of_sight(&self, from: &Vec3, to: &Vec3, tol_m: f64) -> bool {
        let dv = to - from;
        let dist = dv.norm();
        if dist < 1e-9 {
            return true;
        }
        let d = dv / dist;
        self.raycast(from, &d, dist - tol_m).is_none()
    }

    /// True when `p` is inside some primitive (or below the ground).
    pub fn contains(&self, p: &Vec3) -> bool {
        if p.z < 0.0 {
            return true;
        }
        let [xmin, ymin, xmax, ymax] = self.bounds();
        if p.x < xmin || p.y < ymin || p.x >= xmax || p.y >= ymax {
            return false;
        }
        let ix = (((p.x - self.x0) / self.cell_m) as usize).min(self.nx - 1);
        let iy = (((p.y - self.y0) / self.cell_m) as usize).min(self.ny - 1);
        let c = iy * self.nx + ix;
        let (a, b) = (self.cell_start[c] as usize, self.cell_start[c + 1] as usize);
        self.cell_items[a..b]
            .iter()
            .any(|&i| self.prims[i as usize].shape.contains(p))
    }

    /// Unsigned distance from `p` to the nearest surface (ground included), m. Brute force.
    pub fn surface_distance(&self, p: &Vec3) -> f64 {
        self.prims
            .iter()
            .map(|q| q.shape.surface_distance(p))
            .fold(p.z.abs(), f64::min)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::rng::Rng;

    fn random_world(rng: &mut Rng) -> World {
        let mut prims = Vec::new();
        for _ in 0..60 {
            let c = Vec3::new(rng.range(-40.0, 40.0), rng.range(-40.0, 40.0), 0.0);
            let shape = match rng.below(3) {
                0 => {
                    let h = Vec3::new(
                        rng.range(0.5, 6.0),
                        rng.range(0.5, 6.0),
                        rng.range(1.0, 12.0),
                    );
                    Shape::Box {
                        min: Vec3::new(c.x - h.x, c.y - h.y, 0.0),
                        max: Vec3::new(c.x + h.x, c.y + h.y, h.z),
                    }
                }
                1 => Shape::Cylinder {
                    cx: c.x,
                    cy: c.y,
                    r: rng.range(0.1, 1.0),
                    z0: 0.0,
                    z1: rng.range(1.0, 8.0),
                },
                _ => Shape::Sphere {
                    c: Vec3::new(c.x, c.y, rng.range(1.0, 6.0)),
                    r: rng.range(0.5, 3.0),
                },
            };
            prims.push(Primitive {
                shape,
                material: Material::Building,
            });
        }
        World::new(prims, [-50.0, -50.0, 50.0, 50.0], 5.0)
    }

    #[test]
    fn grid_raycast_equals_brute_force() {
        let mut rng = Rng::new(11);
        let w = random_world(&mut rng);
        let mut hits = 0;
        for _ in 0..20_000 {
            let o = Vec3::new(
                rng.range(-60.0, 60.0),
                rng.range(-60.0, 60.0),
                rng.range(0.2, 15.0),
            );
            // Mostly horizontal rays so that many of them meet primitives.
            let u = rng.unit3();
            let d = Vec3::new(u.x, u.y, 0.3 * u.z).normalize();
            let a = w.raycast(&o, &d, 120.0);
            let b = w.raycast_brute(&o, &d, 120.0);
            match (a, b) {
                (Some(a), Some(b)) => {
                    hits += usize::from(a.prim.is_some());
                    assert!((a.t - b.t).abs() < 1e-9, "{a:?} vs {b:?}");
                    assert!((a.normal.norm() - 1.0).abs() < 1e-9);
                    let p = o + d * a.t;
                    assert!(w.surface_distance(&p) < 1e-6, "hit point off surface");
                }
                (None, None) => {}
                (a, b) => panic!("grid {a:?} vs brute {b:?} for o={o:?} d={d:?}"),
            }
        }
        assert!(hits > 2_000, "only {hits} primitive hits");
    }

    #[test]
    fn surface_distance_of_shapes() {
        let b = Shape::Box {
            min: Vec3::new(0.0, 0.0, 0.0),
            max: Vec3::new(2.0, 2.0, 2.0),
        };
        assert!((b.surface_distance(&Vec3::new(3.0, 1.0, 1.0)) - 1.0).abs() < 1e-12);
        assert!((b.surface_distance(&Vec3::new(1.0, 1.0, 1.5)) - 0.5).abs() < 1e-12);
        let c = Shape::Cylinder {
            cx: 0.0,
            cy: 0.0,
            r: 1.0,
            z0: 0.0,
            z1: 2.0,
        };
        assert!((c.surface_distance(&Vec3::new(2.0, 0.0, 1.0)) - 1.0).abs() < 1e-12);
        assert!((c.surface_distance(&Vec3::new(0.0, 0.0, 3.0)) - 1.0).abs() < 1e-12);
        assert!((c.surface_distance(&Vec3::new(4.0, 0.0, 6.0)) - 5.0).abs() < 1e-12);
        let s = Shape::Sphere {
            c: Vec3::new(0.0, 0.0, 5.0),
            r: 2.0,
        };
        assert!((s.surface_distance(&Vec3::new(0.0, 0.0, 5.5)) - 1.5).abs() < 1e-12);
    }

    #[test]
    fn occluded_point_is_not_in_sight() {
        let w = World::new(
            vec![Primitive {
                shape: Shape::Box {
                    min: Vec3::new(4.0, -1.0, 0.0),
                    max: Vec3::new(5.0, 1.0, 3.0),
                },
                material: Material::Building,
            }],
            [-10.0, -10.0, 10.0, 10.0],
            2.0,
        );
        let eye = Vec3::new(0.0, 0.0, 1.0);
        assert!(!w.line_of_sight(&eye, &Vec3::new(8.0, 0.0, 1.0), 0.01));
        assert!(w.line_of_sight(&eye, &Vec3::new(4.0, 0.0, 1.0), 0.01));
        assert!(w.line_of_sight(&eye, &Vec3::new(8.0, 3.0, 1.0), 0.01));
    }
}
