//! [`FoxgloveSink`]: the live estimate for a person watching the robot, served over Foxglove's
//! WebSocket protocol (the official Foxglove SDK's server, subprotocol `foxglove.sdk.v1`):
//! open `ws://HOST:PORT` in the Foxglove app ("Open connection") and add a 3D panel.
//!
//! ## Channels (protobuf, the SDK's `foxglove.*` schemas, frame [`WORLD_FRAME`])
//! - [`TOPIC_POSE`], `foxglove.PoseInFrame`: the IMU-rate pose (body in the world, z up),
//!   decimated by stamp to [`FoxgloveOptions::pose_rate_hz`] (30 Hz).
//! - [`TOPIC_PATH`], `foxglove.PosesInFrame`: the keyframes' optimized poses so far (at most
//!   [`FoxgloveOptions::path_len`], the oldest dropped), sent at every keyframe.
//! - [`TOPIC_LANDMARKS`], `foxglove.SceneUpdate`: the window's landmarks with a depth at every
//!   keyframe, as spheres, orange when the depth came from the LiDAR, white otherwise.
//!
//! Log times are the measurements' stamps on the sensor clock (ns; a stamp before 1970 is sent
//! as 0).
//!
//! ## Threads and the network
//! The sink's calls on the IMU thread decimate and push to a lock-free queue (full: dropped and
//! counted); the landmarks come from the back end through a [`LandmarkTap`]. A publishing
//! thread builds and logs the messages; the SDK's server runs its own threads. The server binds
//! to the address given ([`FoxgloveOptions::host`]), loopback by default: nothing listens on
//! another interface unless the user asks. What clients send is parsed by the SDK (this sink
//! offers no services, parameters or client publishing).

use super::sink::{KeyframeOut, LandmarkTap, PoseOut, RateDecimator, Sink, Stamped};
use crate::error::IoError;
use crate::trajectory::StampedPose;
use ::foxglove::messages::{
    Color, Pose, PoseInFrame, PosesInFrame, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive,
    Timestamp, Vector3,
};
use ::foxglove::{Channel, ChannelBuilder, Context, PartialMetadata, WebSocketServerHandle};
use povins_core::odometry::LandmarkPoint;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// Topic of the IMU-rate pose.
pub const TOPIC_POSE: &str = "/povins/pose";
/// Topic of the keyframes' path.
pub const TOPIC_PATH: &str = "/povins/path";
/// Topic of the window's landmarks.
pub const TOPIC_LANDMARKS: &str = "/povins/landmarks";
/// The frame everything is given in (the estimator's world frame, z up).
pub const WORLD_FRAME: &str = "world";
/// How often the publishing thread looks at the queue.
const POLL: Duration = Duration::from_millis(10);

/// How [`FoxgloveSink`] serves.
#[derive(Debug, Clone, PartialEq)]
pub struct FoxgloveOptions {
    /// Address to bind (default `127.0.0.1`: this machine only).
    pub host: String,
    /// Port (0: any free port, see [`FoxgloveSink::port`]).
    pub port: u16,
    /// Poses per second of sensor time on [`TOPIC_POSE`].
    pub pose_rate_hz: f64,
    /// Keyframe poses kept in the path.
    pub path_len: usize,
    /// Landmarks per keyframe shown (the estimator's landmark capacity).
    pub landmarks: usize,
    /// Poses and keyframes the queue to the publishing thread holds.
    pub queue: usize,
}

impl FoxgloveOptions {
    /// `127.0.0.1:port`, poses at 30 Hz, a path of 10,000 keyframes, 200 landmarks.
    pub fn new(port: u16) -> Self {
        FoxgloveOptions {
            host: "127.0.0.1".into(),
            port,
            pose_rate_hz: 30.0,
            path_len: 10_000,
            landmarks: 200,
            queue: 1024,
        }
    }

    /// `PORT` (on loopback) or `HOST:PORT` (`[::1]:PORT` for IPv6).
    pub fn parse(s: &str) -> Result<Self, String> {
        let bad = || format!("{s:?}: expected PORT or HOST:PORT");
        let (host, port) = match s.rsplit_once(':') {
            Some((h, p)) => (h.trim_start_matches('[').trim_end_matches(']'), p),
            None => ("127.0.0.1", s),
        };
        if host.is_empty() {
            return Err(bad());
        }
        let port = port.parse::<u16>().map_err(|_| bad())?;
        Ok(FoxgloveOptions {
            host: host.into(),
            ..FoxgloveOptions::new(port)
        })
    }
}

