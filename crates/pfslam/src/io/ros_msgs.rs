//! Decoding of the ROS messages the recordings need (`sensor_msgs/LaserScan`,
//! `nav_msgs/Odometry`, `tf2_msgs/TFMessage`) from ROS 1 serialisation or ROS 2 CDR (little
//! endian), and their assembly into a [`Recording`]; shared by [`super::ros1`] and
//! [`super::mcap`].
//!
//! Options ([`RosOptions`]) choose the topics and the beam geometry:
//! - [`BeamGeometry::Auto`] (default): scans that look converted from a CARMEN log (180 or 360
//!   beams spanning 180 deg from -90 deg, the Freiburg bags) get the CARMEN geometry
//!   ([`super::carmen::carmen_geometry`]: 1 deg or 0.5 deg steps from -90 deg, because the
//!   converter wrote `angle_increment = fov / (n - 1)`, which is not how those lasers
//!   sampled); every other scan keeps the geometry it was recorded with.
//! - [`BeamGeometry::AsRecorded`]: `angle_min` and `angle_increment` as recorded.
//! - [`BeamGeometry::Carmen`]: always the CARMEN geometry.
//!
//! Scans are stamped with their `header.stamp` (not the bag's receive time); odometry with its
//! `header.stamp`. Stamps that go backwards (the Intel bag: 631 scans, 602 odometry messages)
//! are handled by the rule of the CARMEN reader: scans are all kept and sorted by stamp,
//! odometry keeps its longest strictly increasing subsequence. The laser mount `body_from_lidar` is the
//! chain of `/tf_static` transforms from the odometry's `child_frame_id` to the scan's
//! `frame_id` (identity, with a warning, when the chain is absent).

use crate::geometry::{Pose2, Rigid3, StampedPose2, Trajectory};
use crate::sensors::{LidarGeometry, Recording, ScanSet};
use serde::{Deserialize, Serialize};

/// Errors of the binary readers (ROS 1 bags, MCAP).
#[derive(Debug, thiserror::Error)]
pub enum RosError {
    /// The file could not be read.
    #[error(transparent)]
    Io(#[from] super::IoError),
    /// The content is malformed or lacks what a recording needs.
    #[error("{}: {position}: {message}", path.display())]
    Format {
        /// The file.
        path: std::path::PathBuf,
        /// Where: byte offset, chunk and record or message index.
        position: String,
        /// What is wrong.
        message: String,
    },
}

impl RosError {
    /// A format error at `position` of `path`.
    pub fn format(
        path: &std::path::Path,
        position: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        RosError::Format {
            path: path.to_path_buf(),
            position: position.into(),
            message: message.into(),
        }
    }
}

/// Which beam angles the scans get (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BeamGeometry {
    /// CARMEN geometry for scans converted from CARMEN logs, else as recorded.
    #[default]
    Auto,
    /// As recorded in the message.
    AsRecorded,
    /// Always the CARMEN convention (-90 deg + i * 1 deg or 0.5 deg).
    Carmen,
}

/// Options of the ROS 1 bag and MCAP readers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RosOptions {
    /// Topic of the `LaserScan` messages.
    pub scan_topic: String,
    /// Topic of the `Odometry` messages.
    pub odom_topic: String,
    /// Topic of the static transforms (laser mount).
    pub tf_static_topic: String,
    /// Beam angles.
    pub beam_geometry: BeamGeometry,
    /// Readings at or above this range (m) mean "no return"; `None`: 50 m with the CARMEN
    /// geometry (the Freiburg files write 81.83/81.91 m or 50 m for no return), else the
    /// message's `range_max`.
    pub range_max_m: Option<f32>,
}

impl Default for RosOptions {
    fn default() -> Self {
        RosOptions {
            scan_topic: "/scan".to_string(),
            odom_topic: "/odom".to_string(),
            tf_static_topic: "/tf_static".to_string(),
            beam_geometry: BeamGeometry::Auto,
            range_max_m: None,
        }
    }
}

