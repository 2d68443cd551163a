//! Writing ROS 2 bags, as a [`ContainerWriter`]: the bag folder `DIR` with one storage file
//! `DIR/<name>_0.db3` (sqlite3) or `DIR/<name>_0.mcap` (MCAP), `<name>` the folder's name, and
//! `DIR/metadata.yaml`, as `ros2 bag record` (rosbag2, Jazzy: metadata version 9) lays them out.
//! Messages are CDR; they are stored as given, in the order given.
//!
//! - sqlite3: the tables of rosbag2's sqlite3 storage, schema version 4: `schema`
//!   (`schema_version`, `ros_distro`), `metadata` (`metadata_version`, `metadata`: the bag's
//!   metadata as YAML), `topics` (`id` from 1, `name`, `type`, `serialization_format` `cdr`,
//!   `offered_qos_profiles` `[]`, `type_description_hash`), `message_definitions` (one per type:
//!   `topic_type`, `encoding` `ros2msg`, `encoded_message_definition`, `type_description_hash`)
//!   and `messages` (`id`, `topic_id`, `timestamp` ns, `data`) with the index `timestamp_idx`.
//!   All rows are written in one transaction.
//! - MCAP: profile `ros2` ([`McapWriter`]), channel metadata `offered_qos_profiles` and
//!   `topic_type_hash`, and the metadata record `rosbag2` whose `serialized_metadata` is the
//!   bag's metadata as YAML.
//!
//! `metadata.yaml` (key `rosbag2_bagfile_information`): `version` 9, `storage_identifier`,
//! `duration`, `starting_time`, `message_count`, `topics_with_message_count` (each topic's
//! `topic_metadata`: `name`, `type`, `serialization_format`, `offered_qos_profiles` (an empty
//! list: the players' defaults), `type_description_hash`; and its `message_count`),
//! `compression_format` and `compression_mode` (empty: not compressed), `relative_file_paths`,
//! `files` (path, starting time, duration and count of each), `custom_data` (null) and
//! `ros_distro` (`povins`, as Python `rosbags` writes `rosbags`).

use crate::error::IoError;
use crate::mcap_log::write::McapWriter;
use crate::rosrec::write::{ContainerWriter, TopicSpec};
use crate::rosrec::Encoding;
use rusqlite::Connection;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The `version` of `metadata.yaml` written.
pub const METADATA_VERSION: u32 = 9;
/// The sqlite3 storage's `schema_version` written.
pub const SQLITE_SCHEMA_VERSION: u32 = 4;
/// `ros_distro` written.
pub const ROS_DISTRO: &str = "povins";

/// How the messages are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    /// sqlite3 (`.db3`), rosbag2's default up to Humble.
    Sqlite3,
    /// MCAP (`.mcap`), rosbag2's default from Iron.
    Mcap,
}

impl Storage {
    /// `storage_identifier` in `metadata.yaml`.
    pub fn identifier(self) -> &'static str {
        match self {
            Storage::Sqlite3 => "sqlite3",
            Storage::Mcap => "mcap",
        }
    }

    fn extension(self) -> &'static str {
        match self {
            Storage::Sqlite3 => "db3",
            Storage::Mcap => "mcap",
        }
    }
}

const SQLITE_TABLES: &str = "
CREATE TABLE schema(
  schema_version INTEGER PRIMARY KEY,
  ros_distro TEXT NOT NULL
);
CREATE TABLE metadata(
  id INTEGER PRIMARY KEY,
  metadata_version INTEGER NOT NULL,
  metadata TEXT NOT NULL
);
CREATE TABLE topics(
  id INTEGER PRIMARY KEY,
  name TEXT NOT NULL,
  type TEXT NOT NULL,
  serialization_format TEXT NOT NULL,
  offered_qos_profiles TEXT NOT NULL,
  type_description_hash TEXT NOT NULL
);
CREATE TABLE message_definitions(
  id INTEGER PRIMARY KEY,
  topic_type TEXT NOT NULL,
  encoding TEXT NOT NULL,
  encoded_message_definition TEXT NOT NULL,
  type_description_hash TEXT NOT NULL
);
CREATE TABLE messages(
  id INTEGER PRIMARY KEY,
  topic_id INTEGER NOT NULL,
  timestamp INTEGER NOT NULL,
  data BLOB NOT NULL
);
CREATE INDEX timestamp_idx ON messages (timestamp ASC);
";

const INSERT_MESSAGE: &str = "INSERT INTO messages (topic_id, timestamp, data) VALUES (?1, ?2, ?3)";

enum Store {
    Sqlite(Connection),
    Mcap(Box<McapWriter>),
}

struct Topic {
    spec: TopicSpec,
    count: u64,
}

