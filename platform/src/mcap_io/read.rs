//! Reading an MCAP file incrementally ([`McapRecording`]): one pass when it is opened for the
//! calibration, the simulator's truth and which topics have messages, then one pass per
//! stream, each pulling records from the file as it goes, decoding only its own topic's
//! messages and stopping after the topic's last message (the count of the pass at open). A stream
//! holds one chunk record and its decompressed records (each at most [`super::MAX_CHUNK_BYTES`])
//! and at most [`REORDER`] decoded messages, whatever the file's length; a corrupt chunk is
//! skipped (`Records`).
//!
//! Each topic is offered in header-stamp order: messages written out of order by fewer than
//! [`REORDER`] places are put back in order; a repeated stamp, or a message further out of
//! order, is an error naming the topic and the stamps.

use super::{
    calibration_from_metadata, check_chunk_sizes, invalid, SimTruthJson, SimTruthMsg,
    CALIBRATION_METADATA, COMPRESSED_IMAGE_TYPE, IMAGE_TYPE, IMU_TYPE, MAX_CHUNK_BYTES,
    ODOMETRY_TYPE, POINT_CLOUD2_TYPE, POINT_CLOUD_TYPE, SIM_TRUTH_ATTACHMENT, TOPIC_FEATURES,
    TOPIC_GROUND_TRUTH, TOPIC_GROUND_TRUTH_BIAS, TOPIC_IMAGE, TOPIC_IMAGE_COMPRESSED, TOPIC_IMU,
    TOPIC_LIDAR, TOPIC_SIM_TRUTH,
};
use crate::cdr::CdrError;
use crate::dataset::{Calibration, FeatureFrame, ImageFrame, LidarScan, SimLandmark, SimTruth};
use crate::error::IoError;
use crate::recording::{Contents, Recording, Stream};
use crate::ros2::{convert, msgs};
use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use povins_core::inertial::{ImuSample, NavState};
use povins_core::math::Vec3;
use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::{Path, PathBuf};

/// Messages of a topic held to put them back in stamp order.
pub const REORDER: usize = 8;

/// What a record visitor knows of the file: its path and the channel table so far.
struct RecordCtx {
    path: PathBuf,
    schemas: HashMap<u16, String>,
    /// Channel id -> (topic, schema name, message encoding).
    channels: HashMap<u16, (String, String, String)>,
    /// Attachments read past because they did not parse (a bad CRC): povins reads only the
    /// evaluation-only simulator truth from attachments, which never blocks a run.
    skipped: Vec<String>,
}

/// A pull reader of an MCAP file's records, with the channel table built as it goes.
///
/// Chunks are read here, not by the `mcap` reader: a chunk that does not decompress to its
/// size or whose CRC does not match is skipped, its messages lost, and the pass at open says
/// so in a warning naming the offset (the streams skip the same chunks silently); the file is
/// read on. Everything else that fails to parse is an error.
struct Records {
    file: std::io::BufReader<std::fs::File>,
    reader: LinearReader,
    ctx: RecordCtx,
    /// Bytes of the file handed to the reader so far: a record that fails to parse (or a chunk
    /// whose CRC does not match) ends at or before this offset.
    read_bytes: u64,
    /// The records of the chunk being read, decompressed, and the offset of the next one.
    chunk: Vec<u8>,
    chunk_pos: usize,
    /// Whether skipped chunks are reported (in [`RecordCtx::skipped`]).
    report_skips: bool,
}

/// What a visitor did with a record.
enum Step<T> {
    /// The visitor took something from it.
    Item(T),
    /// Nothing for the visitor.
    Skip,
}

impl Records {
    fn open(path: &Path) -> Result<Self, IoError> {
        check_chunk_sizes(path)?;
        let f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
        // A record length limit, so a corrupt length inside a chunk fails instead of allocating.
        // Chunks come whole (`emit_chunks`): [`Records::next_with`] checks and opens them.
        let opts = LinearReaderOptions::default()
            .with_record_length_limit(MAX_CHUNK_BYTES as usize)
            .with_emit_chunks(true);
        Ok(Records {
            file: std::io::BufReader::with_capacity(1 << 16, f),
            reader: LinearReader::new_with_options(opts),
            ctx: RecordCtx {
                path: path.to_path_buf(),
                schemas: HashMap::new(),
                channels: HashMap::new(),
                skipped: Vec::new(),
            },
            read_bytes: 0,
            chunk: Vec::new(),
            chunk_pos: 0,
            report_skips: false,
        })
    }