/// What the Foxglove output did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FoxgloveCounts {
    /// Poses logged on [`TOPIC_POSE`].
    pub poses: u64,
    /// Paths logged on [`TOPIC_PATH`] (one per keyframe).
    pub paths: u64,
    /// Landmark updates logged on [`TOPIC_LANDMARKS`].
    pub landmark_updates: u64,
    /// Outputs not published: the queue to the publishing thread was full.
    pub dropped_queue: u64,
    /// Keyframes whose landmarks the back end could not hand over (the slot was being read).
    pub landmarks_skipped: u64,
}

#[derive(Debug, Default)]
struct Shared {
    stop: AtomicBool,
    poses: AtomicU64,
    paths: AtomicU64,
    landmark_updates: AtomicU64,
}

/// A [`Sink`] serving the live pose, path and landmarks to Foxglove (see the module doc).
pub struct FoxgloveSink {
    rate: RateDecimator,
    tx: rtrb::Producer<Stamped>,
    dropped: u64,
    shared: Arc<Shared>,
    tap: Arc<LandmarkTap>,
    port: u16,
    publisher: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for FoxgloveSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FoxgloveSink")
            .field("port", &self.port)
            .field("counts", &self.counts())
            .finish_non_exhaustive()
    }
}

/// The channels of one server, and their context (the server and the channels hold it weakly:
/// it lives as long as the publishing thread).
struct Channels {
    _ctx: Arc<Context>,
    pose: Channel<PoseInFrame>,
    path: Channel<PosesInFrame>,
    landmarks: Channel<SceneUpdate>,
}

impl FoxgloveSink {
    /// Starts the server (its own context: nothing global) and the publishing thread.
    pub fn new(opts: FoxgloveOptions) -> Result<Self, IoError> {
        let what: std::path::PathBuf = format!("--foxglove {}:{}", opts.host, opts.port).into();
        let bad = |msg: String| IoError::Invalid {
            path: what.clone(),
            msg,
        };
        if !(opts.pose_rate_hz.is_finite() && opts.pose_rate_hz > 0.0 && opts.pose_rate_hz <= 1e4) {
            return Err(bad(format!(
                "pose rate {} Hz: expected (0, 10000]",
                opts.pose_rate_hz
            )));
        }
        if opts.queue == 0 || opts.path_len == 0 {
            return Err(bad("the queue and the path must hold at least 1".into()));
        }
        let ctx = Context::new();
        let server = ::foxglove::WebSocketServer::new()
            .name("povins")
            .context(&ctx)
            .bind(opts.host.clone(), opts.port)
            .start_blocking()
            .map_err(|e| bad(format!("the Foxglove server did not start: {e}")))?;
        let port = server.port();
        let channels = Channels {
            pose: ChannelBuilder::new(TOPIC_POSE).context(&ctx).build(),
            path: ChannelBuilder::new(TOPIC_PATH).context(&ctx).build(),
            landmarks: ChannelBuilder::new(TOPIC_LANDMARKS).context(&ctx).build(),
            _ctx: ctx,
        };
        let shared = Arc::new(Shared::default());
        let tap = Arc::new(LandmarkTap::new(opts.landmarks));
        let (tx, rx) = rtrb::RingBuffer::new(opts.queue);
        let publisher = {
            let (s, t, o) = (shared.clone(), tap.clone(), opts.clone());
            std::thread::Builder::new()
                .name("foxglove-pub".into())
                .spawn(move || publish_loop(server, &channels, rx, &s, &t, &o))
                .map_err(|e| IoError::io(&what, e))?
        };
        Ok(FoxgloveSink {
            rate: RateDecimator::new(opts.pose_rate_hz),
            tx,
            dropped: 0,
            shared,
            tap,
            port,
            publisher: Some(publisher),
        })
    }

    /// The port the server listens on.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// The counts so far (complete after [`Sink::finish`]).
    pub fn counts(&self) -> FoxgloveCounts {
        FoxgloveCounts {
            poses: self.shared.poses.load(Ordering::Relaxed),
            paths: self.shared.paths.load(Ordering::Relaxed),
            landmark_updates: self.shared.landmark_updates.load(Ordering::Relaxed),
            dropped_queue: self.dropped,
            landmarks_skipped: self.tap.skipped(),
        }
    }

    fn push(&mut self, item: Stamped) {
        if self.tx.push(item).is_err() {
            self.dropped += 1;
        }
    }

    fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(h) = self.publisher.take() {
            h.thread().unpark();
            let _ = h.join();
        }
    }
}

impl Sink for FoxgloveSink {
    fn pose(&mut self, p: &PoseOut) {
        let t_ns = p.nav.t_ns;
        if !self.rate.take(t_ns) {
            return;
        }
        self.push(Stamped::Pose(StampedPose::from(&p.nav)));
    }

