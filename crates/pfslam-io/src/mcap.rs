//! ROS 2 recordings in MCAP (`.mcap`, CDR-encoded) into a [`Recording`] (see
//! [`super::ros_assemble`] for the topics, frames and conventions), and a small writer of such
//! files (used by the tests to make MCAP files from real bags, since no real MCAP is at hand).
//!
//! The file is memory-mapped and its messages are visited in file order, chunk by chunk (each
//! chunk decompressed on its own) by the `mcap` crate. Errors name the message index.

use super::IoError;
use super::account::InputAccount;
use super::options::ReaderOptions;
use super::ros_assemble::{RecordingBuilder, TopicInfo, TopicTable, choose_topics};
use super::ros_msgs::{Decoder, OdomMsg, RosError, ScanMsg, encode};
use pfslam::sensors::Recording;
use std::collections::BTreeMap;
use std::path::Path;

/// Largest decompressed chunk accepted (bytes).
const MAX_CHUNK_BYTES: u64 = 1 << 30;
/// Largest accepted ratio of decompressed to compressed chunk size.
const MAX_COMPRESSION_RATIO: u64 = 256;

/// Walks the top-level records and rejects chunks whose declared decompressed size is
/// implausible: the `mcap` crate allocates that size before decompressing, so a corrupt
/// header would otherwise abort the process on a failed allocation instead of giving an
/// error. A record that runs past the end of the file is an error too.
fn check_chunk_sizes(bytes: &[u8], path: &Path) -> Result<(), RosError> {
    const MAGIC_LEN: usize = 8;
    const OP_FOOTER: u8 = 0x02;
    const OP_CHUNK: u8 = 0x06;
    let u64_at = |at: usize| -> Option<u64> {
        bytes
            .get(at..at + 8)
            .and_then(|b| <[u8; 8]>::try_from(b).ok())
            .map(u64::from_le_bytes)
    };
    let u32_at = |at: usize| -> Option<u32> {
        bytes
            .get(at..at + 4)
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map(u32::from_le_bytes)
    };
    let mut at = MAGIC_LEN;
    while at + 9 <= bytes.len() {
        let op = bytes[at];
        let Some(len) = u64_at(at + 1) else { break };
        let body = at + 9;
        let end = usize::try_from(len).ok().and_then(|l| body.checked_add(l));
        let Some(end) = end.filter(|&e| e <= bytes.len()) else {
            return Err(RosError::format(
                path,
                format!("byte {at}"),
                format!("record (opcode 0x{op:02x}) of {len} bytes runs past the end of the file"),
            ));
        };
        if op == OP_FOOTER {
            break;
        }
        check_record_fields(op, &bytes[body..end]).map_err(|()| {
            RosError::format(
                path,
                format!("byte {at}"),
                format!("a length inside the record (opcode 0x{op:02x}) runs past its end"),
            )
        })?;
        if op == OP_CHUNK {
            // message_start_time u64, message_end_time u64, uncompressed_size u64,
            // uncompressed_crc u32, compression string, records (u64 length + bytes)
            let bad = |what: String| RosError::format(path, format!("byte {at}"), what);
            let uncompressed = u64_at(body + 16).ok_or_else(|| bad("chunk header cut".into()))?;
            let comp_len = u32_at(body + 28).ok_or_else(|| bad("chunk header cut".into()))?;
            let records_at = body + 32 + comp_len as usize;
            let records_len = u64_at(records_at).ok_or_else(|| bad("chunk header cut".into()))?;
            let limit = if comp_len == 0 {
                records_len
            } else {
                records_len
                    .saturating_mul(MAX_COMPRESSION_RATIO)
                    .saturating_add(4096)
                    .min(MAX_CHUNK_BYTES)
            };
            if uncompressed > limit {
                return Err(bad(format!(
                    "chunk declares {uncompressed} decompressed bytes for {records_len} stored \
                     bytes: corrupt"
                )));
            }
            let comp_at = body + 32;
            let compression = &bytes[comp_at..records_at];
            let data_at = records_at + 8;
            let data_end = usize::try_from(records_len)
                .ok()
                .and_then(|l| data_at.checked_add(l))
                .filter(|&e| e <= end)
                .ok_or_else(|| bad("chunk records run past the chunk".into()))?;
            let stored = &bytes[data_at..data_end];
            let content = decompress_chunk(compression, stored, uncompressed as usize)
                .map_err(|e| bad(format!("chunk does not decompress: {e}")))?;
            check_inner_records(&content).map_err(|off| {
                bad(format!(
                    "record at offset {off} inside the chunk is corrupt: its length, or a \
                     length inside it, runs past its end"
                ))
            })?;
        }
        at = end;
    }
    Ok(())
}