    /// The next record inside the current chunk, `None` when it is read; an error when its
    /// framing is broken (the chunk's CRC matched, or it had none).
    fn chunk_record(&mut self) -> Result<Option<(u8, std::ops::Range<usize>)>, IoError> {
        let pos = self.chunk_pos;
        if pos >= self.chunk.len() {
            return Ok(None);
        }
        let head = self.chunk.get(pos..pos + 9).and_then(|h| {
            let len = u64::from_le_bytes(h[1..9].try_into().ok()?);
            let start = pos + 9;
            let end = start.checked_add(usize::try_from(len).ok()?)?;
            (end <= self.chunk.len()).then_some((h[0], start..end))
        });
        let Some((op, range)) = head else {
            self.chunk_pos = self.chunk.len();
            return Err(IoError::Corrupt {
                file: self.ctx.path.clone(),
                what: "chunk".into(),
                offset: self.read_bytes,
                msg: format!(
                    "the record at byte {pos} of the chunk (ending at or before this offset) \
                     runs past its end"
                ),
            });
        };
        self.chunk_pos = range.end;
        Ok(Some((op, range)))
    }

    /// Decompresses and checks the chunk record `data` into `chunk` (its allocation reused from
    /// chunk to chunk); why not, when it cannot be read (the caller skips it).
    fn open_chunk(chunk: &mut Vec<u8>, data: &[u8]) -> Result<(), String> {
        let rec = crate::mcap_record::parse_record(mcap::records::op::CHUNK, data)
            .map_err(|e| e.to_string())?;
        let Record::Chunk { header, data } = rec else {
            return Err("not a chunk".into());
        };
        let size = usize::try_from(header.uncompressed_size)
            .ok()
            .filter(|&n| n as u64 <= MAX_CHUNK_BYTES)
            .ok_or_else(|| {
                format!(
                    "uncompressed size {} is too large",
                    header.uncompressed_size
                )
            })?;
        chunk.clear();
        match header.compression.as_str() {
            "" => chunk.extend_from_slice(&data),
            "zstd" => {
                let d = zstd::stream::read::Decoder::with_buffer(&data[..])
                    .map_err(|e| format!("zstd: {e}"))?;
                read_at_most(d, size, chunk).map_err(|e| format!("zstd: {e}"))?;
            }
            "lz4" => {
                let d = lz4::Decoder::new(&data[..]).map_err(|e| format!("lz4: {e}"))?;
                read_at_most(d, size, chunk).map_err(|e| format!("lz4: {e}"))?;
            }
            other => return Err(format!("compression {other:?} is not supported")),
        }
        if chunk.len() != size {
            return Err(format!(
                "decompressed to {} bytes, not its {size}",
                chunk.len()
            ));
        }
        let crc = crc32fast::hash(chunk);
        if header.uncompressed_crc != 0 && crc != header.uncompressed_crc {
            return Err(format!(
                "CRC {crc:#010x} of its records, {:#010x} recorded",
                header.uncompressed_crc
            ));
        }
        Ok(())
    }

