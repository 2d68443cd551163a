//! The IMU samples a run gets from topics that are not already one IMU in m/s^2:
//!
//! - **Accelerometer apart** (RealSense: `/camera/gyro/sample` at 200 or 400 Hz and
//!   `/camera/accel/sample` at 63 to 250 Hz, each `sensor_msgs/Imu` with only its own half set):
//!   the gyro's stamps are the samples' stamps and the accelerometer is linearly interpolated to
//!   each of them, `a(t) = a0 + (a1 - a0) (t - t0) / (t1 - t0)` between the accelerometer samples
//!   `t0 <= t <= t1` around it. Gyro samples before the first or after the last accelerometer
//!   sample cannot be interpolated: they are dropped and counted.
//! - **Accelerometer unit**: some IMUs (Livox's built-in one) publish specific force in g, not
//!   m/s^2. [`AccelUnit::Auto`] decides from the median magnitude of the first
//!   [`UNIT_SAMPLES`] samples (gravity dominates it, at rest or in ordinary motion): within
//!   [`G_RANGE`] it is g, within [`MPS2_RANGE`] m/s^2, otherwise m/s^2 with a warning. A sample in
//!   g is multiplied by standard gravity, [`STANDARD_GRAVITY_MPS2`] (the unit's definition, not
//!   the local gravity).

use crate::error::IoError;
use povins_core::inertial::ImuSample;
use povins_core::math::Vec3;

/// The accelerometer's unit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum AccelUnit {
    /// Decided from the magnitude (see the module docs).
    #[default]
    Auto,
    /// m/s^2 (ROS's convention, REP 103).
    Mps2,
    /// Standard gravities.
    G,
}

impl std::str::FromStr for AccelUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(AccelUnit::Auto),
            "mps2" | "m/s^2" => Ok(AccelUnit::Mps2),
            "g" => Ok(AccelUnit::G),
            _ => Err(format!(
                "accelerometer unit {s:?}: expected auto, mps2 or g"
            )),
        }
    }
}

/// Samples the unit is decided on.
pub const UNIT_SAMPLES: usize = 200;
/// Median magnitudes read as g.
pub const G_RANGE: (f64, f64) = (0.5, 2.0);
/// Median magnitudes read as m/s^2.
pub const MPS2_RANGE: (f64, f64) = (5.0, 20.0);
/// One g, m/s^2.
pub const STANDARD_GRAVITY_MPS2: f64 = 9.80665;

/// The unit of accelerometer samples `accel` (their first [`UNIT_SAMPLES`]), and a warning
/// when it could not be told.
pub fn detect_unit(accel: &[Vec3]) -> (AccelUnit, Option<String>) {
    let mut mags: Vec<f64> = accel.iter().take(UNIT_SAMPLES).map(|a| a.norm()).collect();
    if mags.is_empty() {
        return (AccelUnit::Mps2, None);
    }
    mags.sort_by(f64::total_cmp);
    let m = mags[mags.len() / 2];
    let within = |r: (f64, f64)| m >= r.0 && m <= r.1;
    if within(G_RANGE) {
        (AccelUnit::G, None)
    } else if within(MPS2_RANGE) {
        (AccelUnit::Mps2, None)
    } else {
        let w = format!(
            "the accelerometer's median magnitude over its first {} samples is {m:.3}, neither \
             about 1 (g) nor about 9.8 (m/s^2): read as m/s^2 (set [input] accel_unit to choose)",
            mags.len()
        );
        (AccelUnit::Mps2, Some(w))
    }
}

/// Scale to m/s^2 of a (decided) unit.
pub fn scale(unit: AccelUnit) -> f64 {
    match unit {
        AccelUnit::G => STANDARD_GRAVITY_MPS2,
        AccelUnit::Auto | AccelUnit::Mps2 => 1.0,
    }
}

/// The gyro samples with the accelerometer interpolated to their stamps (see the module docs).
pub struct Merged<G, A> {
    on_end: Option<Box<dyn FnOnce(u64) + Send>>,
    gyro: G,
    accel: A,
    /// The accelerometer samples around the current gyro stamp.
    a0: Option<ImuSample>,
    a1: Option<ImuSample>,
    accel_done: bool,
    /// Gyro samples that could not be interpolated.
    pub dropped: u64,
}