/// A decoded `sensor_msgs/LaserScan`.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanMsg {
    /// `header.stamp` (ns).
    pub stamp_ns: i64,
    /// `header.frame_id`.
    pub frame_id: String,
    /// First beam angle (rad).
    pub angle_min: f32,
    /// Last beam angle (rad).
    pub angle_max: f32,
    /// Angle step (rad).
    pub angle_increment: f32,
    /// Smallest valid range (m).
    pub range_min: f32,
    /// Largest valid range (m).
    pub range_max: f32,
    /// Ranges (m).
    pub ranges: Vec<f32>,
}

/// A decoded `nav_msgs/Odometry` (planar part).
#[derive(Debug, Clone, PartialEq)]
pub struct OdomMsg {
    /// `header.stamp` (ns).
    pub stamp_ns: i64,
    /// `header.frame_id` (the odometry frame).
    pub frame_id: String,
    /// `child_frame_id` (the body frame).
    pub child_frame_id: String,
    /// Position and yaw of the body in the odometry frame.
    pub pose: Pose2,
}

/// One transform of a `tf2_msgs/TFMessage`.
#[derive(Debug, Clone, PartialEq)]
pub struct TfMsg {
    /// Parent frame (`header.frame_id`).
    pub parent: String,
    /// Child frame.
    pub child: String,
    /// `parent_from_child`.
    pub parent_from_child: Rigid3,
}

/// Little-endian reader of ROS 1 serialisation (`cdr == false`: packed, strings without
/// terminator, header with `seq`) or ROS 2 CDR (`cdr == true`: aligned to the field size from
/// the start of the payload after the 4-byte encapsulation header, strings NUL-terminated).
pub struct Decoder<'a> {
    buf: &'a [u8],
    pos: usize,
    origin: usize,
    cdr: bool,
}

impl<'a> Decoder<'a> {
    /// A decoder of ROS 1 serialisation.
    pub fn ros1(buf: &'a [u8]) -> Self {
        Decoder {
            buf,
            pos: 0,
            origin: 0,
            cdr: false,
        }
    }

    /// A decoder of a CDR payload (checks the encapsulation header: little-endian CDR only).
    pub fn cdr(buf: &'a [u8]) -> Result<Self, String> {
        match buf.get(..4) {
            Some([0x00, 0x01, _, _]) => Ok(Decoder {
                buf,
                pos: 4,
                origin: 4,
                cdr: true,
            }),
            Some([0x00, 0x00, _, _]) => Err("big-endian CDR is not supported".into()),
            Some(h) => Err(format!(
                "unknown CDR encapsulation {:02x}{:02x}",
                h[0], h[1]
            )),
            None => Err("message shorter than the CDR header".into()),
        }
    }

    /// Current byte offset in the message.
    pub fn pos(&self) -> usize {
        self.pos
    }

    fn align(&mut self, n: usize) {
        if self.cdr {
            let rel = self.pos - self.origin;
            self.pos += (n - rel % n) % n;
        }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.buf.len());
        match end {
            Some(e) => {
                let s = &self.buf[self.pos..e];
                self.pos = e;
                Ok(s)
            }
            None => Err(format!(
                "message truncated reading {what} at byte {} (needs {n}, has {})",
                self.pos,
                self.buf.len().saturating_sub(self.pos)
            )),
        }
    }

    /// A `uint32`.
    pub fn u32(&mut self, what: &str) -> Result<u32, String> {
        self.align(4);
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// A `float32`.
    pub fn f32(&mut self, what: &str) -> Result<f32, String> {
        self.u32(what).map(f32::from_bits)
    }

    /// A `float64`.
    pub fn f64(&mut self, what: &str) -> Result<f64, String> {
        self.align(8);
        let b = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(f64::from_le_bytes(a))
    }

    /// A string.
    pub fn string(&mut self, what: &str) -> Result<String, String> {
        let n = self.u32(what)? as usize;
        let b = self.take(n, what)?;
        let b = if self.cdr {
            b.strip_suffix(&[0]).unwrap_or(b)
        } else {
            b
        };
        String::from_utf8(b.to_vec()).map_err(|_| format!("{what}: not UTF-8"))
    }

    /// A `std_msgs/Header`: stamp (ns) and frame id.
    pub fn header(&mut self) -> Result<(i64, String), String> {
        if !self.cdr {
            self.u32("header.seq")?;
        }
        let sec = self.u32("header.stamp.sec")?;
        let nsec = self.u32("header.stamp.nsec")?;
        // ROS 1 time is unsigned, ROS 2 signed
        let sec = if self.cdr {
            i64::from(sec as i32)
        } else {
            i64::from(sec)
        };
        let frame = self.string("header.frame_id")?;
        Ok((sec * 1_000_000_000 + i64::from(nsec), frame))
    }

    /// A `float32[]`.
    pub fn f32_seq(&mut self, what: &str, out: &mut Vec<f32>) -> Result<(), String> {
        let n = self.u32(what)? as usize;
        let b = self.take(n.checked_mul(4).ok_or("sequence too long")?, what)?;
        out.clear();
        out.extend(
            b.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
        );
        Ok(())
    }

    fn pose3(&mut self) -> Result<([f64; 3], [f64; 4]), String> {
        let mut t = [0.0; 3];
        for v in &mut t {
            *v = self.f64("position")?;
        }
        let mut q = [0.0; 4];
        for v in &mut q {
            *v = self.f64("orientation")?;
        }
        Ok((t, q))
    }
}