/// A ROS 2 bag being written (see the module docs). Errors name the file.
pub struct Rosbag2Writer {
    dir: PathBuf,
    /// The storage file's name (relative to `dir`).
    file_name: String,
    storage: Storage,
    store: Store,
    topics: Vec<Topic>,
    /// First and last log time, ns.
    span_ns: Option<(i64, i64)>,
}

fn sql_err(path: &Path, what: &str, e: rusqlite::Error) -> IoError {
    IoError::Invalid {
        path: path.to_path_buf(),
        msg: format!("writing the sqlite3 bag: {what}: {e}"),
    }
}

impl Rosbag2Writer {
    /// Creates the bag folder `dir` (it must not exist, or be empty) with `storage`.
    pub fn create(dir: &Path, storage: Storage) -> Result<Self, IoError> {
        if dir.exists() {
            let mut entries = std::fs::read_dir(dir).map_err(|e| IoError::io(dir, e))?;
            if entries.next().is_some() {
                return Err(IoError::Invalid {
                    path: dir.to_path_buf(),
                    msg: "a ROS 2 bag is a new folder: this one exists and is not empty".into(),
                });
            }
        }
        std::fs::create_dir_all(dir).map_err(|e| IoError::io(dir, e))?;
        let name = dir
            .file_name()
            .map_or("rosbag2".into(), |s| s.to_string_lossy().into_owned());
        let file_name = format!("{name}_0.{}", storage.extension());
        let file = dir.join(&file_name);
        let store = match storage {
            Storage::Sqlite3 => {
                let conn = Connection::open(&file).map_err(|e| sql_err(&file, "create", e))?;
                conn.execute_batch(SQLITE_TABLES)
                    .map_err(|e| sql_err(&file, "create the tables", e))?;
                conn.execute(
                    "INSERT INTO schema (schema_version, ros_distro) VALUES (?1, ?2)",
                    (SQLITE_SCHEMA_VERSION, ROS_DISTRO),
                )
                .map_err(|e| sql_err(&file, "table schema", e))?;
                conn.execute_batch("BEGIN")
                    .map_err(|e| sql_err(&file, "begin", e))?;
                Store::Sqlite(conn)
            }
            Storage::Mcap => Store::Mcap(Box::new(McapWriter::create(&file, Encoding::Cdr)?)),
        };
        Ok(Rosbag2Writer {
            dir: dir.to_path_buf(),
            file_name,
            storage,
            store,
            topics: Vec::new(),
            span_ns: None,
        })
    }

    fn file(&self) -> PathBuf {
        self.dir.join(&self.file_name)
    }

    /// The bag's metadata (the value of `rosbag2_bagfile_information`).
    fn info(&self) -> BagInfo<'_> {
        let (start, end) = self.span_ns.unwrap_or((0, 0));
        let duration = Duration {
            nanoseconds: end.saturating_sub(start),
        };
        let starting_time = StartingTime {
            nanoseconds_since_epoch: start,
        };
        let count = self.topics.iter().map(|t| t.count).sum();
        BagInfo {
            version: METADATA_VERSION,
            storage_identifier: self.storage.identifier(),
            duration,
            starting_time,
            message_count: count,
            topics_with_message_count: self
                .topics
                .iter()
                .map(|t| TopicCount {
                    topic_metadata: TopicMetadata {
                        name: &t.spec.topic,
                        r#type: &t.spec.msg_type,
                        serialization_format: "cdr",
                        offered_qos_profiles: Vec::new(),
                        type_description_hash: &t.spec.type_hash,
                    },
                    message_count: t.count,
                })
                .collect(),
            compression_format: "",
            compression_mode: "",
            relative_file_paths: vec![&self.file_name],
            files: vec![FileInfo {
                path: &self.file_name,
                starting_time,
                duration,
                message_count: count,
            }],
            custom_data: None,
            ros_distro: ROS_DISTRO,
        }
    }

    /// Stores the metadata in the storage file, closes it and writes `metadata.yaml`.
    pub fn finish(self) -> Result<(), IoError> {
        let file = self.file();
        let yaml_err = |e: serde_saphyr::ser::Error| IoError::Invalid {
            path: self.dir.join(super::METADATA_FILE),
            msg: format!("writing YAML: {e}"),
        };
        let info = self.info();
        let inner = serde_saphyr::to_string(&info).map_err(yaml_err)?;
        let outer = serde_saphyr::to_string(&MetadataFile {
            rosbag2_bagfile_information: info,
        })
        .map_err(yaml_err)?;
        match self.store {
            Store::Sqlite(conn) => {
                conn.execute(
                    "INSERT INTO metadata (metadata_version, metadata) VALUES (?1, ?2)",
                    (METADATA_VERSION, inner.trim_end()),
                )
                .map_err(|e| sql_err(&file, "table metadata", e))?;
                conn.execute_batch("COMMIT")
                    .map_err(|e| sql_err(&file, "commit", e))?;
                conn.close().map_err(|(_, e)| sql_err(&file, "close", e))?;
            }
            Store::Mcap(mut w) => {
                let mut m = BTreeMap::new();
                m.insert("serialized_metadata".into(), inner.trim_end().to_string());
                w.write_metadata("rosbag2", m)?;
                w.finish()?;
            }
        }
        let meta = self.dir.join(super::METADATA_FILE);
        std::fs::write(&meta, outer).map_err(|e| IoError::io(&meta, e))
    }
}