    /// Feeds records to `visit` (schemas and channels are recorded first) until it returns an
    /// item; `None` at the end of the file.
    fn next_with<T>(
        &mut self,
        mut visit: impl FnMut(&RecordCtx, &Record<'_>) -> Result<Step<T>, IoError>,
    ) -> Result<Option<T>, IoError> {
        loop {
            // The records of the chunk being read first.
            if let Some((opcode, range)) = self.chunk_record()? {
                let at = self.read_bytes;
                let data = self.chunk.get(range).unwrap_or(&[]);
                let rec = crate::mcap_record::parse_record(opcode, data)
                    .map_err(|e| record_err(&self.ctx.path, e, at))?;
                if let Step::Item(t) = Self::take(&mut self.ctx, &rec, &mut visit)? {
                    return Ok(Some(t));
                }
                continue;
            }
            let Some(event) = self.reader.next_event() else {
                return Ok(None);
            };
            let ctx = &mut self.ctx;
            let at = self.read_bytes;
            let err = |e| record_err(&ctx.path, e, at);
            let rec = match event.map_err(err)? {
                LinearReadEvent::ReadRequest(need) => {
                    let buf = self.reader.insert(need);
                    let n =
                        read_some(&mut self.file, buf).map_err(|e| IoError::io(&ctx.path, e))?;
                    self.reader.notify_read(n);
                    self.read_bytes += n as u64;
                    continue;
                }
                LinearReadEvent::Record { data, opcode } if opcode == mcap::records::op::CHUNK => {
                    self.chunk_pos = 0;
                    if let Err(why) = Self::open_chunk(&mut self.chunk, data) {
                        self.chunk.clear();
                        if self.report_skips {
                            self.ctx.skipped.push(format!(
                                "the chunk ending at byte offset {at} was skipped ({why}): its \
                                 messages are lost"
                            ));
                        }
                    }
                    continue;
                }
                LinearReadEvent::Record { data, opcode } => {
                    match crate::mcap_record::parse_record(opcode, data) {
                        Ok(rec) => rec,
                        Err(e) if opcode == mcap::records::op::ATTACHMENT => {
                            let e = err(e);
                            ctx.skipped.push(format!(
                                "an attachment was ignored (povins reads only the evaluation-only \
                             {SIM_TRUTH_ATTACHMENT} from attachments): {e}"
                            ));
                            continue;
                        }
                        Err(e) => return Err(err(e)),
                    }
                }
            };
            if let Step::Item(t) = Self::take(ctx, &rec, &mut visit)? {
                return Ok(Some(t));
            }
        }
    }

    /// Records a schema or channel, then hands the record to `visit`.
    fn take<T>(
        ctx: &mut RecordCtx,
        rec: &Record<'_>,
        visit: &mut impl FnMut(&RecordCtx, &Record<'_>) -> Result<Step<T>, IoError>,
    ) -> Result<Step<T>, IoError> {
        match rec {
            Record::Schema { header, .. } => {
                ctx.schemas.insert(header.id, header.name.clone());
            }
            Record::Channel(c) => {
                let ty = ctx.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                ctx.channels
                    .insert(c.id, (c.topic.clone(), ty, c.message_encoding.clone()));
            }
            _ => {}
        }
        visit(ctx, rec)
    }
}

impl RecordCtx {
    /// The topic of a message, checked against the schema povins expects on it; `None` for a
    /// topic povins does not read.
    fn topic_of(
        &self,
        header: &mcap::records::MessageHeader,
    ) -> Result<Option<(&str, &'static str)>, IoError> {
        let Some((topic, ty, enc)) = self.channels.get(&header.channel_id) else {
            return Err(IoError::Corrupt {
                file: self.path.clone(),
                what: format!("message {}", header.sequence),
                offset: 0,
                msg: format!("channel {} was never declared", header.channel_id),
            });
        };
        let want = match topic.as_str() {
            TOPIC_IMU | TOPIC_GROUND_TRUTH_BIAS => IMU_TYPE,
            TOPIC_IMAGE if ty == COMPRESSED_IMAGE_TYPE => COMPRESSED_IMAGE_TYPE,
            TOPIC_IMAGE => IMAGE_TYPE,
            TOPIC_IMAGE_COMPRESSED => COMPRESSED_IMAGE_TYPE,
            TOPIC_FEATURES => POINT_CLOUD_TYPE,
            TOPIC_LIDAR => POINT_CLOUD2_TYPE,
            TOPIC_GROUND_TRUTH => ODOMETRY_TYPE,
            // Evaluation-only: in another encoding it is not povins' and is not read.
            TOPIC_SIM_TRUTH if enc == "json" => return Ok(Some((topic.as_str(), ""))),
            _ => return Ok(None),
        };
        if ty != want || enc != "cdr" {
            return Err(invalid(
                &self.path,
                format!("{topic}: schema {ty:?} encoding {enc:?}, expected {want:?} cdr"),
            ));
        }
        Ok(Some((topic.as_str(), want)))
    }
}

/// Reads `r` to its end into `out` (cleared; its allocation reused), at most `size + 1` bytes (so
/// that a longer stream shows as longer without being read whole).
fn read_at_most(r: impl Read, size: usize, out: &mut Vec<u8>) -> std::io::Result<()> {
    out.clear();
    out.reserve(size);
    r.take(size as u64 + 1).read_to_end(out).map(drop)
}

/// Reads into `buf` until it is full or the file ends; the bytes read (0 at the end).
fn read_some(f: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match f.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// An MCAP file as a [`Recording`] (see the module docs).
#[derive(Debug, Clone)]
pub struct McapRecording {
    path: PathBuf,
    name: String,
    calib: Calibration,
    sim_truth: Option<SimTruth>,
    /// Topics povins reads that have messages.
    topics: Vec<&'static str>,
    /// Messages per topic povins reads.
    counts: HashMap<&'static str, usize>,
    imu_span_ns: Option<(i64, i64)>,
    /// What was read past (an unreadable evaluation-only attachment).
    warnings: Vec<String>,
}

/// The povins topics, as `&'static str`.
const TOPICS: [&str; 8] = [
    TOPIC_IMU,
    TOPIC_IMAGE,
    TOPIC_IMAGE_COMPRESSED,
    TOPIC_FEATURES,
    TOPIC_LIDAR,
    TOPIC_GROUND_TRUTH,
    TOPIC_GROUND_TRUTH_BIAS,
    TOPIC_SIM_TRUTH,
];

impl McapRecording {
    /// Opens an MCAP file: one pass over its records for the calibration metadata, the
    /// simulator's truth and the topics with messages (messages are not decoded).
    pub fn open(path: &Path) -> Result<Self, IoError> {
        let mut r = Records::open(path)?;
        r.report_skips = true;
        let mut calib = None;
        let mut sim_truth = None;
        let mut topics: Vec<&'static str> = Vec::new();
        let mut counts: HashMap<&'static str, usize> = HashMap::new();
        let mut imu_span: Option<(i64, i64)> = None;
        let mut warnings = Vec::new();
        r.next_with::<()>(|r, rec| {
            match rec {
                Record::Message { header, .. } => {
                    if let Some((topic, _)) = r.topic_of(header)? {
                        if let Some(t) = TOPICS.iter().find(|t| **t == topic) {
                            if !topics.contains(t) {
                                topics.push(t);
                            }
                            *counts.entry(t).or_default() += 1;
                        }
                        if topic == TOPIC_IMU {
                            // Log times are the header stamps in povins' files: progress only.
                            let t = i64::try_from(header.log_time).unwrap_or(i64::MAX);
                            imu_span = Some(imu_span.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
                        }
                    }
                }
                Record::Metadata(m) if m.name == CALIBRATION_METADATA => {
                    calib = Some(calibration_from_metadata(path, &m.metadata)?);
                }
                Record::Attachment { header, data, .. } if header.name == SIM_TRUTH_ATTACHMENT => {
                    // Only the evaluation reads it: unreadable, the run goes on without it.
                    match sim_truth_from_json(path, data) {
                        Ok(t) => sim_truth = Some(t),
                        Err(e) => warnings.push(format!(
                            "the evaluation-only attachment {SIM_TRUTH_ATTACHMENT} was ignored: {e}"
                        )),
                    }
                }
                _ => {}
            }
            Ok(Step::Skip)
        })?;
        warnings.append(&mut r.ctx.skipped);
        let (name, calib) = calib
            .ok_or_else(|| invalid(path, format!("no {CALIBRATION_METADATA} metadata record")))?;
        if !topics.contains(&TOPIC_IMU) {
            return Err(invalid(path, format!("no {TOPIC_IMU} messages")));
        }
        Ok(McapRecording {
            path: path.to_path_buf(),
            name: if name.is_empty() {
                path.file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default()
            } else {
                name
            },
            calib,
            sim_truth,
            warnings,
            topics,
            counts,
            imu_span_ns: imu_span,
        })
    }

    fn has(&self, topic: &str) -> bool {
        self.topics.contains(&topic)
    }

    /// The image topic read: `/cam0/image_raw`, or `/cam0/image_raw/compressed` when that has
    /// none.
    fn image_topic(&self) -> Option<&'static str> {
        if self.has(TOPIC_IMAGE) {
            Some(TOPIC_IMAGE)
        } else if self.has(TOPIC_IMAGE_COMPRESSED) {
            Some(TOPIC_IMAGE_COMPRESSED)
        } else {
            None
        }
    }

    /// One topic's messages, decoded by `decode`, in stamp order.
    fn topic_stream<T: Send + 'static>(
        &self,
        topic: &'static str,
        decode: Decoder<T>,
        stamp: fn(&T) -> i64,
    ) -> Result<Stream<'static, T>, IoError> {
        if !self.has(topic) {
            return Ok(Box::new(std::iter::empty()));
        }
        Ok(Box::new(TopicStream {
            records: Records::open(&self.path)?,
            topic,
            decode,
            stamp,
            held: BTreeMap::new(),
            last: None,
            unread: self.counts.get(topic).copied().unwrap_or(0),
            done: false,
        }))
    }
}

/// One message of a topic povins reads, as a decoder sees it.
struct Msg<'a> {
    path: &'a Path,
    topic: &'static str,
    /// The schema povins expects on the topic.
    ty: &'static str,
    seq: u32,
    data: &'a [u8],
}

