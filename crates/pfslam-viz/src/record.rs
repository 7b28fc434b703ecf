//! A run as an MCAP file of Foxglove's message schemas (JSON encoding), which Foxglove opens
//! as it is, on one time line (the recording's stamps) and in one frame, `map`:
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/map` | `foxglove.Grid` | the map over time: int8 occupancy, 0-100 %, -1 unknown |
//! | `/scan` | `foxglove.LaserScan` | each scan, placed at its pose on the final trajectory |
//! | `/particles` | `foxglove.PosesInFrame` | the particle cloud after each filter update |
//! | `/trajectory`, `/front_end` | `foxglove.PosesInFrame` | the final and the filter's paths |
//! | `/loop_closures` | `foxglove.SceneUpdate` | a line between the two ends of each closure |

use pfslam::geometry::{Pose2, StampedPose2};
use pfslam::map::{Cell, OccupancyGrid};
use pfslam::sensors::LidarGeometry;
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::io::{Seek, Write};
use std::path::{Path, PathBuf};

/// The frame every message is in.
pub const FRAME: &str = "map";

/// A failure to write the record.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct RecordError {
    /// The record's file.
    pub path: PathBuf,
    /// What went wrong.
    pub message: String,
}

/// The record's topics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topic {
    /// `/map`.
    Map,
    /// `/scan`.
    Scan,
    /// `/particles`.
    Particles,
    /// `/trajectory`.
    Trajectory,
    /// `/front_end`.
    FrontEnd,
    /// `/loop_closures`.
    LoopClosures,
}

/// Topic names and schema names, in [`Topic`] order.
pub const TOPICS: [(&str, &str); 6] = [
    ("/map", "foxglove.Grid"),
    ("/scan", "foxglove.LaserScan"),
    ("/particles", "foxglove.PosesInFrame"),
    ("/trajectory", "foxglove.PosesInFrame"),
    ("/front_end", "foxglove.PosesInFrame"),
    ("/loop_closures", "foxglove.SceneUpdate"),
];

/// An MCAP record being written.
pub struct RunRecord<W: Write + Seek> {
    path: PathBuf,
    writer: mcap::Writer<W>,
    channels: [u16; 6],
    sequence: u32,
}

impl<W: Write + Seek> RunRecord<W> {
    /// Starts a record on `out`; `path` names it in errors.
    pub fn new(out: W, path: &Path) -> Result<Self, RecordError> {
        let fail = |e: mcap::McapError| RecordError {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let mut writer = mcap::Writer::new(out).map_err(fail)?;
        let mut channels = [0u16; 6];
        let mut schemas: BTreeMap<&str, u16> = BTreeMap::new();
        for (k, (topic, schema)) in TOPICS.iter().enumerate() {
            let id = match schemas.get(schema) {
                Some(&id) => id,
                None => {
                    let text = schema_json(schema).to_string();
                    let id = writer
                        .add_schema(schema, "jsonschema", text.as_bytes())
                        .map_err(fail)?;
                    schemas.insert(schema, id);
                    id
                }
            };
            channels[k] = writer
                .add_channel(id, topic, "json", &BTreeMap::new())
                .map_err(fail)?;
        }
        Ok(RunRecord {
            path: path.to_path_buf(),
            writer,
            channels,
            sequence: 0,
        })
    }

    fn write(&mut self, topic: Topic, stamp_ns: i64, message: &Value) -> Result<(), RecordError> {
        let t = u64::try_from(stamp_ns).unwrap_or(0);
        let header = mcap::records::MessageHeader {
            channel_id: self.channels[topic as usize],
            sequence: self.sequence,
            log_time: t,
            publish_time: t,
        };
        self.sequence = self.sequence.wrapping_add(1);
        let data = message.to_string();
        self.writer
            .write_to_known_channel(&header, data.as_bytes())
            .map_err(|e| self.error(e))
    }

    fn error(&self, e: mcap::McapError) -> RecordError {
        RecordError {
            path: self.path.clone(),
            message: e.to_string(),
        }
    }

    /// The map's observed cells at `stamp_ns` (nothing when none is observed yet).
    pub fn map(&mut self, stamp_ns: i64, grid: &OccupancyGrid) -> Result<(), RecordError> {
        let Some(rect) = grid.observed_bounds() else {
            return Ok(());
        };
        let (w, h) = (rect.width(), rect.height());
        let mut data = Vec::with_capacity(w * h);
        for j in rect.min_j..=rect.max_j {
            for i in rect.min_i..=rect.max_i {
                let cell = Cell::new(i, j);
                let v = if grid.logodds_fixed(cell) == 0 {
                    -1i8
                } else {
                    (grid.probability(cell) * 100.0).round() as i8
                };
                data.push(v as u8);
            }
        }
        let (x0, y0) = grid.limits().cell_corner(Cell::new(rect.min_i, rect.min_j));
        let res = grid.limits().resolution_m();
        let message = json!({
            "timestamp": time(stamp_ns),
            "frame_id": FRAME,
            "pose": pose(&Pose2::new(x0, y0, 0.0)),
            "column_count": w,
            "cell_size": {"x": res, "y": res},
            "row_stride": w,
            "cell_stride": 1,
            "fields": [{"name": "occupancy", "offset": 0, "type": 2}],
            "data": super::base64(&data),
        });
        self.write(Topic::Map, stamp_ns, &message)
    }

    /// One scan, its sensor at `world_from_lidar`; readings that are no return are 0.
    pub fn scan(
        &mut self,
        stamp_ns: i64,
        world_from_lidar: &Pose2,
        geometry: &LidarGeometry,
        ranges_m: &[f32],
    ) -> Result<(), RecordError> {
        let ranges: Vec<f32> = ranges_m
            .iter()
            .map(|&r| {
                let valid = r.is_finite() && r > geometry.range_min_m && r < geometry.range_max_m;
                if valid { r } else { 0.0 }
            })
            .collect();
        let last = ranges.len().saturating_sub(1) as f64;
        let message = json!({
            "timestamp": time(stamp_ns),
            "frame_id": FRAME,
            "pose": pose(world_from_lidar),
            "start_angle": geometry.angle_min_rad,
            "end_angle": geometry.angle_min_rad + geometry.angle_increment_rad * last,
            "ranges": ranges,
            "intensities": [],
        });
        self.write(Topic::Scan, stamp_ns, &message)
    }

    /// Poses on `topic` (the particles, or a whole trajectory) at `stamp_ns`.
    pub fn poses(
        &mut self,
        topic: Topic,
        stamp_ns: i64,
        poses: impl Iterator<Item = Pose2>,
    ) -> Result<(), RecordError> {
        let poses: Vec<Value> = poses.map(|p| pose(&p)).collect();
        let message = json!({"timestamp": time(stamp_ns), "frame_id": FRAME, "poses": poses});
        self.write(topic, stamp_ns, &message)
    }

    /// A whole trajectory on `topic`, stamped with its last pose.
    pub fn trajectory(&mut self, topic: Topic, poses: &[StampedPose2]) -> Result<(), RecordError> {
        let stamp_ns = poses.last().map_or(0, |p| p.stamp_ns);
        self.poses(topic, stamp_ns, poses.iter().map(|p| p.pose))
    }

    /// The loop closures as lines between their ends, at `stamp_ns`.
    pub fn loop_closures(
        &mut self,
        stamp_ns: i64,
        ends: &[(Pose2, Pose2)],
    ) -> Result<(), RecordError> {
        let point = |p: &Pose2| json!({"x": p.x_m, "y": p.y_m, "z": 0.0});
        let points: Vec<Value> = ends
            .iter()
            .flat_map(|(a, b)| [point(a), point(b)])
            .collect();
        let line = json!({
            "type": 2,
            "pose": pose(&Pose2::IDENTITY),
            "thickness": 2.0,
            "scale_invariant": true,
            "points": points,
            "color": {"r": 0.1, "g": 0.7, "b": 0.2, "a": 1.0},
            "colors": [],
            "indices": [],
        });
        let entity = json!({
            "timestamp": time(stamp_ns),
            "frame_id": FRAME,
            "id": "loop_closures",
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": false,
            "metadata": [],
            "arrows": [], "cubes": [], "spheres": [], "cylinders": [],
            "lines": [line],
            "triangles": [], "texts": [], "models": [],
        });
        let message = json!({"deletions": [], "entities": [entity]});
        self.write(Topic::LoopClosures, stamp_ns, &message)
    }

    /// Writes the MCAP summary and footer; returns the output (to flush or sync).
    pub fn finish(mut self) -> Result<W, RecordError> {
        self.writer.finish().map_err(|e| self.error(e))?;
        Ok(self.writer.into_inner())
    }
}

fn time(stamp_ns: i64) -> Value {
    let t = stamp_ns.max(0);
    json!({"sec": t / 1_000_000_000, "nsec": t % 1_000_000_000})
}

fn pose(p: &Pose2) -> Value {
    let half = 0.5 * p.yaw_rad;
    json!({
        "position": {"x": p.x_m, "y": p.y_m, "z": 0.0},
        "orientation": {"x": 0.0, "y": 0.0, "z": half.sin(), "w": half.cos()},
    })
}

/// The JSON schema of a Foxglove message type: its fields and their types.
fn schema_json(name: &str) -> Value {
    let number = json!({"type": "number"});
    let integer = json!({"type": "integer", "minimum": 0});
    let string = json!({"type": "string"});
    let time = json!({"type": "object", "title": "time",
        "properties": {"sec": integer, "nsec": integer}});
    let vector3 = json!({"type": "object", "title": "foxglove.Vector3",
        "properties": {"x": number, "y": number, "z": number}});
    let pose = json!({"type": "object", "title": "foxglove.Pose", "properties": {
        "position": vector3,
        "orientation": {"type": "object", "title": "foxglove.Quaternion",
            "properties": {"x": number, "y": number, "z": number, "w": number}}}});
    let array = |items: Value| json!({"type": "array", "items": items});
    let properties = match name {
        "foxglove.Grid" => json!({
            "timestamp": time, "frame_id": string, "pose": pose, "column_count": integer,
            "cell_size": {"type": "object", "title": "foxglove.Vector2",
                "properties": {"x": number, "y": number}},
            "row_stride": integer, "cell_stride": integer,
            "fields": array(json!({"type": "object", "title": "foxglove.PackedElementField",
                "properties": {"name": string, "offset": integer, "type": integer}})),
            "data": {"type": "string", "contentEncoding": "base64"},
        }),
        "foxglove.LaserScan" => json!({
            "timestamp": time, "frame_id": string, "pose": pose, "start_angle": number,
            "end_angle": number, "ranges": array(number.clone()),
            "intensities": array(number.clone()),
        }),
        "foxglove.PosesInFrame" => json!({
            "timestamp": time, "frame_id": string, "poses": array(pose),
        }),
        _ => json!({
            "deletions": array(json!({"type": "object"})),
            "entities": array(json!({"type": "object", "title": "foxglove.SceneEntity",
                "properties": {"timestamp": time, "frame_id": string, "id": string,
                    "lines": array(json!({"type": "object",
                        "title": "foxglove.LinePrimitive",
                        "properties": {"type": integer, "pose": pose, "thickness": number,
                            "scale_invariant": {"type": "boolean"},
                            "points": array(vector3.clone())}}))}})),
        }),
    };
    json!({"title": name, "type": "object", "properties": properties})
}

#[cfg(test)]
mod tests {
    use super::*;
    use pfslam::map::{LogOddsParams, MapLimits};

    /// Every topic written once, read back with the `mcap` crate (Foxglove's reader).
    #[test]
    fn a_record_reads_back_with_its_schemas() {
        let mut bytes = std::io::Cursor::new(Vec::new());
        let mut rec = RunRecord::new(&mut bytes, Path::new("run.mcap")).unwrap();
        let mut grid =
            OccupancyGrid::with_params(MapLimits::new(0.5, 0.0, 0.0), LogOddsParams::ucsd());
        grid.update_occupied(Cell::new(2, 1)).unwrap();
        grid.update_free(Cell::new(0, 0)).unwrap();
        let t = 1_500_000_000_250_000_000;
        rec.map(t, &grid).unwrap();
        let g = pfslam_io::carmen::carmen_geometry(3, 50.0);
        rec.scan(t, &Pose2::new(1.0, 2.0, 0.5), &g, &[1.0, f32::NAN, 60.0])
            .unwrap();
        let p = [Pose2::new(0.0, 0.0, 0.0), Pose2::new(1.0, 0.0, 0.1)];
        rec.poses(Topic::Particles, t, p.iter().copied()).unwrap();
        let traj = [StampedPose2 {
            stamp_ns: t,
            pose: p[1],
        }];
        rec.trajectory(Topic::Trajectory, &traj).unwrap();
        rec.trajectory(Topic::FrontEnd, &traj).unwrap();
        rec.loop_closures(t, &[(p[0], p[1])]).unwrap();
        rec.finish().unwrap();
        let bytes = bytes.into_inner();
        let mut seen = Vec::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            let schema = m.channel.schema.as_ref().unwrap();
            assert_eq!(schema.encoding, "jsonschema");
            let v: Value = serde_json::from_slice(&m.data).unwrap();
            seen.push((m.channel.topic.clone(), schema.name.clone(), v));
            assert_eq!(m.log_time, t as u64);
        }
        let names: Vec<(&str, &str)> = seen
            .iter()
            .map(|(t, s, _)| (t.as_str(), s.as_str()))
            .collect();
        assert_eq!(names, TOPICS);
        let grid_msg = &seen[0].2;
        assert_eq!(grid_msg["column_count"], 3);
        assert_eq!(grid_msg["timestamp"]["sec"], 1_500_000_000);
        assert_eq!(grid_msg["timestamp"]["nsec"], 250_000_000);
        // 3 x 2 cells from the lower left: free, unknown, unknown / unknown, unknown, occupied
        let pct = |c: Cell| (grid.probability(c) * 100.0).round() as u8;
        let expected = [
            pct(Cell::new(0, 0)),
            255,
            255,
            255,
            255,
            pct(Cell::new(2, 1)),
        ];
        assert_eq!(grid_msg["data"].as_str().unwrap(), crate::base64(&expected));
        assert!(expected[0] < 50 && expected[5] > 50, "{expected:?}");
        let scan = &seen[1].2;
        assert_eq!(scan["ranges"], json!([1.0, 0.0, 0.0]));
        assert_eq!(scan["pose"]["position"]["y"], 2.0);
        assert_eq!(seen[2].2["poses"].as_array().unwrap().len(), 2);
        assert_eq!(
            seen[5].2["entities"][0]["lines"][0]["points"]
                .as_array()
                .unwrap()
                .len(),
            2
        );
    }
}
