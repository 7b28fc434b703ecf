//! ROS 1 bags (`.bag`, format 2.0, chunks uncompressed, bz2 or lz4) into a [`Recording`] (see
//! [`super::ros_assemble`] for the topics, frames and conventions). The topics and their
//! counts come from the bag's index first, so the topics can be chosen before reading.
//!
//! The file is memory-mapped and read one chunk at a time (each chunk is decompressed on its
//! own), through the `rosbag` crate. Before that, the bag header is checked here so that a
//! truncated file (whose index would lie past its end) is an error naming byte offsets rather
//! than a panic inside the crate. Errors name the byte offset (header), or the chunk and
//! record index (chunk section).

use super::IoError;
use super::account::InputAccount;
use super::options::ReaderOptions;
use super::ros_assemble::{RecordingBuilder, TopicInfo, TopicTable, choose_topics};
use super::ros_msgs::{Decoder, RosError};
use pfslam::sensors::Recording;
use rosbag::{ChunkRecord, IndexRecord, MessageRecord, RosBag};
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

/// Largest accepted ratio of a chunk's declared decompressed size to its stored size.
const MAX_COMPRESSION_RATIO: u64 = 256;

/// Walks the records of the chunk section and rejects chunks whose declared decompressed size
/// is implausible for their stored size: the `rosbag` crate allocates that size (a u32 taken
/// from the file) before decompressing, so a corrupt header would otherwise allocate up to
/// 4 GiB for a few bytes of input. Records running past the index are errors too.
fn check_chunk_sizes(path: &Path, start: u64, index_pos: u64) -> Result<(), RosError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let map = crate::kernels::memory_map::map_read_only(&file).map_err(|e| IoError::io(path, e))?;
    let end = usize::try_from(index_pos)
        .unwrap_or(usize::MAX)
        .min(map.len());
    let bytes = &map[..end];
    let u32_at = |at: usize| -> Option<usize> {
        bytes
            .get(at..at.checked_add(4)?)
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map(|b| u32::from_le_bytes(b) as usize)
    };
    let mut at = usize::try_from(start).unwrap_or(usize::MAX);
    while at < bytes.len() {
        let bad = |what: &str| RosError::format(path, format!("byte {at}"), what);
        let header_len = u32_at(at).ok_or_else(|| bad("record header cut by the index"))?;
        let header_at = at + 4;
        let header = bytes
            .get(header_at..header_at.saturating_add(header_len))
            .ok_or_else(|| bad("record header runs past the index"))?;
        let data_len_at = header_at + header_len;
        let data_len = u32_at(data_len_at).ok_or_else(|| bad("record data length cut"))?;
        let data_end = (data_len_at + 4)
            .checked_add(data_len)
            .filter(|&e| e <= bytes.len())
            .ok_or_else(|| bad("record data runs past the index"))?;
        let (mut op, mut size, mut compression) = (None, None, None);
        let mut p = 0usize;
        while let Some(l) = header
            .get(p..p + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        {
            let Some(field) = header.get(p + 4..(p + 4).saturating_add(l)) else {
                break;
            };
            if let Some(v) = field.strip_prefix(b"op=") {
                op = v.first().copied();
            } else if let Some(v) = field.strip_prefix(b"size=")
                && let Ok(b) = <[u8; 4]>::try_from(v)
            {
                size = Some(u64::from(u32::from_le_bytes(b)));
            } else if let Some(v) = field.strip_prefix(b"compression=") {
                compression = Some(v);
            }
            p += 4 + l;
        }
        if op == Some(0x05)
            && let Some(size) = size
        {
            let stored = data_len as u64;
            let limit = match compression {
                Some(b"none") => stored,
                _ => stored
                    .saturating_mul(MAX_COMPRESSION_RATIO)
                    .saturating_add(4096),
            };
            if size > limit {
                return Err(bad(&format!(
                    "chunk declares {size} decompressed bytes for {stored} stored bytes: corrupt"
                )));
            }
        }
        at = data_end;
    }
    Ok(())
}