fn yaw_of(q: [f64; 4]) -> f64 {
    let [x, y, z, w] = q;
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

fn rigid_of(t: [f64; 3], q: [f64; 4]) -> Rigid3 {
    let [x, y, z, w] = q;
    let uq = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
    Rigid3 {
        rotation: *uq.to_rotation_matrix().matrix(),
        translation: nalgebra::Vector3::from(t),
    }
}

/// Decodes a `sensor_msgs/LaserScan`.
pub fn decode_scan(d: &mut Decoder<'_>) -> Result<ScanMsg, String> {
    let (stamp_ns, frame_id) = d.header()?;
    let angle_min = d.f32("angle_min")?;
    let angle_max = d.f32("angle_max")?;
    let angle_increment = d.f32("angle_increment")?;
    d.f32("time_increment")?;
    d.f32("scan_time")?;
    let range_min = d.f32("range_min")?;
    let range_max = d.f32("range_max")?;
    let mut ranges = Vec::new();
    d.f32_seq("ranges", &mut ranges)?;
    Ok(ScanMsg {
        stamp_ns,
        frame_id,
        angle_min,
        angle_max,
        angle_increment,
        range_min,
        range_max,
        ranges,
    })
}

/// Decodes the pose part of a `nav_msgs/Odometry` (the twist is not needed).
pub fn decode_odometry(d: &mut Decoder<'_>) -> Result<OdomMsg, String> {
    let (stamp_ns, frame_id) = d.header()?;
    let child_frame_id = d.string("child_frame_id")?;
    let (t, q) = d.pose3()?;
    if !t.iter().chain(q.iter()).all(|v| v.is_finite()) {
        return Err("odometry pose is not finite".into());
    }
    Ok(OdomMsg {
        stamp_ns,
        frame_id,
        child_frame_id,
        pose: Pose2::new(t[0], t[1], yaw_of(q)),
    })
}

/// Decodes a `tf2_msgs/TFMessage`.
pub fn decode_tf(d: &mut Decoder<'_>) -> Result<Vec<TfMsg>, String> {
    let n = d.u32("transforms")? as usize;
    let mut out = Vec::with_capacity(n.min(1024));
    for _ in 0..n {
        let (_, parent) = d.header()?;
        let child = d.string("child_frame_id")?;
        let (t, q) = d.pose3()?;
        out.push(TfMsg {
            parent,
            child,
            parent_from_child: rigid_of(t, q),
        });
    }
    Ok(out)
}

/// What a ROS reader read and dropped.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RosStats {
    /// `LaserScan` messages read.
    pub scan_messages: usize,
    /// Scans whose stamp is not above the previous one's (sorted into place; a repeated stamp
    /// is dropped).
    pub scans_out_of_order: usize,
    /// `Odometry` messages read.
    pub odometry_messages: usize,
    /// Odometry messages dropped because their stamp is out of order or repeated.
    pub odometry_out_of_order: usize,
    /// True when the laser mount came from `/tf_static` (else identity).
    pub mount_from_tf: bool,
}