/// Decompresses a chunk's records with a known output size (already checked to be sane).
fn decompress_chunk<'a>(
    compression: &[u8],
    stored: &'a [u8],
    uncompressed: usize,
) -> Result<std::borrow::Cow<'a, [u8]>, String> {
    use std::io::Read;
    match compression {
        b"" => Ok(std::borrow::Cow::Borrowed(stored)),
        b"zstd" => zstd::bulk::decompress(stored, uncompressed)
            .map(std::borrow::Cow::Owned)
            .map_err(|e| e.to_string()),
        b"lz4" => {
            let mut out = Vec::with_capacity(uncompressed);
            lz4::Decoder::new(stored)
                .map_err(|e| e.to_string())?
                .take(uncompressed as u64 + 1)
                .read_to_end(&mut out)
                .map_err(|e| e.to_string())?;
            Ok(std::borrow::Cow::Owned(out))
        }
        other => Err(format!(
            "unsupported compression {:?}",
            String::from_utf8_lossy(other)
        )),
    }
}

/// Checks that every record inside decompressed chunk content ends inside it (the `mcap` crate
/// reserves a record's declared length before reading it). Returns the offset of a bad record.
fn check_inner_records(content: &[u8]) -> Result<(), usize> {
    let mut at = 0usize;
    while at < content.len() {
        let len = content
            .get(at + 1..at + 9)
            .and_then(|b| <[u8; 8]>::try_from(b).ok())
            .map(u64::from_le_bytes)
            .ok_or(at)?;
        let end = usize::try_from(len)
            .ok()
            .and_then(|l| (at + 9).checked_add(l))
            .filter(|&e| e <= content.len())
            .ok_or(at)?;
        check_record_fields(content[at], &content[at + 9..end]).map_err(|_| at)?;
        at = end;
    }
    Ok(())
}

/// One field of a record, as the MCAP specification lays them out.
#[derive(Clone, Copy)]
enum Field {
    /// A fixed-size field of this many bytes.
    Fixed(usize),
    /// A `u32` byte length, then that many bytes (strings, byte arrays, fixed-size maps).
    Len32,
    /// A `u64` byte length, then that many bytes.
    Len64,
    /// A `u32` byte length, then `(string, string)` entries filling exactly that length.
    StringMap,
    /// A `u32` byte length, then entries of this many bytes filling exactly that length.
    Entries(usize),
    /// A fixed-size field that must be there: the crate slices it without a check.
    Required(usize),
}

/// The length-prefixed layout of the records the reader may meet (a Message has none to
/// check; a Chunk's records are checked apart, but a chunk nested in a chunk only here);
/// `None` for opcodes without one.
fn record_layout(op: u8) -> Option<&'static [Field]> {
    use Field::{Entries, Fixed, Len32, Len64, Required, StringMap};
    Some(match op {
        0x01 => &[Len32, Len32],                                // Header
        0x03 => &[Fixed(2), Len32, Len32, Len32],               // Schema
        0x04 => &[Fixed(4), Len32, Len32, StringMap],           // Channel
        0x06 => &[Fixed(28), Len32, Len64],                     // Chunk
        0x07 => &[Fixed(2), Entries(16)],                       // Message Index: (u64, u64)
        0x08 => &[Fixed(32), Entries(10), Fixed(8), Len32],     // Chunk Index: u16 -> u64
        0x09 => &[Fixed(16), Len32, Len32, Len64, Required(4)], // Attachment, its CRC
        0x0A => &[Fixed(40), Len32, Len32],                     // Attachment Index
        0x0B => &[Fixed(42), Entries(10)],                      // Statistics: u16 -> u64
        0x0C => &[Len32, StringMap],                            // Metadata
        0x0D => &[Fixed(16), Len32],                            // Metadata Index
        _ => return None,
    })
}

