//! Live input from an Ouster sensor over UDP: [`OusterUdp`] receives its lidar and IMU
//! datagrams, decodes them as they arrive ([`StreamDecoder`], also usable on a capture's
//! datagrams) and yields IMU samples and whole sweeps, as a [`Source`].
//!
//! ## Sockets and threads
//! [`OusterUdp::bind`] binds two UDP sockets, `addr:lidar_port` and `addr:imu_port` (the
//! address defaults to loopback: bind `0.0.0.0` or the host's interface address to receive a
//! sensor's packets from the network; port 0 picks a free one, see
//! [`OusterUdp::local_addrs`]), asks for a large kernel receive buffer (`SO_RCVBUF`,
//! [`LiveOptions::recv_buffer_bytes`], capped by the kernel's `net.core.rmem_max`), and starts
//! one receiver thread per socket. The threads copy each datagram into one bounded queue in
//! arrival order; the consumer ([`OusterUdp::poll`], [`Source::next`]) decodes. A datagram that
//! finds the queue full (the consumer is too slow) is dropped and counted
//! ([`LiveCounts::queue_overflows`]). The sockets have a read timeout ([`LiveOptions::poll`])
//! so the threads notice [`OusterUdp::stop`] or the deadline ([`OusterUdp::set_deadline`]);
//! after a stop the queued datagrams are still decoded, the frame being filled is emitted, and
//! the stream ends.
//!
//! ## Untrusted datagrams
//! Every datagram is decoded with the checks of [`Decoder::decode_lidar`] and [`decode_imu`]: a
//! datagram of the wrong size, a wrong packet type, a measurement id out of range, or an IMU
//! packet with non-finite readings is counted in [`LiveCounts::bad_datagrams`] (the first error
//! is kept, naming the port) and skipped; nothing in a datagram can panic.
//!
//! ## Loss and reordering
//! Sweeps are assembled by [`SweepAssembler`]: a frame is emitted when the first packet of a
//! newer frame arrives (or at the end).
//! - A packet of the frame being filled that arrives out of order is used: columns are placed by
//!   their measurement id. The sweep's points are then sorted by time (a stable sort), so a
//!   sweep does not depend on the order its packets arrived in: with column timestamps that
//!   increase with the measurement id (a sensor's), it equals the in-order sweep (column, then
//!   row).
//! - A packet of a frame already emitted is late: counted ([`Counts::late_packets`]) and
//!   skipped; its columns count as missing in the emitted frame. So a packet overtaken by the
//!   next frame's first packet is lost: there is no waiting for stragglers, a sweep is offered as
//!   soon as it can be.
//! - Missing packets leave their columns out of the sweep ([`Counts::dropped_packets`],
//!   [`Counts::missing_columns`]); a column received twice is used once
//!   ([`Counts::duplicate_columns`]).
//! - An IMU sample not later than the previous one is dropped and counted
//!   ([`LiveCounts::imu_out_of_order`]): the stream's IMU times increase strictly.
//!
//! ## Events, frames and times
//! - IMU: [`SensorEvent::Imu`] in the **IMU frame**, which is the body frame of a recording made
//!   from an Ouster alone ([`super::calibration`]); `t_ns` is the packet's gyro timestamp
//!   ([`ImuPacket::gyro_t_ns`], as `ouster_ros` stamps its IMU messages; the accelerometer's is
//!   the same reading's and in practice equal), on the sensor clock (`timestamp_mode`).
//! - LiDAR: [`SensorEvent::Lidar`] with the points in the **sensor frame** (m), each at its
//!   column's timestamp; [`Live::Sweep`] also gives the sweep's time (its earliest valid
//!   column's timestamp). A sweep without points (every column invalid or without returns) is
//!   not emitted ([`LiveCounts::empty_sweeps`]).

