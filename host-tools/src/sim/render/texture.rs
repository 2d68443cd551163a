//! World-fixed procedural surface textures (albedo) and the sky.
//!
//! A texture is a function of the surface point and the surface id only, so every frame sees the
//! same surface. It is the sum of a per-surface base albedo, a few octaves of value noise
//! (quintic-interpolated lattice noise, fractal sum) and sharp-edged rectangular blobs
//! (windows, panels, stones, bark) that give Shi-Tomasi corners.
//!
//! Band limiting (what keeps a single sample per pixel from aliasing): every evaluation gets the
//! pixel footprint on the surface (the size of the pixel mapped onto the texture chart, from ray
//! differentials). Noise octaves whose wavelength spans fewer than [`FADE_PX`]`.1` pixels fade
//! out; blobs are box-filtered exactly over the footprint (a rectangle's box-filtered indicator
//! is the product of two 1-D interval overlaps), and fade to their mean when the footprint
//! covers many cells.
//!
//! Charts: planes use two world coordinates (ground `(x, y)`; a box face the two coordinates in
//! its plane), cylinder sides use `(r phi, z)` with every lattice wrapped to a whole number of
//! cells around the circumference (no seam), spheres (foliage) use 3-D noise and 3-D blobs.

use crate::sim::world::Material;

/// Noise octaves fade from full weight at `.1` pixels per wavelength to zero at `.0`.
pub const FADE_PX: (f64, f64) = (2.5, 5.0);

/// Splits into integer part (towards -inf) and fraction without calling `floor`.
#[inline]
fn floor_frac(x: f64) -> (i64, f64) {
    let i = x as i64;
    let i = if (i as f64) > x { i - 1 } else { i };
    (i, x - i as f64)
}

