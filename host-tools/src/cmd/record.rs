//! `povins record --ouster-meta META.json [--duration S] --out DIR`: records an Ouster sensor's
//! UDP stream (lidar and IMU packets) for `S` seconds or until Ctrl-C (either way Ctrl-C ends it
//! early, and what was received is written), or converts a pcap capture of it (`--pcap FILE`,
//! deterministic), into a recording `povins run` reads:
//!
//! - `--format euroc` (default): `DIR/mav0/imu0/data.csv` (+ `sensor.yaml`: body = IMU frame,
//!   the Ouster IMU's noise), `DIR/mav0/lidar0/data.csv` (points in the Ouster **sensor frame**,
//!   m, as the Ouster SDK's XYZ lookup gives them, each at its column's timestamp) and
//!   `lidar0/sensor.yaml` whose `T_BS` is the LiDAR extrinsic `T_bl` =
//!   `imu_to_sensor_transform`^-1 from the metadata; no `cam0` (a LiDAR-inertial recording).
//!   Written as it arrives.
//! - `--format mcap`: `DIR/recording.mcap` (the same content and calibration), written at the end
//!   from memory.
//!
//! Both also get `DIR/ouster_metadata.json`, a copy of the metadata. Times are the sensor's
//! (`timestamp_mode`); an IMU sample is stamped with its gyro time
//! ([`povins_platform::ouster::live`] documents the frames, the loss and reordering rules and
//! the counts). Progress goes to stderr about once a second; the last line on stdout is a
//! `record summary:` of `key=value` counts. Nothing received (or nothing that decodes) is an
//! error. An `--out` folder that exists and is not empty is refused.

use crate::cmd::convert::check_out_dir;
use anyhow::{Context, Result};
use povins_platform::dataset::{Calibration, Dataset};
use povins_platform::euroc::EurocWriter;
use povins_platform::ouster::live::Live;
use povins_platform::ouster::{
    calibration, LiveCounts, LiveOptions, Metadata, OusterUdp, PcapUdp, StreamDecoder,
};
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Output format.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// EuRoC ASL folder (`mav0/imu0`, `mav0/lidar0`).
    Euroc,
    /// One MCAP file `recording.mcap` (ROS 2 CDR messages).
    Mcap,
}

/// Arguments of `povins record`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The sensor's metadata JSON (from the sensor's HTTP API or the Ouster SDK).
    #[arg(long)]
    pub ouster_meta: PathBuf,
    /// Address to listen on: loopback by default; `0.0.0.0` (or this host's address on the
    /// sensor's network) to receive a sensor's packets.
    #[arg(long, default_value = "127.0.0.1", conflicts_with = "pcap")]
    pub addr: IpAddr,
    /// Lidar packet port (default: the metadata's `udp_port_lidar`, else 7502; 0: any free).
    #[arg(long)]
    pub lidar_port: Option<u16>,
    /// IMU packet port (default: the metadata's `udp_port_imu`, else 7503; 0: any free).
    #[arg(long)]
    pub imu_port: Option<u16>,
    /// How long to record, seconds (without it: until Ctrl-C; either way, Ctrl-C ends the
    /// recording early and writes what was received).
    #[arg(long, conflicts_with = "pcap")]
    pub duration: Option<f64>,
    /// Convert this pcap capture instead of listening (the datagrams to the two ports).
    #[arg(long)]
    pub pcap: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value = "euroc")]
    pub format: Format,
    /// Output folder; must not exist or be empty.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let meta = Metadata::from_file(&args.ouster_meta)
        .with_context(|| format!("--ouster-meta {}", args.ouster_meta.display()))?;
    check_out_dir(&args.out)?;
    let ports = (
        args.lidar_port.or(meta.udp_port_lidar).unwrap_or(7502),
        args.imu_port.or(meta.udp_port_imu).unwrap_or(7503),
    );
    anyhow::ensure!(
        ports.0 != ports.1 || ports.0 == 0,
        "the lidar and IMU ports are both {}: give --lidar-port and --imu-port",
        ports.0
    );
    let mut sink = Sink::new(&args, &meta);
    let counts = match &args.pcap {
        Some(p) => from_pcap(p, &meta, ports, &mut sink)
            .with_context(|| format!("--pcap {}", p.display()))?,
        None => from_udp(&args, &meta, ports, &mut sink)?,
    };
    println!("{}", summary(&counts));
    if let Some(e) = &counts.first_error {
        eprintln!(
            "warning: {} datagrams did not decode and were skipped; the first: {e}",
            counts.bad_datagrams
        );
    }
    anyhow::ensure!(
        sink.events > 0,
        "{} datagrams received, {} bad, nothing to record{}",
        counts.datagrams(),
        counts.bad_datagrams,
        counts
            .first_error
            .as_ref()
            .map_or(String::new(), |e| format!(" (first error: {e})"))
    );
    let written = sink.finish()?;
    println!("wrote {written}");
    Ok(())
}