    fn keyframe(&mut self, k: &KeyframeOut) {
        if let Some(s) = &k.state {
            self.push(Stamped::Keyframe(StampedPose::from(s)));
        }
    }

    fn finish(&mut self) -> Result<(), IoError> {
        self.stop();
        Ok(())
    }

    fn landmark_tap(&self) -> Option<Arc<LandmarkTap>> {
        Some(self.tap.clone())
    }
}

impl Drop for FoxgloveSink {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The publishing thread: logs what the queue holds (and the newest landmarks after each
/// keyframe) until stopped, then stops the server.
fn publish_loop(
    server: WebSocketServerHandle,
    ch: &Channels,
    mut rx: rtrb::Consumer<Stamped>,
    shared: &Shared,
    tap: &LandmarkTap,
    opts: &FoxgloveOptions,
) {
    let mut path: VecDeque<Pose> = VecDeque::with_capacity(opts.path_len.min(1 << 16));
    let mut landmarks = Vec::with_capacity(opts.landmarks);
    let mut seen_version = 0;
    loop {
        let stop = shared.stop.load(Ordering::Acquire);
        while let Ok(item) = rx.pop() {
            match item {
                Stamped::Pose(p) => {
                    ch.pose.log_with_meta(
                        &PoseInFrame {
                            timestamp: Some(timestamp(p.t_ns)),
                            frame_id: WORLD_FRAME.into(),
                            pose: Some(pose(&p)),
                        },
                        meta(p.t_ns),
                    );
                    shared.poses.fetch_add(1, Ordering::Relaxed);
                }
                Stamped::Keyframe(p) => {
                    if path.len() == opts.path_len {
                        path.pop_front();
                    }
                    path.push_back(pose(&p));
                    ch.path.log_with_meta(
                        &PosesInFrame {
                            timestamp: Some(timestamp(p.t_ns)),
                            frame_id: WORLD_FRAME.into(),
                            poses: path.iter().cloned().collect(),
                        },
                        meta(p.t_ns),
                    );
                    shared.paths.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        let v = tap.version();
        if v != seen_version {
            seen_version = v;
            let t_ns = tap.read(&mut landmarks);
            ch.landmarks
                .log_with_meta(&scene(t_ns, &landmarks), meta(t_ns));
            shared.landmark_updates.fetch_add(1, Ordering::Relaxed);
        }
        if stop {
            break;
        }
        std::thread::park_timeout(POLL);
    }
    let _ = server.stop();
}

/// A stamp, ns, as Foxglove's time (0 before 1970, the largest after 2106).
fn timestamp(t_ns: i64) -> Timestamp {
    let t = u64::try_from(t_ns).unwrap_or(0);
    let Ok(sec) = u32::try_from(t / 1_000_000_000) else {
        return Timestamp::MAX;
    };
    Timestamp::new_checked(sec, (t % 1_000_000_000) as u32).unwrap_or(Timestamp::MAX)
}

/// The log time of a stamp.
fn meta(t_ns: i64) -> PartialMetadata {
    PartialMetadata {
        log_time: Some(u64::try_from(t_ns).unwrap_or(0)),
    }
}

fn pose(p: &StampedPose) -> Pose {
    let q = p.q_wb.quaternion();
    Pose {
        position: Some(Vector3 {
            x: p.p_wb.x,
            y: p.p_wb.y,
            z: p.p_wb.z,
        }),
        orientation: Some(Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }),
    }
}

/// The landmarks as one entity of spheres (replacing the previous keyframe's).
fn scene(t_ns: i64, points: &[LandmarkPoint]) -> SceneUpdate {
    let (lidar, visual) = (
        Color {
            r: 1.0,
            g: 0.55,
            b: 0.0,
            a: 1.0,
        },
        Color {
            r: 0.9,
            g: 0.9,
            b: 0.9,
            a: 1.0,
        },
    );
    let spheres = points
        .iter()
        .map(|l| SpherePrimitive {
            pose: Some(Pose {
                position: Some(Vector3 {
                    x: l.p_w.x,
                    y: l.p_w.y,
                    z: l.p_w.z,
                }),
                orientation: Some(Quaternion {
                    x: 0.0,
                    y: 0.0,
                    z: 0.0,
                    w: 1.0,
                }),
            }),
            size: Some(Vector3 {
                x: 0.05,
                y: 0.05,
                z: 0.05,
            }),
            color: Some(if l.lidar { lidar } else { visual }),
        })
        .collect();
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![SceneEntity {
            timestamp: Some(timestamp(t_ns)),
            frame_id: WORLD_FRAME.into(),
            id: "landmarks".into(),
            spheres,
            ..Default::default()
        }],
    }
}

#[cfg(test)]
mod tests;