/// Decodes one message of a topic.
type Decoder<T> = fn(&Msg<'_>) -> Result<T, IoError>;

/// One topic of an MCAP file in stamp order (module docs).
struct TopicStream<T> {
    records: Records,
    topic: &'static str,
    decode: Decoder<T>,
    stamp: fn(&T) -> i64,
    /// Messages held, by stamp.
    held: BTreeMap<i64, T>,
    last: Option<i64>,
    /// Messages of the topic not yet read (the count of the pass at open): the stream stops
    /// at its last message rather than read the rest of the file (an attachment, the summary).
    unread: usize,
    done: bool,
}

impl<T> TopicStream<T> {
    fn pull(&mut self) -> Result<Option<T>, IoError> {
        while !self.done && self.unread > 0 && self.held.len() < REORDER {
            let (topic, decode) = (self.topic, self.decode);
            let msg = self.records.next_with(|r, rec| {
                let Record::Message { header, data } = rec else {
                    return Ok(Step::Skip);
                };
                match r.topic_of(header)? {
                    Some((t, ty)) if t == topic => decode(&Msg {
                        path: &r.path,
                        topic,
                        ty,
                        seq: header.sequence,
                        data,
                    })
                    .map(Step::Item),
                    _ => Ok(Step::Skip),
                }
            })?;
            let Some(msg) = msg else {
                self.done = true;
                break;
            };
            self.unread -= 1;
            let t = (self.stamp)(&msg);
            if self.held.insert(t, msg).is_some() {
                return Err(self.out_of_order(format!("two messages stamped {t} ns")));
            }
        }
        let Some((t, msg)) = self.held.pop_first() else {
            return Ok(None);
        };
        if let Some(last) = self.last.filter(|&l| t <= l) {
            return Err(self.out_of_order(if t == last {
                format!("two messages stamped {t} ns")
            } else {
                format!(
                    "a message stamped {t} ns comes more than {REORDER} messages after one \
                     stamped {last} ns"
                )
            }));
        }
        self.last = Some(t);
        Ok(Some(msg))
    }

    fn out_of_order(&self, msg: String) -> IoError {
        invalid(&self.records.ctx.path, format!("{}: {msg}", self.topic))
    }
}

impl<T> Iterator for TopicStream<T> {
    type Item = Result<T, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        match self.pull() {
            Ok(Some(v)) => Some(Ok(v)),
            Ok(None) => None,
            Err(e) => {
                self.done = true;
                self.held.clear();
                Some(Err(e))
            }
        }
    }
}