/// Receives from the sockets until `--duration` has passed or Ctrl-C (`SIGINT`) is pressed,
/// then decodes what the receivers still hold.
fn from_udp(
    args: &Args,
    meta: &Metadata,
    ports: (u16, u16),
    sink: &mut Sink,
) -> Result<LiveCounts> {
    if let Some(d) = args.duration {
        anyhow::ensure!(
            d.is_finite() && d > 0.0 && d < 1e7,
            "--duration {d}: give a positive number of seconds"
        );
    }
    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let flag = interrupted.clone();
        ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed))
            .context("cannot catch Ctrl-C")?;
    }
    let opts = LiveOptions {
        addr: args.addr,
        lidar_port: ports.0,
        imu_port: ports.1,
        ..LiveOptions::default()
    };
    let mut src = OusterUdp::bind(meta, opts)?;
    let (la, ia) = src.local_addrs();
    let (lb, ib) = src.recv_buffer_bytes();
    let how_long = args.duration.map_or("until Ctrl-C".to_string(), |d| {
        format!("for {d} s (Ctrl-C: stop early)")
    });
    eprintln!(
        "record: listening on udp {la} (lidar) and udp {ia} (IMU) {how_long} \
         (receive buffers {lb} and {ib} bytes)"
    );
    let start = Instant::now();
    if let Some(d) = args.duration {
        src.set_deadline(start + Duration::from_secs_f64(d));
    }
    let mut report = Report::new(start);
    let mut stopping = false;
    loop {
        if !stopping && interrupted.load(Ordering::Relaxed) {
            eprintln!("record: interrupted: writing what was received");
            src.stop();
            stopping = true;
        }
        match src.poll(Duration::from_millis(200))? {
            Live::End => break,
            Live::Idle => {}
            ev => sink.push(ev)?,
        }
        report.maybe(&src.counts());
    }
    let counts = src.counts();
    anyhow::ensure!(
        counts.datagrams() > 0,
        "nothing received on udp {la} (lidar) or udp {ia} (IMU) in {:.1} s: is the sensor \
         sending to this host (its udp_dest) and these ports, and is --addr an address of this \
         host on the sensor's network (0.0.0.0: any)?",
        start.elapsed().as_secs_f64()
    );
    Ok(counts)
}

/// Decodes a capture's datagrams to the two ports, in capture order.
fn from_pcap(
    path: &Path,
    meta: &Metadata,
    ports: (u16, u16),
    sink: &mut Sink,
) -> Result<LiveCounts> {
    let mut udp = PcapUdp::open(path)?.ports(&[ports.0, ports.1]);
    let mut dec = StreamDecoder::new(meta);
    let mut report = Report::new(Instant::now());
    for d in udp.by_ref() {
        let d = d?;
        if d.dst_port == ports.0 {
            dec.lidar(&d.payload, d.dst_port);
        } else {
            dec.imu(&d.payload, d.dst_port);
        }
        while let Some(ev) = dec.pop() {
            sink.push(ev)?;
        }
        report.maybe(&dec.counts());
    }
    dec.finish();
    while let Some(ev) = dec.pop() {
        sink.push(ev)?;
    }
    let counts = dec.counts();
    anyhow::ensure!(
        counts.datagrams() > 0,
        "the capture holds no UDP datagram to port {} (lidar) or {} (IMU) ({:?})",
        ports.0,
        ports.1,
        udp.counts()
    );
    Ok(counts)
}

/// Progress lines on stderr, about one a second.
struct Report {
    start: Instant,
    next: Instant,
}

impl Report {
    fn new(start: Instant) -> Self {
        Report {
            start,
            next: start + Duration::from_secs(1),
        }
    }

