//! What a reader read, kept, dropped and repaired: nothing a reader leaves out goes unreported.
//!
//! Every reader fills an [`InputAccount`]; `pfslam run`, `map` and `dead-reckon` print its
//! [`InputAccount::one_line`] and `summary.json` stores it under `"input"`. A share of dropped
//! scans above [`DROPPED_SCANS_WARNING_SHARE`] is a warning.

use pfslam::sensors::LidarGeometry;
use serde::{Deserialize, Serialize};

/// Dropping more than this share of the scans read is a warning.
pub const DROPPED_SCANS_WARNING_SHARE: f64 = 0.01;

/// A count of records dropped or repaired for one reason.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Tally {
    /// What was affected: `scans`, `odometry`, `lines`, `messages`, `rows`.
    pub what: String,
    /// Why.
    pub reason: String,
    /// How many.
    pub count: usize,
    /// Where the first one was (`line 12`, `message 40`), when known.
    pub first_at: Option<String>,
}

/// One beam layout seen in the recording and how many scans had it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BeamLayout {
    /// Beams per scan.
    pub beams: usize,
    /// Angle of the first beam (deg).
    pub angle_min_deg: f64,
    /// Step between beams (deg).
    pub angle_increment_deg: f64,
    /// Readings at or above this range mean "no return" (m).
    pub range_max_m: f32,
    /// Scans with this layout.
    pub scans: usize,
}

/// What a reader read, kept, dropped and repaired.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct InputAccount {
    /// The format read (`carmen`, `ros1_bag`, `mcap`, `ucsd_car`, `humanoid`).
    pub format: String,
    /// The file or directory read.
    pub path: String,
    /// What `records_read` counts (`lines`, `messages`, `rows`).
    pub records_unit: String,
    /// Records read in all (lines of a log, messages of a bag, rows of CSV files).
    pub records_read: usize,
    /// Scans found in the input.
    pub scans_read: usize,
    /// Scans the recording holds.
    pub scans_kept: usize,
    /// Scans left out because they lie outside the span asked for (`--start-s`, `--end-s`).
    pub scans_outside_span: usize,
    /// Odometry poses found in the input (from the source named by `odometry_source`).
    pub odometry_read: usize,
    /// Odometry poses the recording holds.
    pub odometry_kept: usize,
    /// Where the odometry came from.
    pub odometry_source: String,
    /// How the scans were stamped (the recording's own stamps, repaired ones, or a clock
    /// made from the file order).
    pub clock: String,
    /// Where the LiDAR mount came from.
    pub mount_source: String,
    /// The beam layouts seen, in order of first appearance.
    pub beam_layouts: Vec<BeamLayout>,
    /// Records left out, by reason.
    pub dropped: Vec<Tally>,
    /// Records kept after a repair, by reason.
    pub repaired: Vec<Tally>,
    /// Records of other kinds that the reader does not use, by kind (`NEFF lines`, topics).
    pub ignored: Vec<Tally>,
    /// Anything else the user should know.
    pub warnings: Vec<String>,
}

impl InputAccount {
    /// An empty account of `format` read from `path`, counting `records_unit`.
    pub fn new(format: &str, path: &std::path::Path, records_unit: &str) -> Self {
        InputAccount {
            format: format.to_string(),
            path: path.display().to_string(),
            records_unit: records_unit.to_string(),
            ..InputAccount::default()
        }
    }

    /// Counts one record of `what` dropped for `reason` at `at`.
    pub fn drop_one(&mut self, what: &str, reason: &str, at: impl FnOnce() -> String) {
        tally(&mut self.dropped, what, reason, 1, at);
    }

    /// Counts `count` records of `what` dropped for `reason`.
    pub fn drop_many(&mut self, what: &str, reason: &str, count: usize) {
        if count > 0 {
            tally(&mut self.dropped, what, reason, count, String::new);
        }
    }

    /// Counts `count` records of `what` repaired for `reason`.
    pub fn repair(&mut self, what: &str, reason: &str, count: usize) {
        if count > 0 {
            tally(&mut self.repaired, what, reason, count, String::new);
        }
    }

    /// Counts one record of a kind the reader does not use.
    pub fn ignore_one(&mut self, kind: &str, unit: &str) {
        self.ignore_many(kind, unit, 1);
    }

    /// Counts `count` records of a kind the reader does not use.
    pub fn ignore_many(&mut self, kind: &str, unit: &str, count: usize) {
        if count > 0 {
            tally(&mut self.ignored, unit, kind, count, String::new);
        }
    }

