//! Golden determinism hash: preintegrate the whole EuRoC V1_01 IMU log (145 s) in consecutive
//! 0.5 s windows and hash every delta and covariance bit pattern (FNV-1a 64). Run on x86-64 and
//! under qemu on aarch64: the hash must be identical (libm only, no fused multiply-add).

mod inertial_common;

use inertial_common::euroc_imu;
use povins_core::inertial::{ImuNoise, PreintConfig, Preintegration};
use povins_core::math::Vec3;

/// Hash of the current implementation on x86-64; any change to the integration arithmetic
/// changes it (update deliberately, and re-check aarch64).
const GOLDEN: u64 = 0x160f_a7c5_46b0_1a72;

struct Fnv(u64);

impl Fnv {
    fn f64(&mut self, x: f64) {
        for b in x.to_bits().to_le_bytes() {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

#[test]
fn preintegration_golden_hash() {
    let imu = euroc_imu();
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    let mut pre = Preintegration::<128>::new(
        ImuNoise::EUROC_ADIS16448,
        PreintConfig::DEFAULT,
        &imu[0],
        Vec3::zeros(),
        Vec3::zeros(),
    )
    .unwrap();
    let mut windows = 0;
    for (k, s) in imu.iter().enumerate().skip(1) {
        pre.push(s).unwrap();
        if k % 100 == 0 {
            for x in pre.delta_p().iter().chain(pre.delta_v().iter()) {
                h.f64(*x);
            }
            for x in pre.delta_q().coords.iter() {
                h.f64(*x);
            }
            for x in pre.covariance().iter() {
                h.f64(*x);
            }
            windows += 1;
            pre.reset(s, Vec3::zeros(), Vec3::zeros()).unwrap();
        }
    }
    println!("POVINS_PREINT_HASH={:016x} ({windows} windows)", h.0);
    assert_eq!(windows, 291);
    assert_eq!(h.0, GOLDEN, "golden hash changed: {:016x}", h.0);
}