/// Reads a ROS 1 bag into a [`Recording`].
pub fn read_ros1_bag(path: &Path, options: &ReaderOptions) -> Result<Recording, RosError> {
    read_ros1_bag_with_account(path, options).map(|(r, _)| r)
}

/// The bag's topics with their types and message counts, from its index, and its time span
/// (ns) when it has messages.
pub fn ros1_topics(path: &Path) -> Result<TopicTable, RosError> {
    let (start, index_pos) = check_header(path)?;
    check_chunk_sizes(path, start, index_pos)?;
    let bag = RosBag::new(path).map_err(|e| RosError::format(path, "byte 0", e.to_string()))?;
    let mut conns: Vec<(u32, TopicInfo)> = Vec::new();
    let mut span: Option<(i64, i64)> = None;
    let mut counts: HashMap<u32, usize> = HashMap::new();
    for (k, rec) in bag.index_records().enumerate() {
        let rec =
            rec.map_err(|e| RosError::format(path, format!("index record {k}"), e.to_string()))?;
        match rec {
            IndexRecord::Connection(c) => {
                if !conns.iter().any(|(id, _)| *id == c.id) {
                    conns.push((
                        c.id,
                        TopicInfo {
                            topic: c.topic.to_string(),
                            type_name: c.tp.to_string(),
                            count: 0,
                        },
                    ));
                }
            }
            IndexRecord::ChunkInfo(ci) => {
                let (a, b) = (ros_time_ns(ci.start_time), ros_time_ns(ci.end_time));
                span = Some(span.map_or((a, b), |(x, y)| (x.min(a), y.max(b))));
                for e in ci.entries() {
                    *counts.entry(e.conn_id).or_default() += e.count as usize;
                }
            }
            IndexRecord::IndexData(_) => {}
        }
    }
    // several connections may share a topic (one per publisher)
    let mut topics: Vec<TopicInfo> = Vec::new();
    for (id, t) in conns {
        let n = counts.get(&id).copied().unwrap_or(0);
        match topics
            .iter_mut()
            .find(|x| x.topic == t.topic && x.type_name == t.type_name)
        {
            Some(x) => x.count += n,
            None => topics.push(TopicInfo { count: n, ..t }),
        }
    }
    Ok(TopicTable {
        topics,
        span_ns: span,
    })
}

/// A bag time as the `rosbag` crate gives it (ns) as a signed stamp.
fn ros_time_ns(t: u64) -> i64 {
    i64::try_from(t).unwrap_or(i64::MAX)
}

/// Reads a ROS 1 bag into a [`Recording`], with what was read, dropped and repaired.
pub fn read_ros1_bag_with_account(
    path: &Path,
    options: &ReaderOptions,
) -> Result<(Recording, InputAccount), RosError> {
    let topics = ros1_topics(path)?.topics;
    let chosen =
        choose_topics(&topics, options).map_err(|e| RosError::format(path, "topics", e))?;
    let bag = RosBag::new(path).map_err(|e| RosError::format(path, "byte 0", e.to_string()))?;
    let mut acc = InputAccount::new("ros1_bag", path, "messages");
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
                    acc.records_read += 1;
                    let Some((topic, tp)) = conns.get(&md.conn_id) else {
                        return Err(RosError::format(
                            path,
                            pos(Some(ri)),
                            format!("message on unknown connection {}", md.conn_id),
                        ));
                    };
                    let err = |e: String| {
                        RosError::format(path, pos(Some(ri)), format!("{tp} on {topic}: {e}"))
                    };
                    let mut d = Decoder::ros1(md.data);
                    builder
                        .add_message(&chosen, options, topic, tp, &mut d)
                        .map_err(err)?;
                }
            }
        }
    }
    builder
        .finish(super::carmen::recording_name(path), &chosen, options, acc)
        .map_err(|e| RosError::format(path, "whole file", e))
}
