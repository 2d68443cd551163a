//! Procedural worlds along a carrier's path and the landmarks sampled on their surfaces.
//!
//! Objects are dropped at random arc-length positions beside the path (random side, random
//! lateral offset) and rejected when their footprint comes closer to the path than a clearance,
//! so the carrier never drives through anything. Landmarks are sampled uniformly on object
//! surfaces (area-proportional counts, per-material density) and on the ground in a band around
//! the path; each keeps its outward normal and the surface it lies on.

use super::rng::Rng;
use super::world::{Material, Primitive, Shape, World};
use povins_core::math::Vec3;

/// Placement rule for one object class, per 100 m of path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Mean number of objects per 100 m of path (both sides together).
    pub per_100m: f64,
    /// Lateral offset range of the object centre from the path, m.
    pub offset_m: (f64, f64),
    /// Minimum horizontal distance between the object's footprint and the path, m.
    pub clearance_m: f64,
}

/// Object classes and their size ranges for one kind of environment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneParams {
    /// Buildings: footprint side range and height range, m.
    pub buildings: Placement,
    /// Building footprint side, m.
    pub building_side_m: (f64, f64),
    /// Building height, m.
    pub building_height_m: (f64, f64),
    /// Low walls / fences.
    pub walls: Placement,
    /// Trees (trunk + foliage cluster).
    pub trees: Placement,
    /// Parked vehicles.
    pub cars: Placement,
    /// Poles / posts.
    pub poles: Placement,
    /// Half-width of the textured ground band around the path, m.
    pub ground_band_m: f64,
    /// Landmarks per m^2: (ground, building, vehicle, trunk, foliage, pole).
    pub density: [f64; 6],
    /// Grid cell size for ray casting and landmark lookup, m.
    pub cell_m: f64,
}

/// Landmarks with a spatial index over `(x, y)`.
#[derive(Debug, Clone)]
pub struct Landmarks {
    /// Positions in `w`, m.
    pub p_w: Vec<Vec3>,
    /// Outward unit normals in `w`.
    pub n_w: Vec<Vec3>,
    /// Surface ids (0 = ground, `1 + primitive index`).
    pub surface: Vec<u32>,
    x0: f64,
    y0: f64,
    cell_m: f64,
    nx: usize,
    ny: usize,
    cell_start: Vec<u32>,
    cell_items: Vec<u32>,
}

