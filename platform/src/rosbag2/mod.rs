//! ROS 2 bags as a [`MessageLog`]: a bag folder (its `metadata.yaml`,
//! `rosbag2_bagfile_information`: `storage_identifier` `sqlite3` or `mcap`, `relative_file_paths`
//! chained in their order for a split bag, `topics_with_message_count` checked against the
//! files), or a bare `.db3` file. sqlite3 storage is read with SQLite ([`sqlite`]); MCAP storage
//! files are MCAP files ([`crate::mcap_log::McapLog`]). Messages are CDR.
//!
//! Topics and counts come from the storage files themselves (a bag whose recorder was killed
//! has no `metadata.yaml`, or a stale one): a count that disagrees with `metadata.yaml` is a
//! warning. A topic's messages are those of each file in turn, in log-time order within a file
//! (split files follow each other in time).

pub mod sqlite;
#[cfg(test)]
mod tests;
pub mod write;

use crate::error::IoError;
use crate::mcap_log::McapLog;
use crate::rosrec::{LogStream, MessageLog, TopicInfo};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The metadata file of a bag folder.
pub const METADATA_FILE: &str = "metadata.yaml";

#[derive(Debug, Deserialize)]
struct MetadataFile {
    rosbag2_bagfile_information: BagInfo,
}

#[derive(Debug, Deserialize)]
struct BagInfo {
    storage_identifier: String,
    #[serde(default)]
    relative_file_paths: Vec<String>,
    #[serde(default)]
    topics_with_message_count: Vec<TopicCount>,
}

#[derive(Debug, Deserialize)]
struct TopicCount {
    topic_metadata: TopicMetadata,
    #[serde(default)]
    message_count: u64,
}

#[derive(Debug, Deserialize)]
struct TopicMetadata {
    name: String,
}

/// A ROS 2 bag (see the module docs).
#[derive(Debug)]
pub struct Rosbag2 {
    path: PathBuf,
    storage: String,
    files: Vec<Box<dyn MessageLog>>,
    warnings: Vec<String>,
}

/// Whether `path` is a ROS 2 bag folder (it holds `metadata.yaml`).
pub fn is_bag_folder(path: &Path) -> bool {
    path.is_dir() && path.join(METADATA_FILE).is_file()
}

impl Rosbag2 {
    /// Opens a bag folder or a bare `.db3` file.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        if !path.is_dir() {
            let file = sqlite::Db3::open(path)?;
            return Ok(Rosbag2 {
                path: path.to_path_buf(),
                storage: "sqlite3".into(),
                files: vec![Box::new(file)],
                warnings: Vec::new(),
            });
        }
        let meta_path = path.join(METADATA_FILE);
        let text = std::fs::read_to_string(&meta_path).map_err(|e| IoError::io(&meta_path, e))?;
        let meta: MetadataFile = serde_saphyr::from_str(&text).map_err(|e| IoError::Parse {
            path: meta_path.clone(),
            line: e.location().map_or(0, |l| l.line() as usize),
            msg: e.to_string(),
        })?;
        let info = meta.rosbag2_bagfile_information;
        if info.relative_file_paths.is_empty() {
            return Err(IoError::Invalid {
                path: meta_path,
                msg: "relative_file_paths lists no storage file".into(),
            });
        }
        let mut files: Vec<Box<dyn MessageLog>> = Vec::new();
        for rel in &info.relative_file_paths {
            // Older bags list the path with the folder's name in front.
            let mut p = path.join(rel);
            if !p.exists() {
                if let Some(name) = Path::new(rel).file_name() {
                    p = path.join(name);
                }
            }
            match info.storage_identifier.as_str() {
                "sqlite3" => files.push(Box::new(sqlite::Db3::open(&p)?)),
                "mcap" => files.push(Box::new(McapLog::open(&p)?)),
                other => {
                    return Err(IoError::Invalid {
                        path: meta_path,
                        msg: format!(
                            "storage_identifier {other:?}: povins reads sqlite3 and mcap bags"
                        ),
                    })
                }
            }
        }
        let mut bag = Rosbag2 {
            path: path.to_path_buf(),
            storage: info.storage_identifier,
            files,
            warnings: Vec::new(),
        };
        let topics = bag.topics();
        for tc in &info.topics_with_message_count {
            let name = &tc.topic_metadata.name;
            let n: u64 = topics
                .iter()
                .filter(|t| &t.topic == name)
                .map(|t| t.count)
                .sum();
            if n != tc.message_count {
                bag.warnings.push(format!(
                    "{}: topic {name}: metadata.yaml counts {} messages, the storage files \
                     hold {n}",
                    meta_path.display(),
                    tc.message_count
                ));
            }
        }
        Ok(bag)
    }
}

impl MessageLog for Rosbag2 {
    fn path(&self) -> &Path {
        &self.path
    }

    fn locate(&self, offset: u64) -> String {
        match self.files.first() {
            Some(f) => f.locate(offset),
            None => format!("record {offset}"),
        }
    }

    fn describe(&self) -> String {
        let parts: Vec<String> = self.files.iter().map(|f| f.describe()).collect();
        format!(
            "ROS 2 bag, {} storage, {} file{}: {}",
            self.storage,
            self.files.len(),
            if self.files.len() == 1 { "" } else { "s" },
            parts.join("; ")
        )
    }

    fn topics(&self) -> Vec<TopicInfo> {
        let mut out: Vec<TopicInfo> = Vec::new();
        for t in self.files.iter().flat_map(|f| f.topics()) {
            match out
                .iter_mut()
                .find(|o| o.topic == t.topic && o.msg_type == t.msg_type)
            {
                Some(o) => {
                    o.count += t.count;
                    o.span_ns = match (o.span_ns, t.span_ns) {
                        (Some(a), Some(b)) => Some((a.0.min(b.0), a.1.max(b.1))),
                        (a, b) => a.or(b),
                    };
                }
                None => out.push(t),
            }
        }
        out.sort_by(|a, b| (&a.topic, &a.msg_type).cmp(&(&b.topic, &b.msg_type)));
        out
    }

    fn messages(&self, topic: &str) -> LogStream<'_> {
        let topic = topic.to_string();
        Box::new(self.files.iter().flat_map(move |f| f.messages(&topic)))
    }

    fn warnings(&self) -> Vec<String> {
        let mut w = self.warnings.clone();
        w.extend(self.files.iter().flat_map(|f| f.warnings()));
        w
    }
}
