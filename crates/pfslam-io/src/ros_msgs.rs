//! Decoding of the ROS messages the recordings need (`sensor_msgs/LaserScan`,
//! `sensor_msgs/MultiEchoLaserScan`, `nav_msgs/Odometry`, `tf2_msgs/TFMessage`) from ROS 1
//! serialisation or ROS 2 CDR (little endian). [`super::ros_assemble`] turns the decoded
//! messages into a recording.

use pfslam::geometry::{Pose2, Rigid3};

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
    /// `header.stamp` (ns).
    pub stamp_ns: i64,
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

/// Decodes a `sensor_msgs/MultiEchoLaserScan`, keeping each beam's first echo (a beam
/// without echo is "no return", NaN).
pub fn decode_multi_echo_scan(d: &mut Decoder<'_>) -> Result<ScanMsg, String> {
    let (stamp_ns, frame_id) = d.header()?;
    let mut v = [0f32; 7];
    for (x, name) in v.iter_mut().zip([
        "angle_min",
        "angle_max",
        "angle_increment",
        "time_increment",
        "scan_time",
        "range_min",
        "range_max",
    ]) {
        *x = d.f32(name)?;
    }
    let n = d.u32("ranges")? as usize;
    // each echo list takes at least its 4-byte length: a larger count is a corrupt message
    if n > d.buf.len() / 4 {
        return Err(format!("ranges: {n} beams cannot fit in the message"));
    }
    let mut ranges = Vec::with_capacity(n);
    let mut echoes = Vec::new();
    for _ in 0..n {
        d.f32_seq("echoes", &mut echoes)?;
        ranges.push(echoes.first().copied().unwrap_or(f32::NAN));
    }
    Ok(ScanMsg {
        stamp_ns,
        frame_id,
        angle_min: v[0],
        angle_max: v[1],
        angle_increment: v[2],
        range_min: v[5],
        range_max: v[6],
        ranges,
    })
}

/// A decoded `sensor_msgs/Imu` (what the motion model uses of it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuMsg {
    /// `header.stamp` (ns).
    pub stamp_ns: i64,
    /// Yaw of the orientation (rad), when the message has one (`orientation_covariance[0]`
    /// is not -1, the ROS mark of "no orientation").
    pub yaw_rad: Option<f64>,
    /// Angular velocity about z (rad/s).
    pub yaw_rate_rad_per_s: f64,
}

/// Decodes a `sensor_msgs/Imu`.
pub fn decode_imu(d: &mut Decoder<'_>) -> Result<ImuMsg, String> {
    let (stamp_ns, _) = d.header()?;
    let mut q = [0.0; 4];
    for v in &mut q {
        *v = d.f64("orientation")?;
    }
    let mut cov = [0.0; 9];
    for v in &mut cov {
        *v = d.f64("orientation_covariance")?;
    }
    let mut w = [0.0; 3];
    for v in &mut w {
        *v = d.f64("angular_velocity")?;
    }
    let has_orientation = cov[0] != -1.0 && q.iter().all(|v| v.is_finite());
    let norm = q.iter().map(|v| v * v).sum::<f64>();
    if !w[2].is_finite() {
        return Err("angular_velocity.z is not finite".into());
    }
    Ok(ImuMsg {
        stamp_ns,
        yaw_rad: (has_orientation && norm > 0.5).then(|| yaw_of(q)),
        yaw_rate_rad_per_s: w[2],
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
        let (stamp_ns, parent) = d.header()?;
        let child = d.string("child_frame_id")?;
        let (t, q) = d.pose3()?;
        out.push(TfMsg {
            stamp_ns,
            parent,
            child,
            parent_from_child: rigid_of(t, q),
        });
    }
    Ok(out)
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
        /// A planar pose as `geometry_msgs/Pose` (position, then the yaw's quaternion).
        fn planar_pose(&mut self, pose: &pfslam::geometry::Pose2) {
            let half = 0.5 * pose.yaw_rad;
            for v in [pose.x_m, pose.y_m, 0.0, 0.0, 0.0, half.sin(), half.cos()] {
                self.f64(v);
            }
        }
        /// The bytes.
        pub fn into_bytes(self) -> Vec<u8> {
            self.buf
        }
    }

    /// The fields both laser-scan messages begin with: header, angles, the two times
    /// (left 0), range limits.
    fn scan_head(m: &ScanMsg) -> CdrWriter {
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
        w
    }

    /// `sensor_msgs/msg/LaserScan` as CDR.
    pub fn scan_cdr(m: &ScanMsg) -> Vec<u8> {
        let mut w = scan_head(m);
        w.u32(m.ranges.len() as u32);
        for &r in &m.ranges {
            w.f32(r);
        }
        w.u32(0); // intensities
        w.into_bytes()
    }

    /// `sensor_msgs/msg/MultiEchoLaserScan` as CDR: `echoes[k]` are beam `k`'s echoes.
    pub fn multi_echo_scan_cdr(m: &ScanMsg, echoes: &[Vec<f32>]) -> Vec<u8> {
        let mut w = scan_head(m);
        w.u32(echoes.len() as u32);
        for e in echoes {
            w.u32(e.len() as u32);
            for &r in e {
                w.f32(r);
            }
        }
        w.u32(0); // intensities
        w.into_bytes()
    }

    /// A `tf2_msgs/msg/TFMessage` of one planar transform `frame_id -> child_frame_id`.
    pub fn tf_cdr(m: &OdomMsg) -> Vec<u8> {
        let mut w = CdrWriter::new();
        w.u32(1);
        w.header(m.stamp_ns, &m.frame_id);
        w.string(&m.child_frame_id);
        w.planar_pose(&m.pose);
        w.into_bytes()
    }

    /// `sensor_msgs/msg/Imu` as CDR: the yaw as orientation (or, `None`, covariance -1 for
    /// "no orientation") and the yaw rate.
    pub fn imu_cdr(stamp_ns: i64, yaw_rad: Option<f64>, yaw_rate_rad_per_s: f64) -> Vec<u8> {
        let mut w = CdrWriter::new();
        w.header(stamp_ns, "imu");
        let half = 0.5 * yaw_rad.unwrap_or(0.0);
        for v in [0.0, 0.0, half.sin(), half.cos()] {
            w.f64(v);
        }
        let cov0 = if yaw_rad.is_some() { 0.0 } else { -1.0 };
        for k in 0..9 {
            w.f64(if k == 0 { cov0 } else { 0.0 });
        }
        for v in [0.0, 0.0, yaw_rate_rad_per_s] {
            w.f64(v);
        }
        for _ in 0..(9 + 3 + 9) {
            w.f64(0.0);
        }
        w.into_bytes()
    }

    /// `nav_msgs/msg/Odometry` as CDR (zero covariances and twist).
    pub fn odometry_cdr(m: &OdomMsg) -> Vec<u8> {
        let mut w = CdrWriter::new();
        w.header(m.stamp_ns, &m.frame_id);
        w.string(&m.child_frame_id);
        w.planar_pose(&m.pose);
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
            if let Some(mut d) = mk() { let _ = decode_multi_echo_scan(&mut d); }
            if let Some(mut d) = mk() { let _ = decode_imu(&mut d); }
        }
    }
}