impl Msg<'_> {
    fn corrupt(&self, e: CdrError) -> IoError {
        IoError::Corrupt {
            file: self.path.into(),
            what: format!("{} message {}", self.topic, self.seq),
            offset: e.offset as u64,
            msg: e.msg,
        }
    }

    fn bad(&self, msg: impl std::fmt::Display) -> IoError {
        invalid(
            self.path,
            format!("{} message {}: {msg}", self.topic, self.seq),
        )
    }
}

fn decode_imu(m: &Msg<'_>) -> Result<ImuSample, IoError> {
    let i = msgs::Imu::decode(m.data).map_err(|e| m.corrupt(e))?;
    convert::imu_from_msg(&i).ok_or_else(|| m.bad("non-finite sample"))
}

fn decode_bias(m: &Msg<'_>) -> Result<msgs::Imu, IoError> {
    msgs::Imu::decode(m.data).map_err(|e| m.corrupt(e))
}

fn decode_odometry(m: &Msg<'_>) -> Result<msgs::Odometry, IoError> {
    msgs::Odometry::decode(m.data).map_err(|e| m.corrupt(e))
}

fn decode_image(m: &Msg<'_>) -> Result<ImageFrame, IoError> {
    if m.ty == COMPRESSED_IMAGE_TYPE {
        let c = msgs::CompressedImage::decode(m.data).map_err(|e| m.corrupt(e))?;
        convert::image_from_compressed_msg(&c).map_err(|e| IoError::Corrupt {
            file: m.path.into(),
            what: format!("{} message {} (format {:?})", m.topic, m.seq, c.format),
            offset: 0,
            msg: e,
        })
    } else {
        let i = msgs::Image::decode(m.data).map_err(|e| m.corrupt(e))?;
        convert::image_from_msg(i).map_err(|e| m.bad(e))
    }
}

