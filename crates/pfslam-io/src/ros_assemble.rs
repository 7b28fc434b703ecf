//! ROS recordings (ROS 1 bags, MCAP) into a [`Recording`]: which topics and frames to use,
//! and the assembly of the decoded messages; shared by [`super::ros1`] and [`super::mcap`].
//!
//! - **Topics**: the scan topic is `[input] scan_topic` when given, else the only
//!   `LaserScan` (or `MultiEchoLaserScan`, first echo) topic, or `/scan` among several; the
//!   odometry likewise (`nav_msgs/Odometry`, `/odom` among several). A missing topic's
//!   error lists the topics present with their types and counts.
//! - **Odometry** from the odometry topic or, when the recording has none, from the `/tf`
//!   transforms `odom_frame -> base_frame` (`odom` and the first child of `odom` by default).
//! - **Beam geometry** per scan ([`BeamGeometry`]): `auto` (default) gives scans converted from
//!   a CARMEN log (every scan 180/181/360/361 beams spanning 180 deg from -90 deg, the
//!   Freiburg bags) the CARMEN geometry ([`super::carmen::carmen_geometry`]: their converter
//!   wrote `angle_increment = fov / (n - 1)`, which is not how those lasers sampled); every
//!   other recording keeps each scan's geometry as recorded, so beam counts and angles may
//!   change from scan to scan.
//! - **Stamps**: scans by `header.stamp` (not the bag's receive time), odometry likewise.
//!   Scans are all kept and sorted by stamp (a repeated stamp is dropped and counted);
//!   odometry keeps its longest strictly increasing run (the Intel bag: 631 scans, 602
//!   odometry messages out of order).
//! - **Laser mount** `body_from_lidar`: the chain of `/tf_static` (else first `/tf`)
//!   transforms from the base frame to the scan's `frame_id` (identity, with a warning,
//!   when the chain is absent).

use super::account::InputAccount;
use super::clock::{longest_increasing, sort_scans};
use super::options::ReaderOptions;
use super::ros_msgs::{
    Decoder, OdomMsg, ScanMsg, TfMsg, decode_imu, decode_multi_echo_scan, decode_odometry,
    decode_scan, decode_tf,
};
use pfslam::geometry::{Rigid3, StampedPose2, Trajectory};
pub use pfslam::sensors::reader_options::BeamGeometry;
use pfslam::sensors::{LidarGeometry, Recording, ScanSet};
use serde::{Deserialize, Serialize};

/// One topic of a recording.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TopicInfo {
    /// The topic.
    pub topic: String,
    /// Its message type as recorded (`sensor_msgs/LaserScan`, `sensor_msgs/msg/LaserScan`).
    pub type_name: String,
    /// Messages on it.
    pub count: usize,
}

/// The topics of a recording and the time its messages span.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TopicTable {
    /// The topics, in order of first appearance.
    pub topics: Vec<TopicInfo>,
    /// First and last message time (ns), when there are messages.
    pub span_ns: Option<(i64, i64)>,
}

/// What a message type is to the readers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MsgKind {
    /// `sensor_msgs/LaserScan`.
    Scan,
    /// `sensor_msgs/MultiEchoLaserScan`.
    MultiEchoScan,
    /// `nav_msgs/Odometry`.
    Odometry,
    /// `tf2_msgs/TFMessage`.
    Tf,
    /// `sensor_msgs/Imu`.
    Imu,
}

/// The kind of a ROS 1 or ROS 2 type name, if the readers use it.
pub fn msg_kind(type_name: &str) -> Option<MsgKind> {
    match type_name.replace("/msg/", "/").as_str() {
        "sensor_msgs/LaserScan" => Some(MsgKind::Scan),
        "sensor_msgs/MultiEchoLaserScan" => Some(MsgKind::MultiEchoScan),
        "nav_msgs/Odometry" => Some(MsgKind::Odometry),
        "tf2_msgs/TFMessage" | "tf/tfMessage" => Some(MsgKind::Tf),
        "sensor_msgs/Imu" => Some(MsgKind::Imu),
        _ => None,
    }
}

/// The topics a reader uses.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChosenTopics {
    /// Scans.
    pub scan: String,
    /// Odometry, when the recording has an odometry topic.
    pub odom: Option<String>,
    /// Dynamic transforms (`/tf`), when present.
    pub tf: Option<String>,
    /// Static transforms (`/tf_static`), when present.
    pub tf_static: Option<String>,
    /// IMU, when asked for.
    pub imu: Option<String>,
}

