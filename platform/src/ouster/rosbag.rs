//! Ouster packets recorded by the `ouster_ros` driver in a ROS 1 bag: raw `ouster_ros/PacketMsg`
//! (`uint8[] buf`: a u32 length, then the UDP payload) on `…/lidar_packets` and
//! `…/imu_packets`, and the sensor metadata JSON as a `std_msgs/String` on `…/metadata`.
//!
//! Older drivers published each buffer one byte longer than the packet (a guard byte of their
//! receive buffer); a payload exactly one byte longer than the profile's packet is cut to size.

use super::{decode_imu, Decoder, Metadata, OusterCapture, OusterError, SweepAssembler};
use crate::rosbag1::Bag;
use crate::IoError;
use std::collections::HashSet;
use std::path::Path;

/// The `uint8[]` (or `string`) that is a message's only field: its bytes.
fn only_array(msg: &[u8]) -> Result<&[u8], OusterError> {
    let n = msg
        .get(..4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        .ok_or_else(|| OusterError::Packet(format!("message of {} bytes", msg.len())))?;
    msg.get(4..).filter(|rest| rest.len() == n).ok_or_else(|| {
        OusterError::Packet(format!(
            "message array of {n} bytes in a message of {} bytes",
            msg.len()
        ))
    })
}

/// The one connection set whose topic ends with `suffix` and has type `msg_type`.
fn topic_conns(
    bag: &Bag,
    path: &Path,
    suffix: &str,
    msg_type: &str,
) -> Result<HashSet<u32>, IoError> {
    let mut topics: Vec<&str> = bag
        .connections
        .values()
        .filter(|c| c.topic.ends_with(suffix) && c.msg_type == msg_type)
        .map(|c| c.topic.as_str())
        .collect();
    topics.sort_unstable();
    topics.dedup();
    match topics.as_slice() {
        [t] => Ok(bag.topic_conns(t)),
        [] => Err(IoError::Invalid {
            path: path.to_path_buf(),
            msg: format!("no {msg_type} topic ending with {suffix}"),
        }),
        many => Err(IoError::Invalid {
            path: path.to_path_buf(),
            msg: format!("several {msg_type} topics ending with {suffix}: {many:?}"),
        }),
    }
}

/// Reads an `ouster_ros` raw-packet bag: the metadata from its metadata topic, the lidar packets
/// into sweeps (receipt order) and the IMU packets. Packets that do not decode are skipped and
/// counted ([`OusterCapture::bad_packets`]).
pub fn read_bag(path: &Path) -> Result<(Metadata, OusterCapture), IoError> {
    let bag = Bag::open(path)?;
    let meta_conns = topic_conns(&bag, path, "metadata", "std_msgs/String")?;
    let lidar = topic_conns(&bag, path, "lidar_packets", "ouster_ros/PacketMsg")?;
    let imu = topic_conns(&bag, path, "imu_packets", "ouster_ros/PacketMsg")?;
    let invalid = |msg: String| IoError::Invalid {
        path: path.to_path_buf(),
        msg,
    };
    let first = bag
        .conn_messages(meta_conns)
        .next()
        .ok_or_else(|| invalid("the metadata topic has no message".into()))??;
    let text = only_array(&first.data)
        .ok()
        .and_then(|b| std::str::from_utf8(b).ok())
        .ok_or_else(|| invalid("the metadata message is not a string".into()))?;
    let meta = Metadata::from_json(text).map_err(|e| invalid(format!("metadata topic: {e}")))?;
    let decoder = Decoder::new(&meta);
    let size = decoder.lidar_packet_bytes();
    let mut asm = SweepAssembler::new(&meta);
    let mut out = OusterCapture::default();
    for m in bag.conn_messages(lidar.union(&imu).copied().collect()) {
        let m = m?;
        let buf = match only_array(&m.data) {
            Ok(b) => b,
            Err(e) => {
                out.bad(e);
                continue;
            }
        };
        if lidar.contains(&m.conn) {
            let buf = if buf.len() == size + 1 {
                &buf[..size]
            } else {
                buf
            };
            match decoder.decode_lidar(buf) {
                Ok(p) => out.scans.extend(asm.push(&p)),
                Err(e) => out.bad(e),
            }
        } else {
            let buf = if buf.len() == super::packet::IMU_PACKET_BYTES + 1 {
                &buf[..super::packet::IMU_PACKET_BYTES]
            } else {
                buf
            };
            match decode_imu(buf) {
                Ok(p) => out.imu.push(p),
                Err(e) => out.bad(e),
            }
        }
    }
    out.scans.extend(asm.finish());
    out.counts = asm.counts();
    Ok((meta, out))
}
