//! A ROS 1 bag as a [`MessageLog`]: its topics from the connections and the chunks' counts, a
//! topic's messages through [`super::chunk::Messages`].

use super::Bag;
use crate::rosrec::{normalize_type, Encoding, LogMessage, LogStream, MessageLog, TopicInfo};
use std::path::Path;

impl MessageLog for Bag {
    fn path(&self) -> &Path {
        &self.path
    }

    fn describe(&self) -> String {
        let index = if self.indexed {
            "indexed"
        } else {
            "no usable index: scanned"
        };
        format!("ROS 1 bag v2.0, {index}, {} chunks", self.chunks.len())
    }

    fn topics(&self) -> Vec<TopicInfo> {
        let mut out: Vec<TopicInfo> = Vec::new();
        for c in self.connections.values() {
            let n = self.count(c.id);
            let span = self
                .chunks
                .iter()
                .filter(|k| k.counts.iter().any(|(id, n)| *id == c.id && *n > 0))
                .map(|k| (k.start_ns, k.end_ns))
                .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)));
            let msg_type = normalize_type(&c.msg_type);
            match out
                .iter_mut()
                .find(|t| t.topic == c.topic && t.msg_type == msg_type)
            {
                Some(t) => {
                    t.count += n;
                    t.span_ns = match (t.span_ns, span) {
                        (Some(a), Some(b)) => Some((a.0.min(b.0), a.1.max(b.1))),
                        (a, b) => a.or(b),
                    };
                }
                None => out.push(TopicInfo {
                    topic: c.topic.clone(),
                    msg_type,
                    encoding: Encoding::Ros1,
                    count: n,
                    span_ns: span,
                }),
            }
        }
        out.sort_by(|a, b| (&a.topic, &a.msg_type).cmp(&(&b.topic, &b.msg_type)));
        out
    }

    fn messages(&self, topic: &str) -> LogStream<'_> {
        Box::new(self.conn_messages(self.topic_conns(topic)).map(|m| {
            m.map(|m| LogMessage {
                log_time_ns: m.time_ns,
                offset: m.chunk_pos,
                data: m.data,
            })
        }))
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }
}