/// 64-bit mix of a lattice point (SplitMix64 finalizer).
#[inline]
fn hash(a: i64, b: i64, c: i64, seed: u64) -> u64 {
    let mut h = seed
        ^ (a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (c as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    h ^ (h >> 31)
}

/// Cheaper 64-bit mix of a 2-D cell (three multiplies).
#[inline]
fn cell_hash(a: i64, b: i64, seed: u64) -> u64 {
    let mut h = seed ^ (a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    h = (h ^ (h >> 29) ^ b as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h = (h ^ (h >> 32)).wrapping_mul(0x94D0_49BB_1331_11EB);
    h ^ (h >> 29)
}

/// Uniform in `[0, 1)` from 16 bits of `h` starting at `bit`.
#[inline]
fn unit(h: u64, bit: u32) -> f64 {
    ((h >> bit) & 0xFFFF) as i64 as f64 * (1.0 / 65536.0)
}

#[inline]
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// SplitMix64 step, usable in constant evaluation.
const fn splitmix(state: u64) -> (u64, u64) {
    let s = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = s;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (s, z ^ (z >> 31))
}

/// Permutation of 0..=255 (Fisher-Yates with SplitMix64 from a fixed seed), repeated twice.
const fn make_perm() -> [u8; 512] {
    let mut p = [0u8; 256];
    let mut i = 0;
    while i < 256 {
        p[i] = i as u8;
        i += 1;
    }
    let mut state = 0x5EED_7E57u64;
    let mut i = 255;
    while i > 0 {
        let (s, r) = splitmix(state);
        state = s;
        let j = (r % (i as u64 + 1)) as usize;
        let t = p[i];
        p[i] = p[j];
        p[j] = t;
        i -= 1;
    }
    let mut out = [0u8; 512];
    let mut k = 0;
    while k < 512 {
        out[k] = p[k & 255];
        k += 1;
    }
    out
}

/// Lattice values, uniform in `[-1, 1)` (53-bit SplitMix64 draws from a fixed seed).
const fn make_values() -> [f64; 256] {
    let mut v = [0.0; 256];
    let mut state = 0x07A1_00E5u64;
    let mut i = 0;
    while i < 256 {
        let (s, r) = splitmix(state);
        state = s;
        v[i] = (r >> 11) as f64 * (2.0 / (1u64 << 53) as f64) - 1.0;
        i += 1;
    }
    v
}

static PERM: [u8; 512] = make_perm();
static VALUES: [f64; 256] = make_values();

#[inline]
fn perm() -> &'static [u8; 512] {
    &PERM
}

#[inline]
fn values() -> &'static [f64; 256] {
    &VALUES
}

/// Lattice offsets that make octave/surface `seed` an independent noise (period 256 cells).
#[inline]
fn offsets(seed: u64) -> [i64; 3] {
    let h = (seed ^ (seed >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    [
        ((h >> 40) & 255) as i64,
        ((h >> 48) & 255) as i64,
        (h >> 56) as i64,
    ]
}

#[inline]
fn wrap(i: i64, period: i64) -> i64 {
    if period > 0 {
        i.rem_euclid(period)
    } else {
        i
    }
}

/// 2-D value noise in `[-1, 1]`, lattice period `period` cells along x (0 = none).
fn noise2(x: f64, y: f64, seed: u64, period: i64) -> f64 {
    let (p, v, o) = (perm(), values(), offsets(seed));
    let (ix, fx) = floor_frac(x);
    let (iy, fy) = floor_frac(y);
    let i0 = (wrap(ix, period) + o[0]) as usize;
    let i1 = (wrap(ix + 1, period) + o[0]) as usize;
    let j0 = (iy + o[1]) as usize;
    let (pa, pb) = (p[i0 & 255] as usize, p[i1 & 255] as usize);
    let at = |pi: usize, j: usize| v[p[(pi + (j & 255)) & 511] as usize];
    let (sx, sy) = (fade(fx), fade(fy));
    let a = at(pa, j0);
    let b = at(pb, j0);
    let c = at(pa, j0.wrapping_add(1));
    let d = at(pb, j0.wrapping_add(1));
    let top = a + (b - a) * sx;
    let bot = c + (d - c) * sx;
    top + (bot - top) * sy
}

/// 3-D value noise in `[-1, 1]`.
fn noise3(q: [f64; 3], seed: u64) -> f64 {
    let (p, v, o) = (perm(), values(), offsets(seed));
    let (ix, fx) = floor_frac(q[0]);
    let (iy, fy) = floor_frac(q[1]);
    let (iz, fz) = floor_frac(q[2]);
    let (sx, sy, sz) = (fade(fx), fade(fy), fade(fz));
    let at = |i: i64, j: i64, k: i64| {
        let a = p[((i + o[0]) & 255) as usize] as i64;
        let b = p[((a + j + o[1]) & 255) as usize] as i64;
        v[p[((b + k + o[2]) & 255) as usize] as usize]
    };
    let mut r = [0.0; 2];
    for (k, rk) in r.iter_mut().enumerate() {
        let z = iz + k as i64;
        let a = at(ix, iy, z);
        let b = at(ix + 1, iy, z);
        let c = at(ix, iy + 1, z);
        let d = at(ix + 1, iy + 1, z);
        let top = a + (b - a) * sx;
        let bot = c + (d - c) * sx;
        *rk = top + (bot - top) * sy;
    }
    r[0] + (r[1] - r[0]) * sz
}

/// Weight of an octave spanning `q` pixel footprints per wavelength.
#[inline]
fn octave_weight(q: f64) -> f64 {
    ((q - FADE_PX.0) * (1.0 / (FADE_PX.1 - FADE_PX.0))).clamp(0.0, 1.0)
}

/// Fractal value noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fbm {
    /// Wavelength of the coarsest octave, m.
    pub lambda0: f64,
    /// Amplitude of the coarsest octave (albedo units).
    pub amp: f64,
    /// Amplitude ratio between successive octaves (wavelength halves).
    pub gain: f64,
    /// Number of octaves.
    pub octaves: u32,
}

/// Sharp-edged axis-aligned rectangles, at most one per lattice cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blobs {
    /// Cell size along the chart's s and t axes, m.
    pub cell: [f64; 2],
    /// Probability that a cell holds a rectangle.
    pub p: f64,
    /// Rectangle size range as a fraction of the cell, along s and t.
    pub size: [(f64, f64); 2],
    /// Albedo change inside a rectangle, range.
    pub contrast: (f64, f64),
    /// `1 / cell` (kept so the hot path does not divide).
    pub inv_cell: [f64; 2],
}

/// A blob layer of rectangles.
pub const fn rects(cell: [f64; 2], p: f64, size: [(f64, f64); 2], contrast: (f64, f64)) -> Blobs {
    Blobs {
        cell,
        p,
        size,
        contrast,
        inv_cell: [1.0 / cell[0], 1.0 / cell[1]],
    }
}

/// The texture of one material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaterialTexture {
    /// Mean albedo.
    pub mean: f64,
    /// Per-surface random change of the mean, +-.
    pub jitter: f64,
    /// Noise.
    pub fbm: Fbm,
    /// Blob layers, coarse (windows, panels) to fine (stones, stains, bark).
    pub blobs: [Blobs; 3],
}

const fn fbm(lambda0: f64, amp: f64, octaves: u32) -> Fbm {
    Fbm {
        lambda0,
        amp,
        gain: 0.8,
        octaves,
    }
}

const fn sq(cell: f64, p: f64, size: (f64, f64), c: f64) -> Blobs {
    rects([cell, cell], p, [size, size], (-c, c))
}

/// The texture of a material.
pub fn material_texture(m: Material) -> &'static MaterialTexture {
    match m {
        Material::Ground => &GROUND,
        Material::Building => &BUILDING,
        Material::Vehicle => &VEHICLE,
        Material::Trunk => &TRUNK,
        Material::Foliage => &FOLIAGE,
        Material::Pole => &POLE,
    }
}