impl ChosenTopics {
    /// True when messages on `topic` are read.
    pub fn uses(&self, topic: &str) -> bool {
        topic == self.scan
            || [&self.odom, &self.tf, &self.tf_static, &self.imu]
                .iter()
                .any(|t| t.as_deref() == Some(topic))
    }
}

/// The topics as a list for error messages.
pub fn list_topics(topics: &[TopicInfo]) -> String {
    if topics.is_empty() {
        return "the recording has no topic".into();
    }
    let items: Vec<String> = topics
        .iter()
        .map(|t| format!("{} ({}, {} messages)", t.topic, t.type_name, t.count))
        .collect();
    format!("topics present: {}", items.join(", "))
}

/// Chooses the topics by the rules of the module docs.
pub fn choose_topics(
    topics: &[TopicInfo],
    options: &ReaderOptions,
) -> Result<ChosenTopics, String> {
    let of = |kinds: &[MsgKind]| -> Vec<&TopicInfo> {
        topics
            .iter()
            .filter(|t| msg_kind(&t.type_name).is_some_and(|k| kinds.contains(&k)))
            .collect()
    };
    let scan_kinds = [MsgKind::Scan, MsgKind::MultiEchoScan];
    let scan = pick(
        topics,
        &of(&scan_kinds),
        &options.scan_topic,
        "/scan",
        "scan",
        &scan_kinds,
    )?
    .ok_or_else(|| format!("no LaserScan topic; {}", list_topics(topics)))?;
    let odom = pick(
        topics,
        &of(&[MsgKind::Odometry]),
        &options.odom_topic,
        "/odom",
        "odometry",
        &[MsgKind::Odometry],
    )?;
    let tf = |name: &str| {
        topics
            .iter()
            .find(|t| t.topic == name && msg_kind(&t.type_name) == Some(MsgKind::Tf))
            .map(|t| t.topic.clone())
    };
    let imu = match &options.imu_topic {
        Some(_) => pick(topics, &[], &options.imu_topic, "", "IMU", &[MsgKind::Imu])?,
        None => None,
    };
    Ok(ChosenTopics {
        scan,
        odom,
        tf: tf("/tf"),
        tf_static: tf("/tf_static"),
        imu,
    })
}

/// The requested topic (checked), else the only candidate, else `usual` among several.
fn pick(
    topics: &[TopicInfo],
    candidates: &[&TopicInfo],
    requested: &Option<String>,
    usual: &str,
    what: &str,
    kinds: &[MsgKind],
) -> Result<Option<String>, String> {
    if let Some(want) = requested {
        return match topics.iter().find(|t| &t.topic == want) {
            Some(t) if msg_kind(&t.type_name).is_some_and(|k| kinds.contains(&k)) => {
                Ok(Some(want.clone()))
            }
            Some(t) => Err(format!(
                "{what} topic {want} carries {}, not a {what} type; {}",
                t.type_name,
                list_topics(topics)
            )),
            None => Err(format!(
                "no topic {want} (the {what} topic asked for); {}",
                list_topics(topics)
            )),
        };
    }
    match candidates {
        [] => Ok(None),
        [one] => Ok(Some(one.topic.clone())),
        many => match many.iter().find(|t| t.topic == usual) {
            Some(t) => Ok(Some(t.topic.clone())),
            None => Err(format!(
                "several {what} topics, choose one with --{}-topic; {}",
                if what == "scan" { "scan" } else { "odom" },
                list_topics(topics)
            )),
        },
    }
}

/// Per-scan layout fields of a message.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Layout {
    angle_min: f32,
    angle_max: f32,
    angle_increment: f32,
    range_min: f32,
    range_max: f32,
}

/// Collects decoded messages and turns them into a [`Recording`].
#[derive(Debug, Default)]
pub struct RecordingBuilder {
    scans: ScanSet,
    layouts: Vec<Layout>,
    scan_frame: String,
    odom: Vec<StampedPose2>,
    odom_child: Option<String>,
    tf_odom: Vec<StampedPose2>,
    tf_base: Option<String>,
    tf_static: Vec<TfMsg>,
    tf_first: Vec<TfMsg>,
    imu: Vec<pfslam::motion::imu_yaw::ImuSample>,
    dropped_empty: usize,
}

impl RecordingBuilder {
    /// An empty builder.
    pub fn new() -> Self {
        RecordingBuilder::default()
    }

