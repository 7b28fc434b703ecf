//! ROS 1 bags (`.bag`, format 2.0, chunks uncompressed, bz2 or lz4): `sensor_msgs/LaserScan`,
//! `nav_msgs/Odometry` and `/tf_static` into a [`Recording`] (see [`super::ros_msgs`] for the
//! options and conventions).
//!
//! The file is memory-mapped and read one chunk at a time (each chunk is decompressed on its
//! own), through the `rosbag` crate. Before that, the bag header is checked here so that a
//! truncated file (whose index would lie past its end) is an error naming byte offsets rather
//! than a panic inside the crate. Errors name the byte offset (header), or the chunk and
//! record index (chunk section).

use super::IoError;
use super::ros_msgs::{
    Decoder, RecordingBuilder, RosError, RosOptions, RosStats, decode_odometry, decode_scan,
    decode_tf,
};
use crate::sensors::Recording;
use rosbag::{ChunkRecord, MessageRecord, RosBag};
use std::collections::HashMap;
use std::path::Path;

const MAGIC: &[u8] = b"#ROSBAG V2.0\n";

/// Checks the bag header; returns `(first record offset, index_pos)`.
fn check_header(path: &Path) -> Result<(u64, u64), RosError> {
    let file_len = std::fs::metadata(path)
        .map_err(|e| IoError::io(path, e))?
        .len();
    let head = super::recording::read_head(path, 4096)?;
    if !head.starts_with(MAGIC) {
        return Err(RosError::format(
            path,
            "byte 0",
            "not a ROS 1 bag (missing \"#ROSBAG V2.0\")",
        ));
    }
    let at = MAGIC.len();
    let u32_at = |o: usize| -> Option<u32> {
        head.get(o..o + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let hlen = u32_at(at)
        .ok_or_else(|| RosError::format(path, format!("byte {at}"), "truncated bag header"))?
        as usize;
    let fields = head.get(at + 4..at + 4 + hlen).ok_or_else(|| {
        RosError::format(path, format!("byte {}", at + 4), "truncated bag header")
    })?;
    let mut index_pos = None;
    let mut p = 0;
    while p + 4 <= fields.len() {
        let l =
            u32::from_le_bytes([fields[p], fields[p + 1], fields[p + 2], fields[p + 3]]) as usize;
        let Some(field) = fields.get(p + 4..p + 4 + l) else {
            break;
        };
        if let Some(v) = field.strip_prefix(b"index_pos=")
            && v.len() == 8
        {
            let mut a = [0u8; 8];
            a.copy_from_slice(v);
            index_pos = Some(u64::from_le_bytes(a));
        }
        p += 4 + l;
    }
    let dlen_at = at + 4 + hlen;
    let dlen = u32_at(dlen_at)
        .ok_or_else(|| RosError::format(path, format!("byte {dlen_at}"), "truncated bag header"))?
        as u64;
    let start = dlen_at as u64 + 4 + dlen;
    let index_pos = index_pos.ok_or_else(|| {
        RosError::format(
            path,
            format!("byte {}", at + 4),
            "bag header has no index_pos",
        )
    })?;
    if index_pos < start || index_pos > file_len {
        return Err(RosError::format(
            path,
            format!("byte {}", at + 4),
            format!(
                "bag is truncated or unindexed: its header puts the index at byte {index_pos}, the file has {file_len} bytes (records start at byte {start})"
            ),
        ));
    }
    Ok((start, index_pos))
}

/// Reads a ROS 1 bag into a [`Recording`].
pub fn read_ros1_bag(path: &Path, options: &RosOptions) -> Result<Recording, RosError> {
    read_ros1_bag_with_stats(path, options).map(|(r, _)| r)
}

/// Reads a ROS 1 bag into a [`Recording`], with what was read and dropped.
pub fn read_ros1_bag_with_stats(
    path: &Path,
    options: &RosOptions,
) -> Result<(Recording, RosStats), RosError> {
    check_header(path)?;
    let bag = RosBag::new(path).map_err(|e| RosError::format(path, "byte 0", e.to_string()))?;
    let mut builder = RecordingBuilder::new();
    // conn id -> (topic, type)
    let mut conns: HashMap<u32, (String, String)> = HashMap::new();
    for (ci, rec) in bag.chunk_records().enumerate() {
        let pos = |ri: Option<usize>| match ri {
            Some(r) => format!("chunk {ci}, record {r}"),
            None => format!("chunk section record {ci}"),
        };
        let rec = rec.map_err(|e| RosError::format(path, pos(None), e.to_string()))?;
        let ChunkRecord::Chunk(chunk) = rec else {
            continue;
        };
        for (ri, m) in chunk.messages().enumerate() {
            let m = m.map_err(|e| RosError::format(path, pos(Some(ri)), e.to_string()))?;
            match m {
                MessageRecord::Connection(c) => {
                    conns.insert(c.id, (c.topic.to_string(), c.tp.to_string()));
                }
                MessageRecord::MessageData(md) => {
                    let Some((topic, tp)) = conns.get(&md.conn_id) else {
                        return Err(RosError::format(
                            path,
                            pos(Some(ri)),
                            format!("message on unknown connection {}", md.conn_id),
                        ));
                    };
                    let err = |what: &str, e: String| {
                        RosError::format(path, pos(Some(ri)), format!("{what} on {topic}: {e}"))
                    };
                    if *topic == options.scan_topic {
                        expect_type(path, &pos(Some(ri)), topic, tp, "sensor_msgs/LaserScan")?;
                        let scan = decode_scan(&mut Decoder::ros1(md.data))
                            .map_err(|e| err("LaserScan", e))?;
                        builder.add_scan(scan).map_err(|e| err("LaserScan", e))?;
                    } else if *topic == options.odom_topic {
                        expect_type(path, &pos(Some(ri)), topic, tp, "nav_msgs/Odometry")?;
                        let o = decode_odometry(&mut Decoder::ros1(md.data))
                            .map_err(|e| err("Odometry", e))?;
                        builder.add_odometry(o);
                    } else if *topic == options.tf_static_topic {
                        expect_type(path, &pos(Some(ri)), topic, tp, "tf2_msgs/TFMessage")?;
                        let t = decode_tf(&mut Decoder::ros1(md.data))
                            .map_err(|e| err("TFMessage", e))?;
                        builder.add_tf_static(t);
                    }
                }
            }
        }
    }
    builder
        .finish(super::carmen::recording_name(path), options)
        .map_err(|e| RosError::format(path, "whole file", e))
}

fn expect_type(path: &Path, pos: &str, topic: &str, tp: &str, want: &str) -> Result<(), RosError> {
    if tp == want {
        Ok(())
    } else {
        Err(RosError::format(
            path,
            pos,
            format!("topic {topic} carries {tp}, expected {want}"),
        ))
    }
}