const GROUND: MaterialTexture = MaterialTexture {
    mean: 0.42,
    jitter: 0.0,
    fbm: fbm(3.0, 0.09, 7),
    blobs: [
        sq(2.0, 0.5, (0.3, 0.8), 0.1),
        sq(0.35, 0.45, (0.2, 0.6), 0.2),
        sq(0.08, 0.4, (0.25, 0.7), 0.12),
    ],
};

const BUILDING: MaterialTexture = MaterialTexture {
    mean: 0.6,
    jitter: 0.12,
    fbm: fbm(2.0, 0.07, 6),
    blobs: [
        rects([2.6, 3.0], 0.75, [(0.35, 0.6), (0.4, 0.6)], (-0.35, 0.15)),
        rects([0.45, 0.3], 0.35, [(0.3, 0.8), (0.3, 0.7)], (-0.15, 0.15)),
        sq(0.1, 0.35, (0.3, 0.7), 0.1),
    ],
};

const VEHICLE: MaterialTexture = MaterialTexture {
    mean: 0.5,
    jitter: 0.3,
    fbm: fbm(2.0, 0.04, 7),
    blobs: [
        rects([1.2, 0.7], 0.6, [(0.4, 0.8), (0.3, 0.6)], (-0.3, 0.2)),
        sq(0.3, 0.3, (0.2, 0.6), 0.15),
        sq(0.08, 0.3, (0.3, 0.7), 0.08),
    ],
};

const TRUNK: MaterialTexture = MaterialTexture {
    mean: 0.32,
    jitter: 0.05,
    fbm: fbm(1.0, 0.08, 7),
    blobs: [
        rects([0.25, 0.6], 0.5, [(0.2, 0.5), (0.3, 0.9)], (-0.15, 0.15)),
        rects([0.06, 0.12], 0.5, [(0.2, 0.6), (0.3, 0.9)], (-0.12, 0.12)),
        sq(0.03, 0.3, (0.3, 0.7), 0.06),
    ],
};

const FOLIAGE: MaterialTexture = MaterialTexture {
    mean: 0.3,
    jitter: 0.06,
    fbm: fbm(1.2, 0.08, 7),
    blobs: [
        sq(0.5, 0.5, (0.3, 0.7), 0.16),
        sq(0.16, 0.5, (0.3, 0.7), 0.12),
        sq(0.05, 0.4, (0.3, 0.7), 0.08),
    ],
};