/// Checks that every length-prefixed field of a record ends inside the record: the `mcap`
/// crate reserves a declared string or array length before reading it, so one corrupt
/// length would otherwise abort the process on a failed allocation. A record too short for
/// its fixed fields is left to the crate, which reports it.
fn check_record_fields(op: u8, record: &[u8]) -> Result<(), ()> {
    let Some(layout) = record_layout(op) else {
        return Ok(());
    };
    let mut at = 0usize;
    for field in layout {
        let (prefix, len) = match field {
            Field::Fixed(n) | Field::Required(n) => (0, *n as u64),
            Field::Len32 | Field::StringMap | Field::Entries(_) => match record.get(at..at + 4) {
                Some(b) => (4, u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))),
                None => return Ok(()),
            },
            Field::Len64 => match record
                .get(at..at + 8)
                .and_then(|b| <[u8; 8]>::try_from(b).ok())
            {
                Some(b) => (8, u64::from_le_bytes(b)),
                None => return Ok(()),
            },
        };
        let start = at + prefix;
        let end = usize::try_from(len)
            .ok()
            .and_then(|l| start.checked_add(l))
            .filter(|&e| e <= record.len());
        let Some(end) = end else {
            // A fixed field cut short is the crate's to report (but for those it slices
            // without a check); a length is ours.
            let required = matches!(field, Field::Required(_));
            return if prefix == 0 && !required {
                Ok(())
            } else {
                Err(())
            };
        };
        // The crate reads whole entries until it passes the length: a partial one would
        // shift every field after it.
        if let Field::Entries(size) = field
            && !(end - start).is_multiple_of(*size)
        {
            return Err(());
        }
        if matches!(field, Field::StringMap) {
            let map = &record[start..end];
            let mut k = 0usize;
            while k < map.len() {
                for _ in 0..2 {
                    let n = map
                        .get(k..k + 4)
                        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
                        .ok_or(())?;
                    k = (k + 4)
                        .checked_add(n)
                        .filter(|&e| e <= map.len())
                        .ok_or(())?;
                }
            }
        }
        at = end;
    }
    Ok(())
}

/// Reads an MCAP file into a [`Recording`].
pub fn read_mcap(path: &Path, options: &ReaderOptions) -> Result<Recording, RosError> {
    read_mcap_with_account(path, options).map(|(r, _)| r)
}

/// Maps an MCAP file after checking its chunks (see [`check_chunk_sizes`]).
fn map_checked(path: &Path) -> Result<memmap2::Mmap, RosError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let map = crate::kernels::memory_map::map_read_only(&file).map_err(|e| IoError::io(path, e))?;
    check_chunk_sizes(&map, path)?;
    Ok(map)
}