fn decode_features(m: &Msg<'_>) -> Result<FeatureFrame, IoError> {
    let c = msgs::PointCloud::decode(m.data).map_err(|e| m.corrupt(e))?;
    convert::features_from_msg(&c).map_err(|e| m.bad(e))
}

fn decode_sweep(m: &Msg<'_>) -> Result<LidarScan, IoError> {
    let c = msgs::PointCloud2::decode(m.data).map_err(|e| m.corrupt(e))?;
    convert::lidar_from_msg(&c).map_err(|e| m.bad(e))
}

fn sim_truth_from_json(path: &Path, data: &[u8]) -> Result<SimTruth, IoError> {
    let j: SimTruthJson = serde_json::from_slice(data).map_err(|e| IoError::Corrupt {
        file: path.into(),
        what: SIM_TRUTH_ATTACHMENT.into(),
        offset: e.column() as u64,
        msg: e.to_string(),
    })?;
    Ok(SimTruth {
        landmarks_w: j
            .landmarks_w
            .into_iter()
            .map(|(id, p)| (id, Vec3::from(p)))
            .collect(),
        wrong_tracks: j.wrong_tracks,
        edge_features: j.edge_features,
        lidar_edge_points: Vec::new(),
    })
}

impl Recording for McapRecording {
    fn name(&self) -> &str {
        &self.name
    }

    fn calibration(&self) -> &Calibration {
        &self.calib
    }

    fn contents(&self) -> Contents {
        Contents {
            imu: self.has(TOPIC_IMU),
            frames: self.has(TOPIC_FEATURES),
            images: self.image_topic().is_some(),
            lidar: self.has(TOPIC_LIDAR),
            ground_truth: self.has(TOPIC_GROUND_TRUTH),
            imu_span_ns: self.imu_span_ns,
            image_count: self
                .image_topic()
                .map(|t| self.counts.get(t).copied().unwrap_or(0)),
        }
    }

    fn imu(&self) -> Result<Stream<'_, ImuSample>, IoError> {
        self.topic_stream(TOPIC_IMU, decode_imu, |s| s.t_ns)
    }

    fn frames(&self) -> Result<Stream<'_, FeatureFrame>, IoError> {
        self.topic_stream(TOPIC_FEATURES, decode_features, |f| f.t_ns)
    }

    fn images(&self) -> Result<Stream<'_, ImageFrame>, IoError> {
        match self.image_topic() {
            Some(t) => self.topic_stream(t, decode_image, |f| f.t_ns),
            None => Ok(Box::new(std::iter::empty())),
        }
    }

    fn sweeps(&self) -> Result<Stream<'_, LidarScan>, IoError> {
        self.topic_stream(TOPIC_LIDAR, decode_sweep, |s| s.t_ns)
    }

    fn ground_truth_stream(&self) -> Result<Stream<'_, NavState>, IoError> {
        let odoms = self.topic_stream(TOPIC_GROUND_TRUTH, decode_odometry, |o| o.header.t_ns)?;
        let biases = if self.has(TOPIC_GROUND_TRUTH_BIAS) {
            Some(self.topic_stream(TOPIC_GROUND_TRUTH_BIAS, decode_bias, |b| b.header.t_ns)?)
        } else {
            None
        };
        Ok(Box::new(GroundTruthJoin {
            path: &self.path,
            odoms,
            biases,
            failed: false,
        }))
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    fn sim_truth(&self) -> Option<&SimTruth> {
        self.sim_truth.as_ref()
    }

    fn has_sim_truth(&self) -> bool {
        self.has(TOPIC_SIM_TRUTH) || self.sim_truth.is_some()
    }

    fn sim_landmarks(&self) -> Result<Option<Stream<'_, SimLandmark>>, IoError> {
        if !self.has(TOPIC_SIM_TRUTH) {
            return Ok(self.sim_truth.as_ref().map(|t| -> Stream<'_, SimLandmark> {
                Box::new(t.landmarks(&[]).into_iter().map(Ok))
            }));
        }
        let msgs = self.topic_stream(TOPIC_SIM_TRUTH, decode_sim_truth, |m| m.t_ns)?;
        Ok(Some(Box::new(msgs.flat_map(
            |m| -> Vec<Result<SimLandmark, IoError>> {
                match m {
                    Ok(m) => m
                        .landmarks
                        .into_iter()
                        .map(|l| {
                            Ok(SimLandmark {
                                id: l.id,
                                p_w: l.p_w.map(Vec3::from),
                                first_ns: m.t_ns,
                                last_ns: l.last_ns,
                                wrong: l.wrong,
                                edge: l.edge,
                            })
                        })
                        .collect(),
                    Err(e) => vec![Err(e)],
                }
            },
        ))))
    }
}