const POLE: MaterialTexture = MaterialTexture {
    mean: 0.55,
    jitter: 0.1,
    fbm: fbm(1.0, 0.04, 6),
    blobs: [
        rects([1.0, 0.8], 0.5, [(1.0, 1.0), (0.2, 0.5)], (-0.3, 0.25)),
        sq(0.1, 0.3, (0.3, 0.7), 0.1),
        sq(0.03, 0.3, (0.3, 0.7), 0.06),
    ],
};

/// Where and how wide a texture is evaluated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Chart {
    /// Planar or cylindrical chart: coordinates `(s, t)`, footprint along each, m, and the
    /// period of `s` (the circumference of a cylinder; 0 = none).
    Plane {
        /// Coordinates, m.
        st: [f64; 2],
        /// Footprint along s and t, m.
        fp: [f64; 2],
        /// Period of s, m (0 = not periodic).
        period: f64,
    },
    /// 3-D point with an isotropic footprint, m.
    Solid {
        /// Point, m.
        p: [f64; 3],
        /// Footprint, m.
        fp: f64,
    },
}

/// Box-filtered overlap of `[a, b]` with `[x - h, x + h]`, divided by `2 h` (`inv_f = 1/(2h)`).
#[inline]
fn overlap(x: f64, h: f64, inv_f: f64, a: f64, b: f64) -> f64 {
    ((x + h).min(b) - (x - h).max(a)).max(0.0) * inv_f
}

/// Mean albedo change of a blob layer (the limit for large footprints).
fn blob_mean(b: &Blobs, dims: usize) -> f64 {
    let m = |r: (f64, f64)| 0.5 * (r.0 + r.1);
    let area = m(b.size[0]) * m(b.size[1]) * if dims == 3 { m(b.size[1]) } else { 1.0 };
    b.p * area * 0.5 * (b.contrast.0 + b.contrast.1)
}

/// One rectangle of cell `(i, j)` (unwrapped index `i` for the position, wrapped `iw` for the
/// hash): `Some(([s0, s1], [t0, t1], contrast))`.
#[inline]
fn blob_rect(b: &Blobs, cs: f64, i: i64, iw: i64, j: i64, seed: u64) -> Option<([f64; 4], f64)> {
    let h = cell_hash(iw, j, seed);
    if unit(h, 0) >= b.p {
        return None;
    }
    let h2 = h.rotate_left(29).wrapping_mul(0x94D0_49BB_1331_11EB);
    let ws = cs * (b.size[0].0 + (b.size[0].1 - b.size[0].0) * unit(h, 16));
    let wt = b.cell[1] * (b.size[1].0 + (b.size[1].1 - b.size[1].0) * unit(h, 32));
    let s0 = i as f64 * cs + (cs - ws) * unit(h, 48);
    let t0 = j as f64 * b.cell[1] + (b.cell[1] - wt) * unit(h2, 0);
    let c = b.contrast.0 + (b.contrast.1 - b.contrast.0) * unit(h2, 16);
    Some(([s0, s0 + ws, t0, t0 + wt], c))
}