use super::packet::{decode_imu, Decoder, ImuPacket};
use super::sweep::{Counts, SweepAssembler};
use super::Metadata;
use crate::dataset::LidarScan;
use crate::error::IoError;
use crate::source::{SensorEvent, Source};
use povins_core::inertial::ImuSample;
use povins_core::math::Vec3;
use std::collections::VecDeque;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Largest UDP payload, bytes: a receive buffer this size never truncates a datagram.
const MAX_DATAGRAM_BYTES: usize = 65_536;

/// Where and how [`OusterUdp`] listens.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LiveOptions {
    /// Address to bind (default `127.0.0.1`: loopback only).
    pub addr: IpAddr,
    /// Lidar packet port (default 7502; 0: any free port).
    pub lidar_port: u16,
    /// IMU packet port (default 7503; 0: any free port).
    pub imu_port: u16,
    /// Kernel receive buffer asked for each socket, bytes (0: the system default).
    pub recv_buffer_bytes: usize,
    /// Datagrams the queue between the receiver threads and the consumer holds.
    pub queue_datagrams: usize,
    /// Socket read timeout: how soon the receivers notice a stop.
    pub poll: Duration,
}

impl Default for LiveOptions {
    fn default() -> Self {
        LiveOptions {
            addr: IpAddr::V4(Ipv4Addr::LOCALHOST),
            lidar_port: 7502,
            imu_port: 7503,
            recv_buffer_bytes: 16 << 20,
            queue_datagrams: 4096,
            poll: Duration::from_millis(50),
        }
    }
}

/// What a [`StreamDecoder`] (or [`OusterUdp`]) received, decoded and dropped.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct LiveCounts {
    /// Datagrams received on the lidar port.
    pub lidar_datagrams: u64,
    /// Datagrams received on the IMU port.
    pub imu_datagrams: u64,
    /// Datagrams that did not decode (wrong size, garbage), skipped.
    pub bad_datagrams: u64,
    /// The first bad datagram's error, naming its port.
    pub first_error: Option<String>,
    /// IMU samples emitted.
    pub imu_samples: u64,
    /// IMU samples not later than the previous one, dropped.
    pub imu_out_of_order: u64,
    /// Sweeps emitted.
    pub sweeps: u64,
    /// Sweeps without points, not emitted.
    pub empty_sweeps: u64,
    /// Datagrams dropped because the queue to the consumer was full.
    pub queue_overflows: u64,
    /// The sweep assembler's counts (packets, dropped / late packets, duplicate columns, ...).
    pub assembler: Counts,
}

impl LiveCounts {
    /// Datagrams received on both ports.
    pub fn datagrams(&self) -> u64 {
        self.lidar_datagrams + self.imu_datagrams
    }
}

/// What [`OusterUdp::poll`] (or [`StreamDecoder::pop`]) gives.
#[derive(Debug, Clone, PartialEq)]
pub enum Live {
    /// An IMU sample (IMU frame = body frame, gyro timestamp; see the module docs).
    Imu(ImuSample),
    /// A whole sweep (sensor frame), its time the earliest valid column's.
    Sweep(LidarScan),
    /// Nothing arrived within the timeout.
    Idle,
    /// The stream ended (stopped, and everything received was emitted).
    End,
}

/// Decodes a sensor's datagrams in arrival order into IMU samples and sweeps (see the module
/// docs): the consumer side of [`OusterUdp`], and of a capture's replay.
#[derive(Debug)]
pub struct StreamDecoder {
    decoder: Decoder,
    asm: SweepAssembler,
    ready: VecDeque<Live>,
    counts: LiveCounts,
    last_imu_t_ns: Option<i64>,
}

impl StreamDecoder {
    /// A decoder for the packets described by `meta`.
    pub fn new(meta: &Metadata) -> Self {
        StreamDecoder {
            decoder: Decoder::new(meta),
            asm: SweepAssembler::new(meta),
            ready: VecDeque::new(),
            counts: LiveCounts::default(),
            last_imu_t_ns: None,
        }
    }

