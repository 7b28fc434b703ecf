//! The input flags shared by the commands that read a recording, and the account they print.

use pfslam::config::Config;
use pfslam_io::account::InputAccount;
use pfslam_io::recording::ReaderOptions;

/// Topic, frame, strictness and span flags (over `[input]` of the configuration).
#[derive(Debug, Default, Clone, clap::Args)]
pub struct InputArgs {
    /// ROS topic of the scans (default: the only LaserScan topic, or /scan among several).
    #[arg(long)]
    pub scan_topic: Option<String>,
    /// ROS topic of the odometry (default: the only Odometry topic, or /odom; none: /tf).
    #[arg(long)]
    pub odom_topic: Option<String>,
    /// ROS body frame (default: the odometry's child frame).
    #[arg(long)]
    pub base_frame: Option<String>,
    /// ROS odometry frame in /tf (default: odom).
    #[arg(long)]
    pub odom_frame: Option<String>,
    /// ROS topic of sensor_msgs/Imu: its yaw replaces the odometry's turning.
    #[arg(long)]
    pub imu_topic: Option<String>,
    /// Malformed lines of a CARMEN log are errors instead of counted drops.
    #[arg(long)]
    pub strict: bool,
    /// Only the recording from this many seconds after its first scan.
    #[arg(long)]
    pub start_s: Option<f64>,
    /// Only the recording up to this many seconds after its first scan.
    #[arg(long)]
    pub end_s: Option<f64>,
}

impl InputArgs {
    /// The configuration of `path` (or the defaults) with these flags over its `[input]`.
    pub fn config(&self, path: Option<&std::path::Path>) -> anyhow::Result<Config> {
        let mut config = match path {
            Some(p) => Config::from_toml_file(p)?,
            None => Config::default(),
        };
        self.apply(&mut config.input)?;
        Ok(config)
    }

    /// The flags given, over `options`; then checks the result.
    pub fn apply(&self, options: &mut ReaderOptions) -> anyhow::Result<()> {
        let set = |dst: &mut Option<String>, src: &Option<String>| {
            if src.is_some() {
                dst.clone_from(src);
            }
        };
        set(&mut options.scan_topic, &self.scan_topic);
        set(&mut options.odom_topic, &self.odom_topic);
        set(&mut options.base_frame, &self.base_frame);
        set(&mut options.odom_frame, &self.odom_frame);
        set(&mut options.imu_topic, &self.imu_topic);
        options.strict |= self.strict;
        if self.start_s.is_some() {
            options.start_s = self.start_s;
        }
        if self.end_s.is_some() {
            options.end_s = self.end_s;
        }
        options.validate().map_err(anyhow::Error::msg)
    }
}

/// Prints the account on stdout and its warnings on stderr.
pub fn report(account: &InputAccount) {
    say!("{}", account.one_line());
    for w in account.all_warnings() {
        eprintln!("warning: {w}");
    }
}