/// Box-filtered 2-D blob layer; `inv_fp` are the reciprocal footprints.
fn blobs2(b: &Blobs, st: [f64; 2], fp: [f64; 2], inv_fp: [f64; 2], period: f64, seed: u64) -> f64 {
    let (n, cs, inv_cs) = if period > 0.0 {
        let n = (period * b.inv_cell[0]).round().max(1.0);
        (n as i64, period / n, n / period)
    } else {
        (0, b.cell[0], b.inv_cell[0])
    };
    let inv_ct = b.inv_cell[1];
    // Half footprints in cells; beyond 3 cells the layer is replaced by its mean.
    let (hs, ht) = (0.5 * fp[0] * inv_cs, 0.5 * fp[1] * inv_ct);
    let span = 2.0 * hs.max(ht);
    if span >= 3.0 {
        return blob_mean(b, 2);
    }
    let (us, ut) = (st[0] * inv_cs, st[1] * inv_ct);
    let (i, fu) = floor_frac(us);
    let (j, fv) = floor_frac(ut);
    // Usual case: the footprint lies inside one cell.
    let (i0, i1) = if fu >= hs && fu + hs < 1.0 {
        (i, i)
    } else {
        (floor_frac(us - hs).0, floor_frac(us + hs).0)
    };
    let (j0, j1) = if fv >= ht && fv + ht < 1.0 {
        (j, j)
    } else {
        (floor_frac(ut - ht).0, floor_frac(ut + ht).0)
    };
    let (hfs, hft) = (0.5 * fp[0], 0.5 * fp[1]);
    let mut acc = 0.0;
    for j in j0..=j1 {
        for i in i0..=i1 {
            if let Some((r, c)) = blob_rect(b, cs, i, wrap(i, n), j, seed) {
                acc += c
                    * overlap(st[0], hfs, inv_fp[0], r[0], r[1])
                    * overlap(st[1], hft, inv_fp[1], r[2], r[3]);
            }
        }
    }
    if span <= 2.0 {
        return acc;
    }
    // Between 2 and 3 cells the exact value blends into the mean (no pop with distance).
    acc + (blob_mean(b, 2) - acc) * (span - 2.0)
}

/// Box-filtered 3-D blob layer (cubic cells of size `cell[0]`).
fn blobs3(b: &Blobs, p: [f64; 3], fp: f64, seed: u64) -> f64 {
    let c = b.cell[0];
    let f = fp.max(1e-9);
    let span = f / c;
    let mean = blob_mean(b, 3);
    if span >= 2.0 {
        return mean;
    }
    let range = |x: f64| {
        (
            floor_frac((x - 0.5 * f) / c).0,
            floor_frac((x + 0.5 * f) / c).0,
        )
    };
    let (ri, rj, rk) = (range(p[0]), range(p[1]), range(p[2]));
    let mut acc = 0.0;
    for k in rk.0..=rk.1 {
        for j in rj.0..=rj.1 {
            for i in ri.0..=ri.1 {
                let h = hash(i, j, k, seed);
                if unit(h, 0) >= b.p {
                    continue;
                }
                let h2 = hash(i, j, k, seed ^ 0xA5A5);
                let mut cov = 1.0;
                for (axis, (idx, x)) in [(i, p[0]), (j, p[1]), (k, p[2])].into_iter().enumerate() {
                    let r = b.size[axis.min(1)];
                    let bit = 16 * axis as u32;
                    let w = c * (r.0 + (r.1 - r.0) * unit(h, bit + 16));
                    let a = idx as f64 * c + (c - w) * unit(h2, bit + 16);
                    cov *= overlap(x, 0.5 * f, 1.0 / f, a, a + w);
                }
                acc += cov * (b.contrast.0 + (b.contrast.1 - b.contrast.0) * unit(h2, 0));
            }
        }
    }
    let w = (span - 1.0).clamp(0.0, 1.0);
    acc + (mean - acc) * w
}

/// Fractal noise on a 2-D chart (isotropic fade with the larger footprint).
fn fbm2(f: &Fbm, st: [f64; 2], fp: f64, period: f64, seed: u64) -> f64 {
    let inv_fp = 1.0 / fp.max(1e-12);
    let (mut amp, mut lambda, mut inv_l, mut sum) = (f.amp, f.lambda0, 1.0 / f.lambda0, 0.0);
    for o in 0..f.octaves {
        let w = octave_weight(lambda * inv_fp);
        if w <= 0.0 {
            break;
        }
        let s = if period > 0.0 {
            let n = (period * inv_l).round().max(1.0);
            (st[0] * n / period, n as i64)
        } else {
            (st[0] * inv_l, 0)
        };
        sum += w * amp * noise2(s.0, st[1] * inv_l, seed.wrapping_add(o as u64), s.1);
        amp *= f.gain;
        lambda *= 0.5;
        inv_l *= 2.0;
    }
    sum
}

