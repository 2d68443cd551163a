//! Helpers shared by the vision test crates: deterministic PRNG, perturbations (numerical
//! differentiation is `numdiff`'s).
#![allow(dead_code)]

use nalgebra::SMatrix;
use povins_core::camera::{CameraExtrinsic, Vec2};
use povins_core::factors::KeyframePose;
use povins_core::math::{quat_exp, Quat, Vec3};

/// SplitMix64 + Box–Muller: deterministic normal samples.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in (0, 1).
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform();
        let u2 = self.uniform();
        libm::sqrt(-2.0 * libm::log(u1)) * libm::cos(2.0 * core::f64::consts::PI * u2)
    }
    pub fn vec3(&mut self, s: f64) -> Vec3 {
        Vec3::new(self.range(-s, s), self.range(-s, s), self.range(-s, s))
    }
}

/// Right-perturbs a keyframe pose by `d = [dp, dtheta]`.
pub fn perturb_pose(kf: &KeyframePose, d: &[f64; 6]) -> KeyframePose {
    KeyframePose {
        p_wb: kf.p_wb + Vec3::new(d[0], d[1], d[2]),
        q_wb: kf.q_wb * quat_exp(&Vec3::new(d[3], d[4], d[5])),
        td: kf.td,
    }
}

/// Right-perturbs the extrinsic by `d = [dp_bc, dtheta_bc]`.
pub fn perturb_ext(ext: &CameraExtrinsic, d: &[f64; 6]) -> CameraExtrinsic {
    CameraExtrinsic {
        p_bc: ext.p_bc + Vec3::new(d[0], d[1], d[2]),
        q_bc: ext.q_bc * quat_exp(&Vec3::new(d[3], d[4], d[5])),
    }
}

/// Max abs entry difference relative to max(1, max abs of `b`).
pub fn rel_err<const R: usize, const C: usize>(
    a: &SMatrix<f64, R, C>,
    b: &SMatrix<f64, R, C>,
) -> f64 {
    let scale = b.amax().max(1.0);
    (a - b).amax() / scale
}

/// EuRoC cam0 -> body extrinsic (T_BS of `cam0/sensor.yaml`).
pub fn euroc_extrinsic() -> CameraExtrinsic {
    let r = nalgebra::Matrix3::new(
        0.0148655429818,
        -0.999880929698,
        0.00414029679422,
        0.999557249008,
        0.0149672133247,
        0.025715529948,
        -0.0257744366974,
        0.00375618835797,
        0.999660727178,
    );
    let rot = nalgebra::Rotation3::from_matrix(&r);
    CameraExtrinsic {
        p_bc: Vec3::new(-0.0216401454975, -0.064676986768, 0.00981073058949),
        q_bc: Quat::from_rotation_matrix(&rot),
    }
}

/// Random body pose around the origin.
pub fn random_pose(rng: &mut Rng, td: f64) -> KeyframePose {
    KeyframePose {
        p_wb: rng.vec3(1.0),
        q_wb: quat_exp(&rng.vec3(0.4)),
        td,
    }
}

/// Landmark observation on the normalized plane of the camera of `kf`.
pub fn observe(kf: &KeyframePose, ext: &CameraExtrinsic, p_w: &Vec3) -> Vec2 {
    let cam = ext.camera_pose(&kf.p_wb, &kf.q_wb);
    let p_c = cam.q_wc.inverse() * (p_w - cam.p_wc);
    Vec2::new(p_c.x / p_c.z, p_c.y / p_c.z)
}

/// Depth (z) of `p_w` in the camera of `kf`.
pub fn depth_in(kf: &KeyframePose, ext: &CameraExtrinsic, p_w: &Vec3) -> f64 {
    let cam = ext.camera_pose(&kf.p_wb, &kf.q_wb);
    (cam.q_wc.inverse() * (p_w - cam.p_wc)).z
}

/// Data folder: the repository's `tests/data` (small real sequences), else `shared/data` next to
/// the repository root (a git worktree one level deeper also finds it). Fails loudly when absent.
pub fn data_dir() -> std::path::PathBuf {
    let candidates = [
        concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data"),
        concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"),
        concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data"),
    ];
    for c in candidates {
        let p = std::path::PathBuf::from(c);
        if p.is_dir() {
            return p;
        }
    }
    panic!("shared data folder missing: tried {candidates:?}");
}