    /// Decodes a lidar-port datagram; `port` names it in the first error.
    pub fn lidar(&mut self, payload: &[u8], port: u16) {
        self.counts.lidar_datagrams += 1;
        match self.decoder.decode_lidar(payload) {
            Ok(p) => {
                if let Some(scan) = self.asm.push(&p) {
                    self.emit(scan);
                }
            }
            Err(e) => self.bad(format!("lidar port {port}: {e}")),
        }
    }

    /// Decodes an IMU-port datagram; `port` names it in the first error.
    pub fn imu(&mut self, payload: &[u8], port: u16) {
        self.counts.imu_datagrams += 1;
        let p = match decode_imu(payload) {
            Ok(p) => p,
            Err(e) => return self.bad(format!("IMU port {port}: {e}")),
        };
        let Some(s) = imu_sample(&p) else {
            return self.bad(format!("IMU port {port}: non-finite reading"));
        };
        if self.last_imu_t_ns.is_some_and(|t| s.t_ns <= t) {
            self.counts.imu_out_of_order += 1;
            return;
        }
        self.last_imu_t_ns = Some(s.t_ns);
        self.counts.imu_samples += 1;
        self.ready.push_back(Live::Imu(s));
    }

    /// Emits the frame being filled (the end of the stream).
    pub fn finish(&mut self) {
        if let Some(scan) = self.asm.finish() {
            self.emit(scan);
        }
    }

    /// The next decoded event, in the order decoded.
    pub fn pop(&mut self) -> Option<Live> {
        self.ready.pop_front()
    }

    /// Counts so far.
    pub fn counts(&self) -> LiveCounts {
        LiveCounts {
            assembler: self.asm.counts(),
            ..self.counts.clone()
        }
    }

    fn emit(&mut self, mut scan: LidarScan) {
        if scan.points.is_empty() {
            self.counts.empty_sweeps += 1;
            return;
        }
        scan.points.sort_by_key(|p| p.t_ns);
        self.counts.sweeps += 1;
        self.ready.push_back(Live::Sweep(scan));
    }

    fn bad(&mut self, msg: String) {
        self.counts.bad_datagrams += 1;
        if self.counts.first_error.is_none() {
            self.counts.first_error = Some(msg);
        }
    }
}

/// An IMU packet as a sample in the IMU (body) frame at its gyro time; `None` when a reading is
/// not finite.
pub fn imu_sample(p: &ImuPacket) -> Option<ImuSample> {
    let s = ImuSample {
        t_ns: p.gyro_t_ns,
        gyro_rps: Vec3::from(p.gyro_rps),
        accel_mps2: Vec3::from(p.accel_mps2),
    };
    s.is_finite().then_some(s)
}

/// A received datagram, or a receiver's failure.
enum Msg {
    Lidar(Vec<u8>),
    Imu(Vec<u8>),
    Failed(IoError),
}

/// Which port a receiver serves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Port {
    Lidar,
    Imu,
}

/// State the receiver threads share with the consumer.
#[derive(Debug, Default)]
struct Shared {
    stop: AtomicBool,
    overflows: AtomicU64,
}

/// A live Ouster sensor on two UDP ports (see the module docs).
pub struct OusterUdp {
    rx: Receiver<Msg>,
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
    stream: StreamDecoder,
    addrs: (SocketAddr, SocketAddr),
    recv_buffer_bytes: (usize, usize),
    deadline: Option<Instant>,
    poll: Duration,
    ended: bool,
}

impl std::fmt::Debug for OusterUdp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OusterUdp")
            .field("addrs", &self.addrs)
            .field("ended", &self.ended)
            .finish_non_exhaustive()
    }
}