fn fbm3(f: &Fbm, p: [f64; 3], fp: f64, seed: u64) -> f64 {
    let inv_fp = 1.0 / fp.max(1e-12);
    let (mut amp, mut lambda, mut inv_l, mut sum) = (f.amp, f.lambda0, 1.0 / f.lambda0, 0.0);
    for o in 0..f.octaves {
        let w = octave_weight(lambda * inv_fp);
        if w <= 0.0 {
            break;
        }
        let q = [p[0] * inv_l, p[1] * inv_l, p[2] * inv_l];
        sum += w * amp * noise3(q, seed.wrapping_add(o as u64));
        amp *= f.gain;
        lambda *= 0.5;
        inv_l *= 2.0;
    }
    sum
}

/// Albedo in `[0.02, 0.98]` of surface `surface_id` made of `m`, at `chart`.
pub fn albedo(m: Material, surface_id: u32, chart: &Chart) -> f64 {
    let tex = material_texture(m);
    let seed = hash(i64::from(surface_id), 0x7E57, 1, 0x0123_4567_89AB_CDEF);
    let base = tex.mean + tex.jitter * (2.0 * unit(seed, 0) - 1.0);
    let v = match *chart {
        Chart::Plane { st, fp, period } => {
            let iso = fp[0].max(fp[1]);
            let mut v = base + fbm2(&tex.fbm, st, iso, period, seed);
            let inv_fp = [1.0 / fp[0].max(1e-9), 1.0 / fp[1].max(1e-9)];
            let fp = [fp[0].max(1e-9), fp[1].max(1e-9)];
            for (k, b) in tex.blobs.iter().enumerate() {
                v += blobs2(b, st, fp, inv_fp, period, seed ^ (0xC0A5 + k as u64));
            }
            v
        }
        Chart::Solid { p, fp } => {
            let mut v = base + fbm3(&tex.fbm, p, fp, seed);
            for (k, b) in tex.blobs.iter().enumerate() {
                v += blobs3(b, p, fp, seed ^ (0xC0A5 + k as u64));
            }
            v
        }
    };
    v.clamp(0.02, 0.98)
}

/// Sky radiance for a unit world direction: brighter towards the horizon.
pub fn sky(d: &povins_core::math::Vec3) -> f64 {
    let e = d.z.clamp(0.0, 1.0);
    0.92 - 0.3 * e * (2.0 - e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_continuous_and_periodic_when_asked() {
        for k in 0..200 {
            let x = k as f64 * 0.173 - 17.0;
            let a = noise2(x, 0.3, 5, 0);
            let b = noise2(x + 1e-7, 0.3, 5, 0);
            assert!((a - b).abs() < 1e-5 && a.abs() <= 1.0);
            // Period 7: x and x + 7 agree.
            assert!((noise2(x, 1.7, 9, 7) - noise2(x + 7.0, 1.7, 9, 7)).abs() < 1e-12);
        }
    }

    #[test]
    fn blobs_are_box_filtered() {
        // The filtered value is the average of finely point-sampled values over the footprint.
        let b = material_texture(Material::Building).blobs[0];
        let fp = [0.4, 0.25];
        for k in 0..50 {
            let st = [k as f64 * 0.37 - 5.0, k as f64 * 0.21 + 1.0];
            let exact = blobs2(&b, st, fp, [1.0 / fp[0], 1.0 / fp[1]], 0.0, 3);
            let n = 64;
            let mut acc = 0.0;
            for a in 0..n {
                for c in 0..n {
                    let s = st[0] + fp[0] * ((a as f64 + 0.5) / n as f64 - 0.5);
                    let t = st[1] + fp[1] * ((c as f64 + 0.5) / n as f64 - 0.5);
                    acc += blobs2(&b, [s, t], [1e-9, 1e-9], [1e9, 1e9], 0.0, 3);
                }
            }
            let mean = acc / (n * n) as f64;
            assert!((exact - mean).abs() < 0.01, "{exact} vs {mean}");
        }
    }
}