/// Collects decoded messages and turns them into a [`Recording`].
#[derive(Debug, Default)]
pub struct RecordingBuilder {
    scans: Option<ScanSet>,
    first_scan: Option<ScanMsg>,
    scan_frame: String,
    odom: Vec<StampedPose2>,
    body_frame: Option<String>,
    tf_static: Vec<TfMsg>,
}

impl RecordingBuilder {
    /// An empty builder.
    pub fn new() -> Self {
        RecordingBuilder::default()
    }

    /// Adds a scan; `Err` with a message when it is empty or its beam count differs from the
    /// first scan's.
    pub fn add_scan(&mut self, msg: ScanMsg) -> Result<(), String> {
        if msg.ranges.is_empty() {
            return Err("scan has no range".into());
        }
        let set = self
            .scans
            .get_or_insert_with(|| ScanSet::new(msg.ranges.len()));
        if msg.ranges.len() != set.beam_count {
            return Err(format!(
                "scan has {} beams, earlier scans {}",
                msg.ranges.len(),
                set.beam_count
            ));
        }
        set.push(msg.stamp_ns, &msg.ranges);
        if self.first_scan.is_none() {
            self.scan_frame = msg.frame_id.clone();
            self.first_scan = Some(ScanMsg {
                ranges: Vec::new(),
                ..msg
            });
        }
        Ok(())
    }

    /// Adds an odometry pose.
    pub fn add_odometry(&mut self, msg: OdomMsg) {
        if self.body_frame.is_none() && !msg.child_frame_id.is_empty() {
            self.body_frame = Some(msg.child_frame_id);
        }
        self.odom.push(StampedPose2 {
            stamp_ns: msg.stamp_ns,
            pose: msg.pose,
        });
    }

    /// Adds static transforms.
    pub fn add_tf_static(&mut self, tfs: Vec<TfMsg>) {
        self.tf_static.extend(tfs);
    }

    /// Number of scans so far.
    pub fn scan_count(&self) -> usize {
        self.scans.as_ref().map_or(0, ScanSet::len)
    }

    /// Number of odometry messages so far.
    pub fn odometry_count(&self) -> usize {
        self.odom.len()
    }

    /// `body_from_lidar` by walking the static transforms from the scan frame up to the body
    /// frame; `None` when there is no such chain.
    fn mount(&self) -> Option<Rigid3> {
        let body = self.body_frame.as_deref()?;
        let mut frame = self.scan_frame.as_str();
        let mut acc = Rigid3::IDENTITY;
        for _ in 0..64 {
            if frame == body {
                return Some(acc);
            }
            let tf = self.tf_static.iter().find(|t| t.child == frame)?;
            acc = tf.parent_from_child.compose(&acc);
            frame = tf.parent.as_str();
        }
        None
    }