impl OusterUdp {
    /// Binds the lidar and IMU ports and starts receiving; the error names the address and port
    /// that could not be bound.
    pub fn bind(meta: &Metadata, opts: LiveOptions) -> Result<Self, IoError> {
        let lidar = open_socket(opts.addr, opts.lidar_port, "lidar", &opts)?;
        let imu = open_socket(opts.addr, opts.imu_port, "IMU", &opts)?;
        let addrs = (lidar.0.local_addr(), imu.0.local_addr());
        let (Ok(la), Ok(ia)) = addrs else {
            return Err(IoError::Invalid {
                path: format!("udp {}", opts.addr).into(),
                msg: "cannot read the bound sockets' addresses".into(),
            });
        };
        let (tx, rx) = mpsc::sync_channel(opts.queue_datagrams.max(1));
        let shared = Arc::new(Shared::default());
        let mut threads = Vec::new();
        for (sock, port, addr) in [(lidar.0, Port::Lidar, la), (imu.0, Port::Imu, ia)] {
            let (tx, shared) = (tx.clone(), Arc::clone(&shared));
            let t = std::thread::Builder::new()
                .name(format!("ouster-udp-{}", addr.port()))
                .spawn(move || receive(&sock, port, addr, &tx, &shared))
                .map_err(|e| IoError::io(format!("udp {addr}"), e))?;
            threads.push(t);
        }
        Ok(OusterUdp {
            rx,
            shared,
            threads,
            stream: StreamDecoder::new(meta),
            addrs: (la, ia),
            recv_buffer_bytes: (lidar.1, imu.1),
            deadline: None,
            poll: opts.poll,
            ended: false,
        })
    }

    /// The bound lidar and IMU socket addresses (the ports chosen for port 0).
    pub fn local_addrs(&self) -> (SocketAddr, SocketAddr) {
        self.addrs
    }

    /// The kernel receive buffers the lidar and IMU sockets got, bytes (as `SO_RCVBUF` reports
    /// them; 0 when unknown).
    pub fn recv_buffer_bytes(&self) -> (usize, usize) {
        self.recv_buffer_bytes
    }

    /// Stops receiving at `t` (see [`OusterUdp::stop`]).
    pub fn set_deadline(&mut self, t: Instant) {
        self.deadline = Some(t);
    }

    /// Stops receiving: the receivers exit within [`LiveOptions::poll`], what they queued is
    /// still decoded, then the last frame is emitted and the stream ends.
    pub fn stop(&self) {
        self.shared.stop.store(true, Ordering::Relaxed);
    }

    /// Counts so far.
    pub fn counts(&self) -> LiveCounts {
        LiveCounts {
            queue_overflows: self.shared.overflows.load(Ordering::Relaxed),
            ..self.stream.counts()
        }
    }

    /// The next event, waiting at most `timeout` for one ([`Live::Idle`] then); [`Live::End`]
    /// once stopped and drained. A socket failure (not a bad datagram) is an error naming the
    /// socket, and stops the receivers.
    pub fn poll(&mut self, timeout: Duration) -> Result<Live, IoError> {
        let until = Instant::now() + timeout;
        loop {
            if let Some(ev) = self.stream.pop() {
                return Ok(ev);
            }
            if self.ended {
                return Ok(Live::End);
            }
            let now = Instant::now();
            if self.deadline.is_some_and(|d| now >= d) {
                self.stop();
            }
            let wait = until.saturating_duration_since(now).min(self.poll);
            match self.rx.recv_timeout(wait) {
                Ok(Msg::Lidar(b)) => self.stream.lidar(&b, self.addrs.0.port()),
                Ok(Msg::Imu(b)) => self.stream.imu(&b, self.addrs.1.port()),
                Ok(Msg::Failed(e)) => {
                    self.stop();
                    return Err(e);
                }
                Err(RecvTimeoutError::Timeout) if Instant::now() >= until => return Ok(Live::Idle),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => {
                    self.stream.finish();
                    self.ended = true;
                }
            }
        }
    }
}