impl Landmarks {
    /// Indexes landmarks (equal-length vectors) on a grid of `cell_m` over `bounds`.
    pub fn new(
        p_w: Vec<Vec3>,
        n_w: Vec<Vec3>,
        surface: Vec<u32>,
        bounds: [f64; 4],
        cell_m: f64,
    ) -> Self {
        let nx = (((bounds[2] - bounds[0]) / cell_m).ceil() as usize).max(1);
        let ny = (((bounds[3] - bounds[1]) / cell_m).ceil() as usize).max(1);
        let cell_of = |p: &Vec3| {
            let ix =
                (((p.x - bounds[0]) / cell_m).floor() as isize).clamp(0, nx as isize - 1) as usize;
            let iy =
                (((p.y - bounds[1]) / cell_m).floor() as isize).clamp(0, ny as isize - 1) as usize;
            iy * nx + ix
        };
        let mut counts = vec![0u32; nx * ny + 1];
        for p in &p_w {
            counts[cell_of(p) + 1] += 1;
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let cell_start = counts.clone();
        let mut fill = counts;
        let mut cell_items = vec![0u32; p_w.len()];
        for (i, p) in p_w.iter().enumerate() {
            let c = cell_of(p);
            cell_items[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        Landmarks {
            p_w,
            n_w,
            surface,
            x0: bounds[0],
            y0: bounds[1],
            cell_m,
            nx,
            ny,
            cell_start,
            cell_items,
        }
    }

    /// Number of landmarks.
    pub fn len(&self) -> usize {
        self.p_w.len()
    }

    /// True when there are no landmarks.
    pub fn is_empty(&self) -> bool {
        self.p_w.is_empty()
    }

    /// Calls `f(index)` for every landmark in the grid cells overlapping the square of half-side
    /// `r` around `c` (a superset of the disc of radius `r`), in a fixed order.
    pub fn for_each_near(&self, c: &Vec3, r: f64, mut f: impl FnMut(usize)) {
        let cell = |v: f64, v0: f64, n: usize| {
            (((v - v0) / self.cell_m).floor() as isize).clamp(0, n as isize - 1) as usize
        };
        let (ix0, ix1) = (
            cell(c.x - r, self.x0, self.nx),
            cell(c.x + r, self.x0, self.nx),
        );
        let (iy0, iy1) = (
            cell(c.y - r, self.y0, self.ny),
            cell(c.y + r, self.y0, self.ny),
        );
        for iy in iy0..=iy1 {
            for ix in ix0..=ix1 {
                let k = iy * self.nx + ix;
                let (a, b) = (self.cell_start[k] as usize, self.cell_start[k + 1] as usize);
                for &i in &self.cell_items[a..b] {
                    f(i as usize);
                }
            }
        }
    }
}

/// Distance from a point to the path polyline samples (horizontal), m.
fn path_distance(path: &[Vec3], x: f64, y: f64) -> f64 {
    path.iter()
        .map(|p| libm::hypot(p.x - x, p.y - y))
        .fold(f64::INFINITY, f64::min)
}

/// Horizontal distance from the path to a footprint (conservative for round shapes).
fn footprint_clear(path: &[Vec3], shape: &Shape, clearance: f64) -> bool {
    let (f, _) = shape.footprint();
    match shape {
        Shape::Box { .. } => path.iter().all(|p| {
            let dx = (f[0] - p.x).max(p.x - f[2]).max(0.0);
            let dy = (f[1] - p.y).max(p.y - f[3]).max(0.0);
            libm::hypot(dx, dy) >= clearance
        }),
        _ => {
            let r = 0.5 * (f[2] - f[0]);
            path_distance(path, 0.5 * (f[0] + f[2]), 0.5 * (f[1] + f[3])) - r >= clearance
        }
    }
}

/// Random point beside the path: `(x, y, unit tangent)`.
fn beside_path(path: &[Vec3], rng: &mut Rng, offset: (f64, f64)) -> (f64, f64, Vec3) {
    let i = rng
        .below(path.len().saturating_sub(1))
        .min(path.len().saturating_sub(2));
    let d = path[i + 1] - path[i];
    let t = Vec3::new(d.x, d.y, 0.0).normalize();
    let n = Vec3::new(-t.y, t.x, 0.0);
    let side = if rng.chance(0.5) { 1.0 } else { -1.0 };
    let off = rng.range(offset.0, offset.1) * side;
    (path[i].x + n.x * off, path[i].y + n.y * off, t)
}

fn path_length(path: &[Vec3]) -> f64 {
    path.windows(2)
        .map(|w| libm::hypot(w[1].x - w[0].x, w[1].y - w[0].y))
        .sum()
}

/// Adds up to `count` objects made by `make`, keeping only those clear of the path.
fn place(
    out: &mut Vec<Primitive>,
    path: &[Vec3],
    rng: &mut Rng,
    rule: &Placement,
    mut make: impl FnMut(&mut Rng, f64, f64, Vec3) -> Vec<Primitive>,
) {
    let expected = rule.per_100m * path_length(path) / 100.0;
    let count = (expected + rng.uniform()) as usize;
    for _ in 0..count {
        // A few attempts per object so narrow corridors still get filled.
        for _ in 0..8 {
            let (x, y, t) = beside_path(path, rng, rule.offset_m);
            let parts = make(rng, x, y, t);
            if parts
                .iter()
                .all(|p| footprint_clear(path, &p.shape, rule.clearance_m))
            {
                out.extend(parts);
                break;
            }
        }
    }
}

fn boxed(min: Vec3, max: Vec3, material: Material) -> Primitive {
    Primitive {
        shape: Shape::Box { min, max },
        material,
    }
}

/// Builds the world around `path` (samples of the carrier position, >= 2, ~1 m apart).
pub fn build_world(path: &[Vec3], params: &SceneParams, rng: &mut Rng) -> World {
    let mut prims = Vec::new();
    place(&mut prims, path, rng, &params.buildings, |r, x, y, _| {
        let (a, b) = (
            r.range(params.building_side_m.0, params.building_side_m.1),
            r.range(params.building_side_m.0, params.building_side_m.1),
        );
        let h = r.range(params.building_height_m.0, params.building_height_m.1);
        vec![boxed(
            Vec3::new(x - 0.5 * a, y - 0.5 * b, 0.0),
            Vec3::new(x + 0.5 * a, y + 0.5 * b, h),
            Material::Building,
        )]
    });
    place(&mut prims, path, rng, &params.walls, |r, x, y, t| {
        // Walls run roughly along the path: pick the axis closest to the tangent.
        let len = r.range(4.0, 14.0);
        let (hx, hy) = if t.x.abs() > t.y.abs() {
            (0.5 * len, 0.15)
        } else {
            (0.15, 0.5 * len)
        };
        let h = r.range(1.0, 2.5);
        vec![boxed(
            Vec3::new(x - hx, y - hy, 0.0),
            Vec3::new(x + hx, y + hy, h),
            Material::Building,
        )]
    });
    place(&mut prims, path, rng, &params.trees, |r, x, y, _| {
        let trunk_h = r.range(2.0, 3.5);
        let mut v = vec![Primitive {
            shape: Shape::Cylinder {
                cx: x,
                cy: y,
                r: r.range(0.12, 0.3),
                z0: 0.0,
                z1: trunk_h + 0.5,
            },
            material: Material::Trunk,
        }];
        let n = 2 + r.below(3);
        for _ in 0..n {
            let rad = r.range(0.8, 1.6);
            v.push(Primitive {
                shape: Shape::Sphere {
                    c: Vec3::new(
                        x + r.range(-0.8, 0.8),
                        y + r.range(-0.8, 0.8),
                        trunk_h + rad * r.range(0.4, 1.0),
                    ),
                    r: rad,
                },
                material: Material::Foliage,
            });
        }
        v
    });
    place(&mut prims, path, rng, &params.cars, |r, x, y, t| {
        let (l, w) = (r.range(4.0, 4.9), r.range(1.7, 1.9));
        let (hx, hy) = if t.x.abs() > t.y.abs() {
            (0.5 * l, 0.5 * w)
        } else {
            (0.5 * w, 0.5 * l)
        };
        let h = r.range(1.4, 1.7);
        vec![boxed(
            Vec3::new(x - hx, y - hy, 0.0),
            Vec3::new(x + hx, y + hy, h),
            Material::Vehicle,
        )]
    });
    place(&mut prims, path, rng, &params.poles, |r, x, y, _| {
        vec![Primitive {
            shape: Shape::Cylinder {
                cx: x,
                cy: y,
                r: r.range(0.06, 0.12),
                z0: 0.0,
                z1: r.range(2.5, 6.0),
            },
            material: Material::Pole,
        }]
    });
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for p in path {
        b = [b[0].min(p.x), b[1].min(p.y), b[2].max(p.x), b[3].max(p.y)];
    }
    let m = params.buildings.offset_m.1 + params.building_side_m.1;
    World::new(
        prims,
        [b[0] - m, b[1] - m, b[2] + m, b[3] + m],
        params.cell_m,
    )
}

fn density_of(params: &SceneParams, m: Material) -> f64 {
    let i = match m {
        Material::Ground => 0,
        Material::Building => 1,
        Material::Vehicle => 2,
        Material::Trunk => 3,
        Material::Foliage => 4,
        Material::Pole => 5,
    };
    params.density[i]
}

/// Number of samples for an area: the integer part plus a Bernoulli remainder.
fn count_for(area: f64, density: f64, rng: &mut Rng) -> usize {
    let x = area * density;
    x as usize + usize::from(rng.chance(x - libm::floor(x)))
}

/// Samples landmarks on every primitive surface and on the ground band around the path.
pub fn sample_landmarks(
    world: &World,
    path: &[Vec3],
    params: &SceneParams,
    rng: &mut Rng,
) -> Landmarks {
    let (mut p_w, mut n_w, mut surf) = (Vec::new(), Vec::new(), Vec::new());
    let mut push = |p: Vec3, n: Vec3, s: u32| {
        // Points buried inside another solid can never be seen.
        if world.contains(&(p + n * 1e-3)) {
            return;
        }
        p_w.push(p);
        n_w.push(n);
        surf.push(s);
    };
    for (i, prim) in world.primitives().iter().enumerate() {
        let sid = i as u32 + 1;
        let dens = density_of(params, prim.material);
        match prim.shape {
            Shape::Box { min, max } => {
                let e = max - min;
                // Faces: +-x, +-y, top (bottom rests on the ground).
                let faces: [(usize, f64, f64); 5] = [
                    (0, -1.0, e.y * e.z),
                    (0, 1.0, e.y * e.z),
                    (1, -1.0, e.x * e.z),
                    (1, 1.0, e.x * e.z),
                    (2, 1.0, e.x * e.y),
                ];
                for (axis, sign, area) in faces {
                    let mut n = Vec3::zeros();
                    n[axis] = sign;
                    for _ in 0..count_for(area, dens, rng) {
                        let mut p = Vec3::new(
                            rng.range(min.x, max.x),
                            rng.range(min.y, max.y),
                            rng.range(min.z, max.z),
                        );
                        p[axis] = if sign > 0.0 { max[axis] } else { min[axis] };
                        push(p, n, sid);
                    }
                }
            }
            Shape::Cylinder { cx, cy, r, z0, z1 } => {
                let area = 2.0 * core::f64::consts::PI * r * (z1 - z0);
                for _ in 0..count_for(area, dens, rng) {
                    let a = rng.range(0.0, 2.0 * core::f64::consts::PI);
                    let n = Vec3::new(libm::cos(a), libm::sin(a), 0.0);
                    push(
                        Vec3::new(cx + r * n.x, cy + r * n.y, rng.range(z0, z1)),
                        n,
                        sid,
                    );
                }
            }
            Shape::Sphere { c, r } => {
                let area = 4.0 * core::f64::consts::PI * r * r;
                for _ in 0..count_for(area, dens, rng) {
                    let n = rng.unit3();
                    let p = c + n * r;
                    if p.z > 0.05 {
                        push(p, n, sid);
                    }
                }
            }
        }
    }
    // Ground texture: uniform in the band, accepted by distance to the path.
    let band = params.ground_band_m;
    let bounds = world.bounds();
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for p in path {
        b = [
            b[0].min(p.x - band),
            b[1].min(p.y - band),
            b[2].max(p.x + band),
            b[3].max(p.y + band),
        ];
    }
    let area = (b[2] - b[0]) * (b[3] - b[1]);
    // Coarse lookup grid of path samples to keep the band test cheap.
    let coarse = Landmarks::new(
        path.to_vec(),
        vec![Vec3::z(); path.len()],
        vec![0; path.len()],
        bounds,
        band.max(1.0),
    );
    for _ in 0..count_for(area, density_of(params, Material::Ground), rng) {
        let p = Vec3::new(rng.range(b[0], b[2]), rng.range(b[1], b[3]), 0.0);
        let mut near = false;
        coarse.for_each_near(&p, band, |i| {
            near |= libm::hypot(path[i].x - p.x, path[i].y - p.y) <= band;
        });
        if near {
            push(p, Vec3::z(), 0);
        }
    }
    Landmarks::new(p_w, n_w, surf, bounds, params.cell_m)
}