impl ContainerWriter for Rosbag2Writer {
    fn add_topic(&mut self, spec: &TopicSpec) -> Result<usize, IoError> {
        let file = self.file();
        if spec.encoding != Encoding::Cdr {
            return Err(IoError::Invalid {
                path: file,
                msg: format!("topic {}: a ROS 2 bag holds CDR messages", spec.topic),
            });
        }
        let id = self.topics.len() + 1;
        match &mut self.store {
            Store::Sqlite(conn) => {
                let known = self.topics.iter().any(|t| t.spec.msg_type == spec.msg_type);
                if !known {
                    conn.execute(
                        "INSERT INTO message_definitions (topic_type, encoding, \
                         encoded_message_definition, type_description_hash) \
                         VALUES (?1, 'ros2msg', ?2, ?3)",
                        (&spec.msg_type, &spec.definition, &spec.type_hash),
                    )
                    .map_err(|e| sql_err(&file, "table message_definitions", e))?;
                }
                conn.execute(
                    "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', '[]', ?4)",
                    (id as i64, &spec.topic, &spec.msg_type, &spec.type_hash),
                )
                .map_err(|e| sql_err(&file, "table topics", e))?;
            }
            Store::Mcap(w) => {
                let mut m = BTreeMap::new();
                m.insert("offered_qos_profiles".to_string(), "[]".to_string());
                m.insert("topic_type_hash".to_string(), spec.type_hash.clone());
                w.set_channel_metadata(m);
                let k = w.add_topic(spec)?;
                debug_assert_eq!(k + 1, id);
            }
        }
        self.topics.push(Topic {
            spec: spec.clone(),
            count: 0,
        });
        Ok(id - 1)
    }

    fn write(&mut self, topic: usize, t_ns: i64, data: &[u8]) -> Result<(), IoError> {
        let file = self.file();
        let Some(t) = self.topics.get_mut(topic) else {
            return Err(IoError::Invalid {
                path: file,
                msg: format!("topic {topic} was not added"),
            });
        };
        match &mut self.store {
            Store::Sqlite(conn) => {
                let mut st = conn
                    .prepare_cached(INSERT_MESSAGE)
                    .map_err(|e| sql_err(&file, "table messages", e))?;
                st.execute(((topic + 1) as i64, t_ns, data)).map_err(|e| {
                    sql_err(&file, &format!("{} message {}", t.spec.topic, t.count), e)
                })?;
            }
            Store::Mcap(w) => w.write(topic, t_ns, data)?,
        }
        t.count += 1;
        self.span_ns = Some(match self.span_ns {
            Some((a, b)) => (a.min(t_ns), b.max(t_ns)),
            None => (t_ns, t_ns),
        });
        Ok(())
    }
}

#[derive(Serialize)]
struct MetadataFile<'a> {
    rosbag2_bagfile_information: BagInfo<'a>,
}

#[derive(Serialize, Clone, Copy)]
struct Duration {
    nanoseconds: i64,
}

#[derive(Serialize, Clone, Copy)]
struct StartingTime {
    nanoseconds_since_epoch: i64,
}

#[derive(Serialize)]
struct TopicMetadata<'a> {
    name: &'a str,
    r#type: &'a str,
    serialization_format: &'a str,
    offered_qos_profiles: Vec<BTreeMap<String, String>>,
    type_description_hash: &'a str,
}

#[derive(Serialize)]
struct TopicCount<'a> {
    topic_metadata: TopicMetadata<'a>,
    message_count: u64,
}

#[derive(Serialize)]
struct FileInfo<'a> {
    path: &'a str,
    starting_time: StartingTime,
    duration: Duration,
    message_count: u64,
}

#[derive(Serialize)]
struct BagInfo<'a> {
    version: u32,
    storage_identifier: &'a str,
    duration: Duration,
    starting_time: StartingTime,
    message_count: u64,
    topics_with_message_count: Vec<TopicCount<'a>>,
    compression_format: &'a str,
    compression_mode: &'a str,
    relative_file_paths: Vec<&'a str>,
    files: Vec<FileInfo<'a>>,
    custom_data: Option<BTreeMap<String, String>>,
    ros_distro: &'a str,
}