    /// Counts one scan of layout `g`.
    pub fn add_layout(&mut self, g: &LidarGeometry) {
        let same = |l: &BeamLayout| {
            l.beams == g.beam_count
                && l.angle_min_deg == g.angle_min_rad.to_degrees()
                && l.angle_increment_deg == g.angle_increment_rad.to_degrees()
                && l.range_max_m == g.range_max_m
        };
        match self.beam_layouts.iter_mut().find(|l| same(l)) {
            Some(l) => l.scans += 1,
            None => self.beam_layouts.push(BeamLayout {
                beams: g.beam_count,
                angle_min_deg: g.angle_min_rad.to_degrees(),
                angle_increment_deg: g.angle_increment_rad.to_degrees(),
                range_max_m: g.range_max_m,
                scans: 1,
            }),
        }
    }

    /// Scans dropped, all reasons.
    pub fn scans_dropped(&self) -> usize {
        self.scans_read
            .saturating_sub(self.scans_kept + self.scans_outside_span)
    }

    /// The warnings to print: the reader's own, and a drop of more than
    /// [`DROPPED_SCANS_WARNING_SHARE`] of the scans.
    pub fn all_warnings(&self) -> Vec<String> {
        let mut out = self.warnings.clone();
        let dropped = self.scans_dropped();
        if self.scans_read > 0
            && dropped as f64 > DROPPED_SCANS_WARNING_SHARE * self.scans_read as f64
        {
            let reasons: Vec<String> = self
                .dropped
                .iter()
                .filter(|t| t.what == "scans")
                .map(|t| format!("{} {}", t.count, t.reason))
                .collect();
            out.push(format!(
                "{}: {dropped} of {} scans dropped ({:.1} %): {}",
                self.path,
                self.scans_read,
                100.0 * dropped as f64 / self.scans_read as f64,
                reasons.join(", ")
            ));
        }
        out
    }

    /// The account in one line, for the terminal.
    pub fn one_line(&self) -> String {
        let mut s = format!(
            "input: {} ({}, {} {}): {} of {} scans kept, {} of {} odometry poses ({}), clock: {}, mount: {}",
            self.path,
            self.format,
            self.records_read,
            self.records_unit,
            self.scans_kept,
            self.scans_read,
            self.odometry_kept,
            self.odometry_read,
            self.odometry_source,
            self.clock,
            self.mount_source
        );
        if self.scans_outside_span > 0 {
            s += &format!(", {} outside the span asked for", self.scans_outside_span);
        }
        let layouts: Vec<String> = self
            .beam_layouts
            .iter()
            .map(|l| {
                format!(
                    "{} beams from {:.2} deg step {:.3} deg x{}",
                    l.beams, l.angle_min_deg, l.angle_increment_deg, l.scans
                )
            })
            .collect();
        if !layouts.is_empty() {
            s += &format!("; layouts: {}", layouts.join(", "));
        }
        for (label, list) in [("dropped", &self.dropped), ("repaired", &self.repaired)] {
            if !list.is_empty() {
                let items: Vec<String> = list
                    .iter()
                    .map(|t| match &t.first_at {
                        Some(at) => format!("{} {} {} (first at {at})", t.count, t.what, t.reason),
                        None => format!("{} {} {}", t.count, t.what, t.reason),
                    })
                    .collect();
                s += &format!("; {label}: {}", items.join(", "));
            }
        }
        s
    }
}

fn tally(
    list: &mut Vec<Tally>,
    what: &str,
    reason: &str,
    count: usize,
    at: impl FnOnce() -> String,
) {
    match list
        .iter_mut()
        .find(|t| t.what == what && t.reason == reason)
    {
        Some(t) => t.count += count,
        None => {
            let at = at();
            list.push(Tally {
                what: what.to_string(),
                reason: reason.to_string(),
                count,
                first_at: (!at.is_empty()).then_some(at),
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tallies_and_warning() {
        let mut a = InputAccount::new("carmen", std::path::Path::new("x.log"), "lines");
        a.scans_read = 100;
        a.scans_kept = 98;
        a.drop_one("scans", "unparseable", || "line 4".into());
        a.drop_one("scans", "unparseable", || "line 9".into());
        assert_eq!(a.dropped.len(), 1);
        assert_eq!(a.dropped[0].count, 2);
        assert_eq!(a.dropped[0].first_at.as_deref(), Some("line 4"));
        let w = a.all_warnings();
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].contains("2 of 100 scans dropped"), "{}", w[0]);
        a.scans_kept = 99;
        assert!(a.all_warnings().is_empty(), "1 % is not above 1 %");
        let g = LidarGeometry::ucsd_lms511();
        a.add_layout(&g);
        a.add_layout(&g);
        assert_eq!(a.beam_layouts.len(), 1);
        assert_eq!(a.beam_layouts[0].scans, 2);
        assert!(a.one_line().contains("286 beams"));
    }
}