impl<G, A> Merged<G, A> {
    /// Merges `accel` into `gyro`; `on_end` is told the dropped count when the gyro ends.
    pub fn new(gyro: G, accel: A, on_end: Box<dyn FnOnce(u64) + Send>) -> Self {
        Merged {
            on_end: Some(on_end),
            gyro,
            accel,
            a0: None,
            a1: None,
            accel_done: false,
            dropped: 0,
        }
    }
}

impl<G, A> Iterator for Merged<G, A>
where
    G: Iterator<Item = Result<ImuSample, IoError>>,
    A: Iterator<Item = Result<ImuSample, IoError>>,
{
    type Item = Result<ImuSample, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let Some(g) = self.gyro.next() else {
                if let Some(f) = self.on_end.take() {
                    f(self.dropped);
                }
                return None;
            };
            let mut g = match g {
                Ok(g) => g,
                Err(e) => return Some(Err(e)),
            };
            // Advance until a1 is at or after the gyro stamp.
            while !self.accel_done && self.a1.is_none_or(|a1| a1.t_ns < g.t_ns) {
                match self.accel.next() {
                    Some(Ok(a)) => {
                        self.a0 = self.a1.take();
                        self.a1 = Some(a);
                    }
                    Some(Err(e)) => return Some(Err(e)),
                    None => self.accel_done = true,
                }
            }
            let a = match (self.a0, self.a1) {
                (_, Some(a1)) if a1.t_ns == g.t_ns => Some(a1.accel_mps2),
                (Some(a0), Some(a1)) if a0.t_ns <= g.t_ns && g.t_ns <= a1.t_ns => {
                    let f = (g.t_ns - a0.t_ns) as f64 / (a1.t_ns - a0.t_ns) as f64;
                    Some(a0.accel_mps2 + (a1.accel_mps2 - a0.accel_mps2) * f)
                }
                _ => None,
            };
            match a {
                Some(a) => {
                    g.accel_mps2 = a;
                    return Some(Ok(g));
                }
                None => self.dropped += 1,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(t_ns: i64, w: f64, a: f64) -> Result<ImuSample, IoError> {
        Ok(ImuSample {
            t_ns,
            gyro_rps: Vec3::new(w, 0.0, 0.0),
            accel_mps2: Vec3::new(a, 0.0, 9.81),
        })
    }

    #[test]
    fn accel_is_interpolated_to_the_gyro_stamps() {
        let gyro = vec![
            s(5, 1.0, 0.0),
            s(10, 2.0, 0.0),
            s(25, 3.0, 0.0),
            s(40, 4.0, 0.0),
            s(50, 5.0, 0.0),
        ];
        let accel = vec![s(10, 0.0, 1.0), s(20, 0.0, 2.0), s(40, 0.0, 6.0)];
        let seen = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(99));
        let told = seen.clone();
        let end = Box::new(move |n| told.store(n, std::sync::atomic::Ordering::SeqCst));
        let mut m = Merged::new(gyro.into_iter(), accel.into_iter(), end);
        let got: Vec<(i64, f64, f64)> = m
            .by_ref()
            .map(|x| x.unwrap())
            .map(|x| (x.t_ns, x.gyro_rps.x, x.accel_mps2.x))
            .collect();
        // 5 is before the first accel sample, 50 after the last: dropped.
        assert_eq!(got, [(10, 2.0, 1.0), (25, 3.0, 3.0), (40, 4.0, 6.0)]);
        assert_eq!(m.dropped, 2);
        assert_eq!(seen.load(std::sync::atomic::Ordering::SeqCst), 2);
    }

    #[test]
    fn units_are_told_from_the_magnitude() {
        let at = |m: f64| vec![Vec3::new(0.0, 0.0, m); 50];
        assert_eq!(detect_unit(&at(1.0)), (AccelUnit::G, None));
        assert_eq!(detect_unit(&at(9.81)), (AccelUnit::Mps2, None));
        let (u, w) = detect_unit(&at(3.0));
        assert_eq!(u, AccelUnit::Mps2);
        assert!(w.unwrap().contains("3.000"));
        assert_eq!("g".parse::<AccelUnit>(), Ok(AccelUnit::G));
        assert!("furlongs".parse::<AccelUnit>().is_err());
    }
}