    /// Decodes one message of a chosen topic into the builder (`d` positioned at its
    /// payload); messages of other topics are skipped.
    pub fn add_message(
        &mut self,
        chosen: &ChosenTopics,
        options: &ReaderOptions,
        topic: &str,
        type_name: &str,
        d: &mut Decoder<'_>,
    ) -> Result<(), String> {
        if topic == chosen.scan {
            let scan = match msg_kind(type_name) {
                Some(MsgKind::MultiEchoScan) => decode_multi_echo_scan(d)?,
                _ => decode_scan(d)?,
            };
            self.add_scan(scan);
        } else if Some(topic) == chosen.odom.as_deref() {
            self.add_odometry(decode_odometry(d)?);
        } else if Some(topic) == chosen.tf_static.as_deref() {
            self.add_tf_static(decode_tf(d)?);
        } else if Some(topic) == chosen.tf.as_deref() {
            self.add_tf(decode_tf(d)?, options);
        } else if Some(topic) == chosen.imu.as_deref() {
            self.add_imu(decode_imu(d)?);
        }
        Ok(())
    }

    /// Adds a scan (one with no range is dropped and counted).
    pub fn add_scan(&mut self, msg: ScanMsg) {
        if msg.ranges.is_empty() {
            self.dropped_empty += 1;
            return;
        }
        if self.scans.is_empty() {
            self.scan_frame = msg.frame_id.clone();
        }
        self.scans.push_any(msg.stamp_ns, &msg.ranges);
        self.layouts.push(Layout {
            angle_min: msg.angle_min,
            angle_max: msg.angle_max,
            angle_increment: msg.angle_increment,
            range_min: msg.range_min,
            range_max: msg.range_max,
        });
    }