    /// The recording and what was dropped; `Err` with a message when there is no scan or no
    /// odometry.
    pub fn finish(
        self,
        name: String,
        options: &RosOptions,
    ) -> Result<(Recording, RosStats), String> {
        let (Some(scans), Some(first)) = (self.scans.as_ref(), self.first_scan.as_ref()) else {
            return Err(format!("no LaserScan message on {}", options.scan_topic));
        };
        if self.odom.is_empty() {
            return Err(format!("no Odometry message on {}", options.odom_topic));
        }
        let n = scans.beam_count;
        let span_deg = (f64::from(first.angle_max) - f64::from(first.angle_min)).to_degrees();
        let looks_carmen = matches!(n, 180 | 181 | 360 | 361)
            && (f64::from(first.angle_min).to_degrees() + 90.0).abs() < 0.5
            && (span_deg - 180.0).abs() < 0.5;
        let carmen = match options.beam_geometry {
            BeamGeometry::Auto => looks_carmen,
            BeamGeometry::AsRecorded => false,
            BeamGeometry::Carmen => true,
        };
        let lidar = if carmen {
            super::carmen::carmen_geometry(n, options.range_max_m.unwrap_or(50.0))
        } else {
            LidarGeometry {
                angle_min_rad: f64::from(first.angle_min),
                angle_increment_rad: f64::from(first.angle_increment),
                beam_count: n,
                range_max_m: options.range_max_m.unwrap_or(first.range_max),
            }
        };
        let mount = self.mount();
        let mount_from_tf = mount.is_some();
        let body_from_lidar = match mount {
            Some(m) => m,
            None => {
                tracing::warn!(
                    "no static transform chain from {:?} to {:?}: laser mount taken as identity",
                    self.scan_frame,
                    self.body_frame
                );
                Rigid3::IDENTITY
            }
        };
        let scans = self.scans.unwrap_or_default();
        let scan_messages = scans.len();
        let (scans, scans_out_of_order) = super::carmen::sort_scans(scans);
        let stamps: Vec<i64> = self.odom.iter().map(|p| p.stamp_ns).collect();
        let keep = super::carmen::longest_increasing(&stamps);
        let odometry = Trajectory::new(keep.iter().map(|&i| self.odom[i]).collect());
        let stats = RosStats {
            scan_messages,
            scans_out_of_order,
            odometry_messages: self.odom.len(),
            odometry_out_of_order: self.odom.len() - keep.len(),
            mount_from_tf,
        };
        let rec = Recording {
            name,
            odometry,
            imu_yaw: None,
            scans,
            lidar,
            body_from_lidar,
            body_from_lidar_per_scan: None,
            ground_truth: None,
        };
        Ok((rec, stats))
    }
}

/// Encoders used by the MCAP writer (test files) and the tests: the inverse of the decoders.
pub mod encode {
    use super::{OdomMsg, ScanMsg};

    /// CDR writer (little endian), alignment from the start of the payload.
    pub struct CdrWriter {
        buf: Vec<u8>,
    }

    impl Default for CdrWriter {
        fn default() -> Self {
            CdrWriter::new()
        }
    }

    impl CdrWriter {
        /// A payload with the little-endian CDR encapsulation header.
        pub fn new() -> Self {
            CdrWriter {
                buf: vec![0x00, 0x01, 0x00, 0x00],
            }
        }
        fn align(&mut self, n: usize) {
            while !(self.buf.len() - 4).is_multiple_of(n) {
                self.buf.push(0);
            }
        }
        fn u32(&mut self, v: u32) {
            self.align(4);
            self.buf.extend_from_slice(&v.to_le_bytes());
        }
        fn f32(&mut self, v: f32) {
            self.u32(v.to_bits());
        }
        fn f64(&mut self, v: f64) {
            self.align(8);
            self.buf.extend_from_slice(&v.to_le_bytes());
        }
        fn string(&mut self, s: &str) {
            self.u32(s.len() as u32 + 1);
            self.buf.extend_from_slice(s.as_bytes());
            self.buf.push(0);
        }
        fn header(&mut self, stamp_ns: i64, frame: &str) {
            self.u32(stamp_ns.div_euclid(1_000_000_000) as i32 as u32);
            self.u32(stamp_ns.rem_euclid(1_000_000_000) as u32);
            self.string(frame);
        }
        /// The bytes.
        pub fn into_bytes(self) -> Vec<u8> {
            self.buf
        }
    }

    /// `sensor_msgs/msg/LaserScan` as CDR.
    pub fn scan_cdr(m: &ScanMsg) -> Vec<u8> {
        let mut w = CdrWriter::new();
        w.header(m.stamp_ns, &m.frame_id);
        for v in [
            m.angle_min,
            m.angle_max,
            m.angle_increment,
            0.0,
            0.0,
            m.range_min,
            m.range_max,
        ] {
            w.f32(v);
        }
        w.u32(m.ranges.len() as u32);
        for &r in &m.ranges {
            w.f32(r);
        }
        w.u32(0); // intensities
        w.into_bytes()
    }