    fn maybe(&mut self, c: &LiveCounts) {
        let now = Instant::now();
        if now < self.next {
            return;
        }
        self.next = now + Duration::from_secs(1);
        let a = &c.assembler;
        eprintln!(
            "record: {:.0} s: {} lidar packets, {} sweeps, {} IMU samples; dropped {}, late {}, \
             bad {}, overflows {}",
            (now - self.start).as_secs_f64(),
            c.lidar_datagrams,
            c.sweeps,
            c.imu_samples,
            a.dropped_packets,
            a.late_packets,
            c.bad_datagrams,
            c.queue_overflows
        );
    }
}

/// The final counts as `key=value` pairs.
fn summary(c: &LiveCounts) -> String {
    let a = &c.assembler;
    format!(
        "record summary: lidar_datagrams={} imu_datagrams={} bad_datagrams={} sweeps={} \
         points={} imu_samples={} dropped_packets={} missing_columns={} late_packets={} \
         duplicate_columns={} empty_sweeps={} imu_out_of_order={} queue_overflows={}",
        c.lidar_datagrams,
        c.imu_datagrams,
        c.bad_datagrams,
        c.sweeps,
        a.points,
        c.imu_samples,
        a.dropped_packets,
        a.missing_columns,
        a.late_packets,
        a.duplicate_columns,
        c.empty_sweeps,
        c.imu_out_of_order,
        c.queue_overflows
    )
}

/// Where the events go: an EuRoC folder (created at the first event) or a dataset in memory
/// written as MCAP at the end.
struct Sink {
    out: PathBuf,
    meta_path: PathBuf,
    calib: Calibration,
    euroc: Option<EurocWriter>,
    mcap: Option<Dataset>,
    events: u64,
}

impl Sink {
    fn new(args: &Args, meta: &Metadata) -> Self {
        let calib = calibration(meta);
        let mcap = (args.format == Format::Mcap).then(|| Dataset {
            name: args
                .out
                .file_name()
                .map_or("ouster".into(), |n| n.to_string_lossy().into_owned()),
            calib: calib.clone(),
            imu: Vec::new(),
            features: Vec::new(),
            images: Vec::new(),
            lidar: Vec::new(),
            ground_truth: Vec::new(),
            sim_truth: None,
        });
        Sink {
            out: args.out.clone(),
            meta_path: args.ouster_meta.clone(),
            calib,
            euroc: None,
            mcap,
            events: 0,
        }
    }

    /// Creates the folder, the metadata copy and, for EuRoC, the writer (at the first event).
    fn start(&mut self) -> Result<()> {
        std::fs::create_dir_all(&self.out)
            .with_context(|| format!("--out {}: cannot create the folder", self.out.display()))?;
        let copy = self.out.join("ouster_metadata.json");
        std::fs::copy(&self.meta_path, &copy).with_context(|| {
            format!("copying {} to {}", self.meta_path.display(), copy.display())
        })?;
        if self.mcap.is_none() {
            // No camera: the writer makes no cam0.
            self.euroc = Some(EurocWriter::create(&self.out, &self.calib)?);
        }
        Ok(())
    }

    fn push(&mut self, ev: Live) -> Result<()> {
        if self.events == 0 {
            self.start()?;
        }
        self.events += 1;
        match (&mut self.euroc, &mut self.mcap, ev) {
            (Some(w), _, Live::Imu(s)) => w.imu(&s)?,
            (Some(w), _, Live::Sweep(s)) => w.sweep(&s)?,
            (_, Some(d), Live::Imu(s)) => d.imu.push(s),
            (_, Some(d), Live::Sweep(s)) => d.lidar.push(s),
            _ => {}
        }
        Ok(())
    }

    /// Flushes the EuRoC files or writes the MCAP file; says what was written.
    fn finish(self) -> Result<String> {
        if let Some(w) = self.euroc {
            let n = w.finish()?;
            return Ok(format!(
                "{} (EuRoC ASL: {} IMU samples, {} LiDAR sweeps, {} points; ouster_metadata.json)",
                self.out.display(),
                n.imu,
                n.sweeps,
                n.points
            ));
        }
        let Some(ds) = self.mcap else {
            return Ok(format!("nothing to {}", self.out.display()));
        };
        let path = self.out.join("recording.mcap");
        povins_platform::mcap_io::write_dataset(&path, &ds)?;
        Ok(format!(
            "{} (MCAP: {} IMU samples, {} LiDAR sweeps; ouster_metadata.json beside it)",
            path.display(),
            ds.imu.len(),
            ds.lidar.len()
        ))
    }
}