impl Drop for OusterUdp {
    fn drop(&mut self) {
        self.stop();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Source for OusterUdp {
    fn next(&mut self) -> Result<Option<SensorEvent>, IoError> {
        loop {
            match self.poll(self.poll)? {
                Live::Imu(s) => return Ok(Some(SensorEvent::Imu(s))),
                Live::Sweep(scan) => return Ok(Some(SensorEvent::Lidar(scan.points))),
                Live::Idle => {}
                Live::End => return Ok(None),
            }
        }
    }

    fn is_realtime(&self) -> bool {
        true
    }
}

/// Binds `addr:port` with a read timeout and the receive buffer asked for; returns the socket
/// and the receive buffer it got.
fn open_socket(
    addr: IpAddr,
    port: u16,
    what: &str,
    opts: &LiveOptions,
) -> Result<(UdpSocket, usize), IoError> {
    let at = SocketAddr::new(addr, port);
    let err = |e: std::io::Error| IoError::Invalid {
        path: format!("udp {at}").into(),
        msg: format!("cannot listen for the {what} packets: {e}"),
    };
    let sock = UdpSocket::bind(at).map_err(err)?;
    sock.set_read_timeout(Some(opts.poll.max(Duration::from_millis(1))))
        .map_err(err)?;
    let got = set_recv_buffer(&sock, opts.recv_buffer_bytes);
    Ok((sock, got))
}

/// Asks for a `bytes` kernel receive buffer (a hint: the kernel caps it) and returns what the
/// socket has (0 when it cannot be read).
fn set_recv_buffer(sock: &UdpSocket, bytes: usize) -> usize {
    use std::os::fd::AsRawFd;
    let fd = sock.as_raw_fd();
    let len = std::mem::size_of::<libc::c_int>() as libc::socklen_t;
    if bytes > 0 {
        let v = libc::c_int::try_from(bytes).unwrap_or(libc::c_int::MAX);
        // SAFETY: `fd` is the open socket `sock` owns; the option value is a c_int of `len`
        // bytes that lives across the call.
        let _ = unsafe {
            libc::setsockopt(
                fd,
                libc::SOL_SOCKET,
                libc::SO_RCVBUF,
                (&v as *const libc::c_int).cast(),
                len,
            )
        };
    }
    let mut got: libc::c_int = 0;
    let mut got_len = len;
    // SAFETY: as above; `got` and `got_len` are writable and `got_len` holds `got`'s size.
    let r = unsafe {
        libc::getsockopt(
            fd,
            libc::SOL_SOCKET,
            libc::SO_RCVBUF,
            (&mut got as *mut libc::c_int).cast(),
            &mut got_len,
        )
    };
    if r == 0 {
        usize::try_from(got).unwrap_or(0)
    } else {
        0
    }
}

/// A receiver thread: datagrams of `sock` into the queue until stopped.
fn receive(sock: &UdpSocket, port: Port, addr: SocketAddr, tx: &SyncSender<Msg>, sh: &Shared) {
    let mut buf = vec![0u8; MAX_DATAGRAM_BYTES];
    while !sh.stop.load(Ordering::Relaxed) {
        match sock.recv(&mut buf) {
            Ok(n) => {
                let bytes = buf.get(..n).unwrap_or(&buf[..]).to_vec();
                let msg = match port {
                    Port::Lidar => Msg::Lidar(bytes),
                    Port::Imu => Msg::Imu(bytes),
                };
                match tx.try_send(msg) {
                    Ok(()) => {}
                    Err(TrySendError::Full(_)) => {
                        sh.overflows.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(TrySendError::Disconnected(_)) => return,
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::Interrupted
                ) => {}
            Err(e) => {
                let e = IoError::Invalid {
                    path: format!("udp {addr}").into(),
                    msg: format!("receiving failed: {e}"),
                };
                let _ = tx.send(Msg::Failed(e));
                return;
            }
        }
    }
}