    /// `nav_msgs/msg/Odometry` as CDR (zero covariances and twist).
    pub fn odometry_cdr(m: &OdomMsg) -> Vec<u8> {
        let mut w = CdrWriter::new();
        w.header(m.stamp_ns, &m.frame_id);
        w.string(&m.child_frame_id);
        let half = 0.5 * m.pose.yaw_rad;
        for v in [
            m.pose.x_m,
            m.pose.y_m,
            0.0,
            0.0,
            0.0,
            half.sin(),
            half.cos(),
        ] {
            w.f64(v);
        }
        for _ in 0..36 {
            w.f64(0.0);
        }
        for _ in 0..(6 + 36) {
            w.f64(0.0);
        }
        w.into_bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cdr_roundtrip_and_truncation() {
        let scan = ScanMsg {
            stamp_ns: 1_134_864_629_895_182_000,
            frame_id: "laser".into(),
            angle_min: -1.5,
            angle_max: 1.5,
            angle_increment: 0.1,
            range_min: 0.0,
            range_max: 80.0,
            ranges: vec![1.0, 2.5, 81.9],
        };
        let b = encode::scan_cdr(&scan);
        let back = decode_scan(&mut Decoder::cdr(&b).unwrap()).unwrap();
        assert_eq!(back, scan);
        let e = decode_scan(&mut Decoder::cdr(&b[..b.len() - 9]).unwrap()).unwrap_err();
        assert!(e.contains("truncated reading ranges"), "{e}");
        let odom = OdomMsg {
            stamp_ns: 5_000_000_001,
            frame_id: "odom".into(),
            child_frame_id: "base_link".into(),
            pose: Pose2::new(1.0, -2.0, 3.0),
        };
        let b = encode::odometry_cdr(&odom);
        let back = decode_odometry(&mut Decoder::cdr(&b).unwrap()).unwrap();
        assert_eq!(back.stamp_ns, odom.stamp_ns);
        assert_eq!(back.child_frame_id, "base_link");
        assert!((back.pose.yaw_rad - 3.0).abs() < 1e-12);
        assert!(Decoder::cdr(&[0, 0, 0, 0]).is_err());
    }

    proptest::proptest! {
        // arbitrary bytes never panic the decoders, in either serialisation
        #[test]
        fn decoders_never_panic(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..200), cdr in proptest::bool::ANY) {
            let mk = || if cdr { Decoder::cdr(&bytes).ok() } else { Some(Decoder::ros1(&bytes)) };
            if let Some(mut d) = mk() { let _ = decode_scan(&mut d); }
            if let Some(mut d) = mk() { let _ = decode_odometry(&mut d); }
            if let Some(mut d) = mk() { let _ = decode_tf(&mut d); }
        }
    }

    #[test]
    fn mount_follows_static_chain() {
        let mut b = RecordingBuilder::new();
        b.add_scan(ScanMsg {
            stamp_ns: 10,
            frame_id: "laser".into(),
            angle_min: -1.0,
            angle_max: 1.0,
            angle_increment: 1.0,
            range_min: 0.0,
            range_max: 30.0,
            ranges: vec![1.0, 2.0, 3.0],
        })
        .unwrap();
        b.add_odometry(OdomMsg {
            stamp_ns: 5,
            frame_id: "odom".into(),
            child_frame_id: "base_link".into(),
            pose: Pose2::IDENTITY,
        });
        let tf = |parent: &str, child: &str, p: Pose2| TfMsg {
            parent: parent.into(),
            child: child.into(),
            parent_from_child: Rigid3::from_pose2(&p),
        };
        b.add_tf_static(vec![
            tf("mast", "laser", Pose2::new(0.1, 0.0, 0.0)),
            tf(
                "base_link",
                "mast",
                Pose2::new(0.2, 0.0, std::f64::consts::FRAC_PI_2),
            ),
        ]);
        let (rec, stats) = b.finish("t".into(), &RosOptions::default()).unwrap();
        assert!(stats.mount_from_tf);
        // base_from_laser = base_from_mast * mast_from_laser: (0.2, 0.1)
        let t = rec.body_from_lidar.translation;
        assert!(
            (t.x - 0.2).abs() < 1e-12 && (t.y - 0.1).abs() < 1e-12,
            "{t:?}"
        );
        // not CARMEN-shaped: geometry as recorded
        assert_eq!(rec.lidar.beam_count, 3);
        assert_eq!(rec.lidar.angle_increment_rad, 1.0);
        assert_eq!(rec.lidar.range_max_m, 30.0);
    }
}