/// Visits every message in file order with its index, topic, type name and encoding.
fn for_each_message(
    path: &Path,
    map: &[u8],
    mut f: impl FnMut(usize, &::mcap::Message<'_>, &str) -> Result<(), RosError>,
) -> Result<(), RosError> {
    let stream = ::mcap::MessageStream::new(map)
        .map_err(|e| RosError::format(path, "byte 0", e.to_string()))?;
    for (k, msg) in stream.enumerate() {
        let msg = msg.map_err(|e| RosError::format(path, format!("message {k}"), e.to_string()))?;
        let type_name = msg
            .channel
            .schema
            .as_ref()
            .map_or_else(String::new, |s| s.name.clone());
        f(k, &msg, &type_name)?;
    }
    Ok(())
}

/// The file's topics with their types and message counts, and its time span (ns, by the
/// messages' log times) when it has messages.
pub fn mcap_topics(path: &Path) -> Result<TopicTable, RosError> {
    topics_in(path, &map_checked(path)?)
}

/// [`mcap_topics`] of an already mapped and checked file.
fn topics_in(path: &Path, map: &[u8]) -> Result<TopicTable, RosError> {
    let mut topics: Vec<TopicInfo> = Vec::new();
    let mut span: Option<(i64, i64)> = None;
    for_each_message(path, map, |_, msg, type_name| {
        let t = i64::try_from(msg.log_time).unwrap_or(i64::MAX);
        span = Some(span.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
        let topic = msg.channel.topic.as_str();
        match topics.iter_mut().find(|x| x.topic == topic) {
            Some(x) => x.count += 1,
            None => topics.push(TopicInfo {
                topic: topic.to_string(),
                type_name: type_name.to_string(),
                count: 1,
            }),
        }
        Ok(())
    })?;
    Ok(TopicTable {
        topics,
        span_ns: span,
    })
}

/// Reads a MCAP file into a [`Recording`], with what was read, dropped and repaired.
pub fn read_mcap_with_account(
    path: &Path,
    options: &ReaderOptions,
) -> Result<(Recording, InputAccount), RosError> {
    mcap_with_account(&map_checked(path)?, path, options)
}

/// [`read_mcap_with_account`] on the file's bytes; `path` names it in errors.
pub fn read_mcap_from_bytes(
    bytes: &[u8],
    path: &Path,
    options: &ReaderOptions,
) -> Result<(Recording, InputAccount), RosError> {
    check_chunk_sizes(bytes, path)?;
    mcap_with_account(bytes, path, options)
}

/// Reads checked MCAP bytes.
fn mcap_with_account(
    map: &[u8],
    path: &Path,
    options: &ReaderOptions,
) -> Result<(Recording, InputAccount), RosError> {
    let topics = topics_in(path, map)?.topics;
    let chosen =
        choose_topics(&topics, options).map_err(|e| RosError::format(path, "topics", e))?;
    let mut acc = InputAccount::new("mcap", path, "messages");
    let mut builder = RecordingBuilder::new();
    for_each_message(path, map, |k, msg, type_name| {
        acc.records_read += 1;
        let topic = msg.channel.topic.as_str();
        if !chosen.uses(topic) {
            return Ok(());
        }
        let pos = format!("message {k}");
        if msg.channel.message_encoding != "cdr" {
            return Err(RosError::format(
                path,
                pos,
                format!(
                    "topic {topic}: message encoding {:?}, only \"cdr\" is supported",
                    msg.channel.message_encoding
                ),
            ));
        }
        let err = |e: String| RosError::format(path, &pos, format!("{type_name} on {topic}: {e}"));
        let mut d = Decoder::cdr(&msg.data).map_err(err)?;
        builder
            .add_message(&chosen, options, topic, type_name, &mut d)
            .map_err(err)
    })?;
    builder
        .finish(super::carmen::recording_name(path), &chosen, options, acc)
        .map_err(|e| RosError::format(path, "whole file", e))
}

/// The topics [`write_mcap_with`] writes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct McapTopics {
    /// The scans' topic.
    pub scan: String,
    /// The odometry's topic; `None` writes the odometry as `/tf` transforms `odom ->
    /// base_link` instead.
    pub odom: Option<String>,
    /// The topic of `sensor_msgs/Imu` messages made from the recording's `imu_yaw` (as
    /// orientations), when set.
    pub imu: Option<String>,
}

/// Writes the scans and odometry of `recording` as an MCAP file of CDR messages on the topics
/// of `options` (`/scan`, `/odom` when unset), atomically; see [`write_mcap_with`].
pub fn write_mcap(
    path: &Path,
    recording: &Recording,
    options: &ReaderOptions,
) -> Result<(), RosError> {
    let topics = McapTopics {
        scan: options.scan_topic.clone().unwrap_or_else(|| "/scan".into()),
        odom: Some(options.odom_topic.clone().unwrap_or_else(|| "/odom".into())),
        imu: None,
    };
    write_mcap_with(path, recording, &topics)
}

/// Writes the scans and odometry of `recording` as an MCAP file of CDR messages (frames
/// `laser`, `base_link`, `odom`; each scan's own beam angles; no `/tf_static`), atomically.
/// For tests and examples: the output of pfslam is TUM, maps and JSON.
pub fn write_mcap_with(
    path: &Path,
    recording: &Recording,
    topics: &McapTopics,
) -> Result<(), RosError> {
    let mcap_err = |e: ::mcap::McapError| RosError::format(path, "writing", e.to_string());
    // built in memory (the writer seeks), then written atomically
    let mut w = ::mcap::Writer::new(std::io::Cursor::new(Vec::new())).map_err(mcap_err)?;
    let meta = BTreeMap::new();
    let scan_schema = w
        .add_schema("sensor_msgs/msg/LaserScan", "ros2msg", b"")
        .map_err(mcap_err)?;
    let (odom_type, odom_topic) = match &topics.odom {
        Some(t) => ("nav_msgs/msg/Odometry", t.as_str()),
        None => ("tf2_msgs/msg/TFMessage", "/tf"),
    };
    let odom_schema = w.add_schema(odom_type, "ros2msg", b"").map_err(mcap_err)?;
    let scan_ch = w
        .add_channel(scan_schema, &topics.scan, "cdr", &meta)
        .map_err(mcap_err)?;
    let odom_ch = w
        .add_channel(odom_schema, odom_topic, "cdr", &meta)
        .map_err(mcap_err)?;
    // merge both streams by time, as a recorder would
    let scans = &recording.scans;
    let odom = &recording.odometry.poses;
    let (mut i, mut j, mut seq) = (0usize, 0usize, 0u32);
    while i < scans.len() || j < odom.len() {
        let take_scan =
            j >= odom.len() || (i < scans.len() && scans.stamps_ns[i] <= odom[j].stamp_ns);
        let (channel_id, stamp_ns, data) = if take_scan {
            let g = recording.lidar_at(i);
            let n = scans.ranges(i).len();
            let msg = ScanMsg {
                stamp_ns: scans.stamps_ns[i],
                frame_id: "laser".into(),
                angle_min: g.angle_min_rad as f32,
                angle_max: g.beam_angle_rad(n.saturating_sub(1)) as f32,
                angle_increment: g.angle_increment_rad as f32,
                range_min: 0.0,
                range_max: g.range_max_m,
                ranges: scans.ranges(i).to_vec(),
            };
            i += 1;
            (scan_ch, msg.stamp_ns, encode::scan_cdr(&msg))
        } else {
            let msg = OdomMsg {
                stamp_ns: odom[j].stamp_ns,
                frame_id: "odom".into(),
                child_frame_id: "base_link".into(),
                pose: odom[j].pose,
            };
            j += 1;
            let data = match topics.odom {
                Some(_) => encode::odometry_cdr(&msg),
                None => encode::tf_cdr(&msg),
            };
            (odom_ch, msg.stamp_ns, data)
        };
        let t = u64::try_from(stamp_ns).unwrap_or(0);
        w.write_to_known_channel(
            &::mcap::records::MessageHeader {
                channel_id,
                sequence: seq,
                log_time: t,
                publish_time: t,
            },
            &data,
        )
        .map_err(mcap_err)?;
        seq += 1;
    }
    if let (Some(topic), Some(series)) = (&topics.imu, &recording.imu_yaw) {
        let schema = w
            .add_schema("sensor_msgs/msg/Imu", "ros2msg", b"")
            .map_err(mcap_err)?;
        let ch = w
            .add_channel(schema, topic, "cdr", &meta)
            .map_err(mcap_err)?;
        for &(stamp_ns, yaw) in series {
            let t = u64::try_from(stamp_ns).unwrap_or(0);
            let header = ::mcap::records::MessageHeader {
                channel_id: ch,
                sequence: seq,
                log_time: t,
                publish_time: t,
            };
            w.write_to_known_channel(&header, &encode::imu_cdr(stamp_ns, Some(yaw), 0.0))
                .map_err(mcap_err)?;
            seq += 1;
        }
    }
    w.finish().map_err(mcap_err)?;
    super::write_bytes_atomic(path, w.into_inner().get_ref())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A string field as MCAP writes it: `u32` length, then the bytes.
    fn string(s: &[u8]) -> Vec<u8> {
        let mut out = (s.len() as u32).to_le_bytes().to_vec();
        out.extend_from_slice(s);
        out
    }

    #[test]
    fn record_fields_must_end_inside_their_record() {
        let header = [string(b"ros2"), string(b"pfslam")].concat();
        assert!(check_record_fields(0x01, &header).is_ok());
        // The second string claims 4 GiB in a 20-byte record.
        let mut huge = string(b"ros2");
        huge.extend_from_slice(&u32::MAX.to_le_bytes());
        huge.extend_from_slice(b"pfslam");
        assert!(check_record_fields(0x01, &huge).is_err());
        // A channel whose metadata map holds a string running past the map.
        let mut channel = vec![1, 0, 1, 0];
        channel.extend([string(b"/scan"), string(b"cdr")].concat());
        let entry = [string(b"k"), 100u32.to_le_bytes().to_vec()].concat();
        channel.extend(string(&entry));
        assert!(check_record_fields(0x04, &channel).is_err());
        let entry = [string(b"k"), string(b"v")].concat();
        let mut good = vec![1, 0, 1, 0];
        good.extend([string(b"/scan"), string(b"cdr"), string(&entry)].concat());
        assert!(check_record_fields(0x04, &good).is_ok());
        // Messages carry no length to check.
        assert!(check_record_fields(0x05, &[0; 3]).is_ok());
    }

    #[test]
    fn a_map_of_fixed_entries_must_hold_whole_entries() {
        // found by fuzzing: a chunk index whose offsets map held 2.4 entries; the crate
        // read 3 and took the compression's length from the wrong bytes
        let index = |map_len: u32| {
            let mut r = vec![0u8; 32];
            r.extend_from_slice(&map_len.to_le_bytes());
            r.extend(std::iter::repeat_n(0u8, map_len as usize));
            r.extend_from_slice(&[0; 8]);
            r.extend(string(b"zstd"));
            r
        };
        assert!(check_record_fields(0x08, &index(20)).is_ok());
        assert!(check_record_fields(0x08, &index(24)).is_err());
        // message index entries are (u64, u64)
        let mut message_index = vec![1, 0];
        message_index.extend_from_slice(&24u32.to_le_bytes());
        message_index.extend_from_slice(&[0; 24]);
        assert!(check_record_fields(0x07, &message_index).is_err());
    }

    #[test]
    fn nested_chunks_and_attachments_are_checked() {
        // found by fuzzing: a chunk inside a chunk whose compression string claimed 4 GiB
        let chunk = |comp_len: u32| {
            let mut r = vec![0u8; 28];
            r.extend_from_slice(&comp_len.to_le_bytes());
            r.extend_from_slice(b"lz4");
            r.extend_from_slice(&0u64.to_le_bytes());
            r
        };
        assert!(check_record_fields(0x06, &chunk(3)).is_ok());
        assert!(check_record_fields(0x06, &chunk(u32::MAX)).is_err());
        // an attachment must keep room for its CRC, which the crate slices unchecked
        let mut attachment = vec![0u8; 16];
        attachment.extend([string(b"a"), string(b"b")].concat());
        attachment.extend_from_slice(&0u64.to_le_bytes());
        assert!(check_record_fields(0x09, &attachment).is_err());
        attachment.extend_from_slice(&[0; 4]);
        assert!(check_record_fields(0x09, &attachment).is_ok());
    }
}