fn decode_sim_truth(m: &Msg<'_>) -> Result<SimTruthMsg, IoError> {
    serde_json::from_slice(m.data).map_err(|e| IoError::Corrupt {
        file: m.path.into(),
        what: format!("{} message {}", m.topic, m.seq),
        offset: e.column() as u64,
        msg: e.to_string(),
    })
}

/// The ground truth of an MCAP file, one state at a time: each odometry message joined with the
/// bias message of the same stamp (the file has both topics or only the odometry). The first
/// mismatch ends the stream with an error naming the stamp.
struct GroundTruthJoin<'a> {
    path: &'a Path,
    odoms: Stream<'static, msgs::Odometry>,
    biases: Option<Stream<'static, msgs::Imu>>,
    failed: bool,
}

impl GroundTruthJoin<'_> {
    fn state(&mut self, o: msgs::Odometry) -> Result<NavState, IoError> {
        let t_ns = o.header.t_ns;
        let b = match &mut self.biases {
            None => None,
            Some(biases) => match biases.next().transpose()? {
                Some(b) if b.header.t_ns == t_ns => Some(b),
                Some(b) => {
                    return Err(invalid(
                        self.path,
                        format!(
                            "{TOPIC_GROUND_TRUTH_BIAS}: no message at {t_ns} ns (the next one is \
                             at {} ns)",
                            b.header.t_ns
                        ),
                    ))
                }
                None => {
                    return Err(invalid(
                        self.path,
                        format!(
                            "{TOPIC_GROUND_TRUTH_BIAS}: no message at {t_ns} ns (fewer messages \
                             than {TOPIC_GROUND_TRUTH})"
                        ),
                    ))
                }
            },
        };
        convert::ground_truth_from_msgs(&o, b.as_ref())
            .map_err(|e| invalid(self.path, format!("{TOPIC_GROUND_TRUTH} at {t_ns} ns: {e}")))
    }
}

impl Iterator for GroundTruthJoin<'_> {
    type Item = Result<NavState, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let r = match self.odoms.next() {
            Some(Ok(o)) => self.state(o),
            Some(Err(e)) => Err(e),
            None => match self.biases.as_mut().and_then(|b| b.next()) {
                None => return None,
                Some(Err(e)) => Err(e),
                Some(Ok(b)) => Err(invalid(
                    self.path,
                    format!(
                        "{TOPIC_GROUND_TRUTH_BIAS} at {} ns: no {TOPIC_GROUND_TRUTH} message at \
                         its stamp (more messages than {TOPIC_GROUND_TRUTH})",
                        b.header.t_ns
                    ),
                )),
            },
        };
        if r.is_err() {
            self.failed = true;
        }
        Some(r)
    }
}

/// A record the reader refused (a chunk CRC that does not match, a record that does not parse),
/// with the offset it ends at or before (`read_bytes`).
fn record_err(path: &Path, e: mcap::McapError, read_bytes: u64) -> IoError {
    IoError::Corrupt {
        file: path.into(),
        what: "mcap record".into(),
        offset: read_bytes,
        msg: format!("{e} (the record ends at or before this offset)"),
    }
}
