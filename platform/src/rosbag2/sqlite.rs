//! One sqlite3 storage file of a ROS 2 bag (`.db3`): tables `topics` (id, name, type,
//! serialization_format) and `messages` (id, topic_id, timestamp, data). The file is opened
//! read-only; topics and counts are read at open, and a topic's messages are read in pages of
//! [`PAGE_ROWS`] rows in (timestamp, id) order, each page a new query that borrows nothing across
//! the iteration, so memory stays bounded whatever the file's length. A message's
//! [`LogMessage::offset`] is its row id (SQLite has no stable byte offset for a row).

use crate::error::IoError;
use crate::rosrec::{normalize_type, Encoding, LogMessage, LogStream, MessageLog, TopicInfo};
use rusqlite::{Connection, OpenFlags};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};

/// Rows read per query.
pub const PAGE_ROWS: i64 = 32;

/// A `.db3` file (see the module docs).
#[derive(Debug)]
pub struct Db3 {
    path: PathBuf,
    /// (topic id, topic).
    topics: Vec<(i64, TopicInfo)>,
}

fn sql_err(path: &Path, what: &str, e: rusqlite::Error) -> IoError {
    IoError::Invalid {
        path: path.to_path_buf(),
        msg: format!("sqlite3 bag: {what}: {e}"),
    }
}

fn connect(path: &Path) -> Result<Connection, IoError> {
    Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(|e| sql_err(path, "open", e))
}

impl Db3 {
    /// Opens a `.db3` file and reads its topics and their counts.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        if !path.is_file() {
            return Err(IoError::Invalid {
                path: path.to_path_buf(),
                msg: "no such sqlite3 bag file".into(),
            });
        }
        let conn = connect(path)?;
        let err = |what: &str| {
            let what = what.to_string();
            move |e| sql_err(path, &what, e)
        };
        let mut topics = Vec::new();
        {
            let mut st = conn
                .prepare("SELECT id, name, type, serialization_format FROM topics ORDER BY id")
                .map_err(err("table topics"))?;
            let rows = st
                .query_map([], |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        r.get::<_, String>(1)?,
                        r.get::<_, String>(2)?,
                        r.get::<_, String>(3)?,
                    ))
                })
                .map_err(err("table topics"))?;
            for row in rows {
                let (id, name, ty, format) = row.map_err(err("table topics"))?;
                let (msg_type, encoding) = match format.as_str() {
                    "cdr" => (normalize_type(&ty), Encoding::Cdr),
                    other => (
                        format!("{} ({other} encoding, not read)", normalize_type(&ty)),
                        Encoding::Cdr,
                    ),
                };
                topics.push((
                    id,
                    TopicInfo {
                        topic: name,
                        msg_type,
                        encoding,
                        count: 0,
                        span_ns: None,
                    },
                ));
            }
        }
        let mut st = conn
            .prepare(
                "SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) FROM messages \
                 GROUP BY topic_id",
            )
            .map_err(err("table messages"))?;
        let rows = st
            .query_map([], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, i64>(2)?,
                    r.get::<_, i64>(3)?,
                ))
            })
            .map_err(err("table messages"))?;
        for row in rows {
            let (id, n, t0, t1) = row.map_err(err("table messages"))?;
            if let Some((_, t)) = topics.iter_mut().find(|(tid, _)| *tid == id) {
                t.count = u64::try_from(n).unwrap_or(0);
                t.span_ns = Some((t0, t1));
            }
        }
        Ok(Db3 {
            path: path.to_path_buf(),
            topics,
        })
    }
}

impl MessageLog for Db3 {
    fn path(&self) -> &Path {
        &self.path
    }

    fn locate(&self, offset: u64) -> String {
        format!("row id {offset} of the messages table")
    }

    fn describe(&self) -> String {
        format!("sqlite3 file {}", self.path.display())
    }

    fn topics(&self) -> Vec<TopicInfo> {
        let mut out: Vec<TopicInfo> = self.topics.iter().map(|(_, t)| t.clone()).collect();
        out.sort_by(|a, b| (&a.topic, &a.msg_type).cmp(&(&b.topic, &b.msg_type)));
        out
    }

    fn messages(&self, topic: &str) -> LogStream<'_> {
        let ids: Vec<i64> = self
            .topics
            .iter()
            .filter(|(_, t)| t.topic == topic && !t.msg_type.ends_with("not read)"))
            .map(|(id, _)| *id)
            .collect();
        Box::new(Pages {
            path: &self.path,
            topic: topic.to_string(),
            conn: None,
            ids,
            after: (i64::MIN, i64::MIN),
            buf: VecDeque::new(),
            done: false,
        })
    }

    fn warnings(&self) -> Vec<String> {
        Vec::new()
    }
}

/// A topic's rows, a page at a time.
struct Pages<'a> {
    path: &'a Path,
    topic: String,
    conn: Option<Connection>,
    ids: Vec<i64>,
    /// (timestamp, id) of the last row read.
    after: (i64, i64),
    buf: VecDeque<LogMessage>,
    done: bool,
}

impl Pages<'_> {
    fn fill(&mut self) -> Result<(), IoError> {
        if self.conn.is_none() {
            self.conn = Some(connect(self.path)?);
        }
        let Some(conn) = self.conn.as_ref() else {
            return Ok(());
        };
        let ids: Vec<String> = self.ids.iter().map(i64::to_string).collect();
        let sql = format!(
            "SELECT timestamp, id, data FROM messages WHERE topic_id IN ({}) AND \
             (timestamp > ?1 OR (timestamp = ?1 AND id > ?2)) ORDER BY timestamp, id LIMIT ?3",
            ids.join(",")
        );
        let what = format!("messages of {} after row id {}", self.topic, self.after.1);
        let err = |e| sql_err(self.path, &what, e);
        let mut st = conn.prepare_cached(&sql).map_err(err)?;
        let rows = st
            .query_map((self.after.0, self.after.1, PAGE_ROWS), |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, Vec<u8>>(2)?,
                ))
            })
            .map_err(err)?;
        for row in rows {
            let (t, id, data) = row.map_err(err)?;
            self.after = (t, id);
            self.buf.push_back(LogMessage {
                log_time_ns: t,
                offset: u64::try_from(id).unwrap_or(0),
                data,
            });
        }
        Ok(())
    }
}

impl Iterator for Pages<'_> {
    type Item = Result<LogMessage, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done || self.ids.is_empty() {
            return None;
        }
        if self.buf.is_empty() {
            if let Err(e) = self.fill() {
                self.done = true;
                return Some(Err(e));
            }
        }
        let m = self.buf.pop_front();
        if m.is_none() {
            self.done = true;
        }
        m.map(Ok)
    }
}