    /// Adds an odometry pose.
    pub fn add_odometry(&mut self, msg: OdomMsg) {
        if self.odom_child.is_none() && !msg.child_frame_id.is_empty() {
            self.odom_child = Some(msg.child_frame_id);
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

    /// Adds dynamic transforms: `odom_frame -> base` ones become odometry, the first of every
    /// other edge may serve for the laser mount.
    pub fn add_tf(&mut self, tfs: Vec<TfMsg>, options: &ReaderOptions) {
        let odom_frame = options.odom_frame.as_deref().unwrap_or("odom");
        for t in tfs {
            let base = options.base_frame.as_deref().or(self.tf_base.as_deref());
            if t.parent.trim_start_matches('/') == odom_frame.trim_start_matches('/')
                && base.is_none_or(|b| b == t.child)
            {
                if self.tf_base.is_none() {
                    self.tf_base = Some(t.child.clone());
                }
                self.tf_odom.push(StampedPose2 {
                    stamp_ns: t.stamp_ns,
                    pose: t.parent_from_child.to_pose2(),
                });
            } else if !self.tf_first.iter().any(|f| f.child == t.child) {
                self.tf_first.push(t);
            }
        }
    }

    /// Adds an IMU sample.
    pub fn add_imu(&mut self, msg: super::ros_msgs::ImuMsg) {
        self.imu
            .push((msg.stamp_ns, msg.yaw_rad, msg.yaw_rate_rad_per_s));
    }

    /// `body_from_lidar` by walking the transforms from the scan frame up to the body frame;
    /// `None` when there is no such chain.
    fn mount(&self, body: &str) -> Option<(Rigid3, &'static str)> {
        let norm = |f: &str| f.trim_start_matches('/').to_string();
        let mut frame = norm(&self.scan_frame);
        let mut acc = Rigid3::IDENTITY;
        let mut source = "/tf_static";
        for _ in 0..64 {
            if frame == norm(body) {
                return Some((acc, source));
            }
            let tf = match self.tf_static.iter().find(|t| norm(&t.child) == frame) {
                Some(t) => t,
                None => {
                    source = "/tf (first transforms)";
                    self.tf_first.iter().find(|t| norm(&t.child) == frame)?
                }
            };
            acc = tf.parent_from_child.compose(&acc);
            frame = norm(&tf.parent);
        }
        None
    }

    /// The recording, its account filled in; `Err` with a message when there is no scan or
    /// no odometry.
    pub fn finish(
        mut self,
        name: String,
        topics: &ChosenTopics,
        options: &ReaderOptions,
        mut acc: InputAccount,
    ) -> Result<(Recording, InputAccount), String> {
        if self.scans.is_empty() {
            return Err(format!(
                "no LaserScan message with ranges on {}",
                topics.scan
            ));
        }
        acc.scans_read = self.scans.len() + self.dropped_empty;
        acc.drop_many("scans", "without any range", self.dropped_empty);
        let (odometry_src, source) = self.take_odometry(topics, options, &mut acc);
        let geometry = self.geometries(options);
        let body_from_lidar = self.body_from_lidar(options, &mut acc);
        let (scans, geometry) =
            sort_scans_with_geometry(self.scans, &geometry, self.dropped_empty, &mut acc);
        let odometry = kept_odometry(&odometry_src, source, topics, &mut self.imu, &mut acc)?;
        acc.scans_kept = scans.len();
        acc.clock = "header stamps".into();
        let uniform = geometry.windows(2).all(|w| w[0] == w[1]);
        let rec = Recording {
            name,
            odometry,
            imu_yaw: None,
            lidar: geometry[0],
            lidar_per_scan: (!uniform).then_some(geometry),
            scans,
            body_from_lidar,
            body_from_lidar_per_scan: None,
            ground_truth: None,
        };
        Ok((rec, acc))
    }

    /// The odometry poses (the odometry topic's, else the `/tf` ones, else none with a
    /// warning) and a description of where they come from.
    fn take_odometry(
        &mut self,
        topics: &ChosenTopics,
        options: &ReaderOptions,
        acc: &mut InputAccount,
    ) -> (Vec<StampedPose2>, String) {
        if !self.odom.is_empty() {
            let t = topics.odom.as_deref().unwrap_or("?");
            (
                std::mem::take(&mut self.odom),
                format!("{t} (nav_msgs/Odometry)"),
            )
        } else if !self.tf_odom.is_empty() {
            let base = self.tf_base.as_deref().unwrap_or("?");
            let odom = options.odom_frame.as_deref().unwrap_or("odom");
            let source = format!("/tf {odom} -> {base}");
            (std::mem::take(&mut self.tf_odom), source)
        } else {
            acc.warnings.push(format!(
                "no odometry (no Odometry topic, no /tf transform from {:?}): LiDAR-only, the motion comes from scan matching",
                options.odom_frame.as_deref().unwrap_or("odom")
            ));
            (Vec::new(), "none in the recording".to_string())
        }
    }

    /// The laser mount in the body frame (identity, with a warning, when no transform chain
    /// leads from the scan frame to the body frame); its source goes to the account.
    fn body_from_lidar(&self, options: &ReaderOptions, acc: &mut InputAccount) -> Rigid3 {
        let body = options
            .base_frame
            .clone()
            .or(self.odom_child.clone())
            .or(self.tf_base.clone())
            .unwrap_or_default();
        match self.mount(&body) {
            Some((m, src)) => {
                acc.mount_source = format!("{src}: {body} -> {}", self.scan_frame);
                m
            }
            None => {
                acc.mount_source = "identity (no transform chain)".into();
                acc.warnings.push(format!(
                    "no transform chain from {:?} to {body:?}: the laser mount is taken as identity",
                    self.scan_frame
                ));
                Rigid3::IDENTITY
            }
        }
    }

    /// Each scan's geometry by [`BeamGeometry`].
    fn geometries(&self, options: &ReaderOptions) -> Vec<LidarGeometry> {
        let n_of = |i: usize| self.scans.ranges(i).len();
        let first = self.layouts[0];
        let same = self.scans.is_uniform() && self.layouts.iter().all(|l| *l == first);
        let carmen = match options.beam_geometry {
            BeamGeometry::Auto => same && looks_carmen(&first, n_of(0)),
            BeamGeometry::AsRecorded => false,
            BeamGeometry::Carmen => true,
        };
        (0..self.scans.len())
            .map(|i| {
                let (l, n) = (self.layouts[i], n_of(i));
                if carmen {
                    let max = super::carmen::CarmenOptions::default().range_max_m;
                    super::carmen::carmen_geometry(n, options.range_max_m.unwrap_or(max))
                } else {
                    let max = if l.range_max.is_finite() && l.range_max > 0.0 {
                        l.range_max
                    } else {
                        f32::MAX
                    };
                    LidarGeometry {
                        angle_min_rad: f64::from(l.angle_min),
                        angle_increment_rad: f64::from(l.angle_increment),
                        beam_count: n,
                        range_min_m: scan_range_min(
                            l.range_min,
                            options.range_max_m.unwrap_or(max),
                        ),
                        range_max_m: options.range_max_m.unwrap_or(max),
                    }
                }
            })
            .collect()
    }
}

/// The scans sorted by stamp (repeats dropped) with their geometries in the same order;
/// the repairs and drops go to the account.
fn sort_scans_with_geometry(
    scans: ScanSet,
    geometry: &[LidarGeometry],
    dropped_empty: usize,
    acc: &mut InputAccount,
) -> (ScanSet, Vec<LidarGeometry>) {
    let (scans, order, moved) = sort_scans(scans);
    let geometry: Vec<LidarGeometry> = order.iter().map(|&i| geometry[i]).collect();
    acc.repair(
        "scans",
        "stamp not above the previous one: sorted into place",
        moved,
    );
    acc.drop_many(
        "scans",
        "stamp repeats another scan's",
        acc.scans_read - dropped_empty - scans.len(),
    );
    for g in &geometry {
        acc.add_layout(g);
    }
    (scans, geometry)
}

/// The odometry's longest strictly increasing run by stamp, turned by the IMU yaw when an
/// IMU topic is chosen; `Err` when that topic has no message.
fn kept_odometry(
    odometry_src: &[StampedPose2],
    source: String,
    topics: &ChosenTopics,
    imu: &mut [pfslam::motion::imu_yaw::ImuSample],
    acc: &mut InputAccount,
) -> Result<Trajectory, String> {
    let stamps: Vec<i64> = odometry_src.iter().map(|p| p.stamp_ns).collect();
    let keep = longest_increasing(&stamps);
    acc.odometry_read = odometry_src.len();
    acc.odometry_kept = keep.len();
    let mut odometry = Trajectory::new(keep.iter().map(|&i| odometry_src[i]).collect());
    if let Some(topic) = &topics.imu {
        imu.sort_by_key(|s| s.0);
        let series = pfslam::motion::imu_yaw::yaw_series(imu);
        if series.is_empty() {
            return Err(format!("no IMU message on {topic}"));
        }
        odometry = pfslam::motion::imu_yaw::fuse_odometry_with_imu_yaw(&odometry, &series);
        acc.odometry_source = format!("{source}, turning from {topic} (sensor_msgs/Imu)");
    } else {
        acc.odometry_source = source;
    }
    acc.drop_many(
        "odometry",
        "stamp out of order or repeated",
        odometry_src.len() - keep.len(),
    );
    Ok(odometry)
}

/// A scan converted from a CARMEN log: 180/181/360/361 beams over 180 deg from -90 deg.
fn looks_carmen(l: &Layout, n: usize) -> bool {
    let span_deg = (f64::from(l.angle_max) - f64::from(l.angle_min)).to_degrees();
    matches!(n, 180 | 181 | 360 | 361)
        && (f64::from(l.angle_min).to_degrees() + 90.0).abs() < 0.5
        && (span_deg - 180.0).abs() < 0.5
}

/// A LaserScan's `range_min` as the geometry's minimum: 0 when it is not a finite number
/// below the maximum (a driver that leaves it unset or garbage must not drop every return).
fn scan_range_min(range_min: f32, range_max_m: f32) -> f32 {
    if range_min.is_finite() && range_min > 0.0 && range_min < range_max_m {
        range_min
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pfslam::geometry::Pose2;

    fn scan(stamp_ns: i64, frame: &str, n: usize, angle_min: f32) -> ScanMsg {
        ScanMsg {
            stamp_ns,
            frame_id: frame.into(),
            angle_min,
            angle_max: angle_min + n as f32 * 0.01,
            angle_increment: 0.01,
            range_min: 0.0,
            range_max: 30.0,
            ranges: vec![1.0; n],
        }
    }

    fn tf(parent: &str, child: &str, p: Pose2) -> TfMsg {
        TfMsg {
            stamp_ns: 0,
            parent: parent.into(),
            child: child.into(),
            parent_from_child: Rigid3::from_pose2(&p),
        }
    }

    fn topics() -> ChosenTopics {
        ChosenTopics {
            scan: "/scan".into(),
            odom: Some("/odom".into()),
            tf: None,
            tf_static: None,
            imu: None,
        }
    }

    #[test]
    fn mount_follows_static_chain() {
        let mut b = RecordingBuilder::new();
        b.add_scan(scan(10, "laser", 3, -1.0));
        b.add_odometry(OdomMsg {
            stamp_ns: 5,
            frame_id: "odom".into(),
            child_frame_id: "base_link".into(),
            pose: Pose2::IDENTITY,
        });
        b.add_tf_static(vec![
            tf("mast", "laser", Pose2::new(0.1, 0.0, 0.0)),
            tf(
                "base_link",
                "mast",
                Pose2::new(0.2, 0.0, std::f64::consts::FRAC_PI_2),
            ),
        ]);
        let acc = InputAccount::default();
        let (rec, acc) = b
            .finish("t".into(), &topics(), &ReaderOptions::default(), acc)
            .unwrap();
        assert!(
            acc.mount_source.starts_with("/tf_static"),
            "{}",
            acc.mount_source
        );
        // base_from_laser = base_from_mast * mast_from_laser: (0.2, 0.1)
        let t = rec.body_from_lidar.translation;
        assert!(
            (t.x - 0.2).abs() < 1e-12 && (t.y - 0.1).abs() < 1e-12,
            "{t:?}"
        );
        // not CARMEN-shaped: geometry as recorded
        assert_eq!(rec.lidar.beam_count, 3);
        assert_eq!(rec.lidar.angle_increment_rad, f64::from(0.01f32));
        assert_eq!(rec.lidar.range_max_m, 30.0);
        assert!(rec.lidar_per_scan.is_none());
    }

    #[test]
    fn mixed_layouts_and_odometry_from_tf() {
        let mut b = RecordingBuilder::new();
        let opts = ReaderOptions::default();
        for k in 0..4i64 {
            let n = if k % 2 == 0 { 181 } else { 180 };
            b.add_scan(scan(10 + k, "laser", n, -1.5 + 0.001 * k as f32));
            let odom = TfMsg {
                stamp_ns: 10 + k,
                ..tf("odom", "base_footprint", Pose2::new(k as f64, 0.0, 0.0))
            };
            b.add_tf(vec![odom], &opts);
        }
        b.add_tf(
            vec![tf("base_footprint", "laser", Pose2::new(0.3, 0.0, 0.0))],
            &opts,
        );
        let acc = InputAccount::default();
        let t = ChosenTopics {
            odom: None,
            ..topics()
        };
        let (rec, acc) = b.finish("t".into(), &t, &opts, acc).unwrap();
        let per = rec.lidar_per_scan.as_ref().unwrap();
        assert_eq!(per.len(), 4);
        assert_eq!((per[0].beam_count, per[1].beam_count), (181, 180));
        assert_eq!(rec.scans.ranges(1).len(), 180);
        assert_eq!(acc.beam_layouts.len(), 4);
        assert_eq!(rec.odometry.len(), 4);
        assert!(
            acc.odometry_source.contains("odom -> base_footprint"),
            "{}",
            acc.odometry_source
        );
        assert!((rec.body_from_lidar.translation.x - 0.3).abs() < 1e-12);
    }

    #[test]
    fn topics_by_type_or_name_with_a_listing() {
        let t = |topic: &str, ty: &str| TopicInfo {
            topic: topic.into(),
            type_name: ty.into(),
            count: 3,
        };
        let all = vec![
            t("/base_scan", "sensor_msgs/LaserScan"),
            t("/pose", "nav_msgs/Odometry"),
            t("/tf", "tf2_msgs/TFMessage"),
        ];
        let c = choose_topics(&all, &ReaderOptions::default()).unwrap();
        assert_eq!(
            (c.scan.as_str(), c.odom.as_deref()),
            ("/base_scan", Some("/pose"))
        );
        assert_eq!(c.tf.as_deref(), Some("/tf"));
        let asked = ReaderOptions {
            scan_topic: Some("/scan".into()),
            ..ReaderOptions::default()
        };
        let e = choose_topics(&all, &asked).unwrap_err();
        assert!(
            e.contains("no topic /scan")
                && e.contains("/base_scan (sensor_msgs/LaserScan, 3 messages)"),
            "{e}"
        );
        let two = vec![
            t("/a", "sensor_msgs/msg/LaserScan"),
            t("/b", "sensor_msgs/LaserScan"),
        ];
        let e = choose_topics(&two, &ReaderOptions::default()).unwrap_err();
        assert!(e.contains("several scan topics"), "{e}");
    }

    #[test]
    fn a_scan_states_its_own_minimum_unless_it_is_garbage() {
        assert_eq!(scan_range_min(0.45, 30.0), 0.45);
        for bad in [f32::NAN, -1.0, 0.0, 40.0] {
            assert_eq!(scan_range_min(bad, 30.0), 0.0, "{bad}");
        }
    }
}
