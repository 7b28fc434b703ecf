//! Online calibration of the odometry's translation scale for the scan-matching mode.
//!
//! Matching a scan against a map built from the filter's own poses barely sees a scale error
//! of the odometry: the map is mostly the last few scans, which drift with the poses. A long
//! baseline does: every `scale_keyframe_spacing_m` of travel the scan is kept at its pose in
//! the scaled-odometry frame, and the new keyframe is matched against a submap of the
//! keyframes `scale_baseline_m` to 1.5 x that far back (hits only). The along-track offset
//! of the match over the mean baseline is the scale's relative error; the scale moves by
//! `gain` of it.

use super::scanmatch::{self, LikelihoodField, MatchParams, MatchScratch, ScanMatchOptions};
use crate::geometry::{Pose2, wrap_angle};
use crate::map::{InsertScratch, MapError, MapOptions, OccupancyGrid, PlanarScan, to_world};
use std::collections::VecDeque;

/// One kept scan: its odometry pose, the odometry travel up to it, its body-frame points.
#[derive(Debug, Clone)]
struct Keyframe {
    odom: Pose2,
    travel_m: f64,
    scan: PlanarScan,
}

/// The calibrator's state (see the module docs).
#[derive(Debug)]
pub struct ScaleCalibrator {
    /// The current odometry translation scale (1 = as recorded).
    pub scale: f64,
    /// Calibration matches made.
    pub matches: usize,
    keyframes: VecDeque<Keyframe>,
    /// The scaled odometry: composed from the odometry steps with the scale of their time.
    scaled: Option<(Pose2, Pose2)>,
    map: MapOptions,
    params: MatchParams,
    options: ScanMatchOptions,
    world: PlanarScan,
    insert: InsertScratch,
    field: LikelihoodField,
    points: Vec<[f64; 2]>,
    scratch: MatchScratch,
}

impl ScaleCalibrator {
    /// A calibrator at scale 1 for maps like `map`.
    pub fn new(options: &ScanMatchOptions, map: &MapOptions) -> Self {
        let mut params = options.params(map.resolution_m);
        // Only x and y: the FOG's yaw over the baseline is far better than a match's.
        params.yaw_offsets_rad = vec![0.0];
        params.inv_var_xy = 1.0 / (options.scale_match_prior_m * options.scale_match_prior_m);
        params.inv_var_along = None;
        // Finer steps: the scale signal is a few cm over the baseline.
        params.refine_levels = params.refine_levels.max(5);
        let mut field = LikelihoodField::new();
        // One scan's hits are walls (a single hit rarely reaches the occupied threshold).
        field.set_source_threshold(Some(1));
        ScaleCalibrator {
            scale: 1.0,
            matches: 0,
            keyframes: VecDeque::new(),
            scaled: None,
            map: map.clone(),
            params,
            options: options.clone(),
            world: PlanarScan::default(),
            insert: InsertScratch::new(),
            field,
            points: Vec::new(),
            scratch: MatchScratch::default(),
        }
    }

    /// The scan `body` was taken at odometry pose `odom` after `travel_m` of odometry travel:
    /// keeps it when it is a new keyframe and then calibrates against the keyframe about a
    /// baseline back.
    pub fn observe(
        &mut self,
        odom: &Pose2,
        travel_m: f64,
        body: &PlanarScan,
    ) -> Result<(), MapError> {
        // Advance the scaled odometry (the first call only anchors it).
        let now = match self.scaled {
            None => *odom,
            Some((last_odom, last_scaled)) => {
                let step = last_odom.between(odom);
                last_scaled.compose(&Pose2::new(
                    step.x_m * self.scale,
                    step.y_m * self.scale,
                    step.yaw_rad,
                ))
            }
        };
        self.scaled = Some((*odom, now));
        let o = &self.options;
        if self
            .keyframes
            .back()
            .is_some_and(|k| travel_m - k.travel_m < o.scale_keyframe_spacing_m)
        {
            return Ok(());
        }
        let (near, far) = (o.scale_baseline_m, 1.5 * o.scale_baseline_m);
        while self
            .keyframes
            .front()
            .is_some_and(|k| travel_m - k.travel_m > far)
        {
            self.keyframes.pop_front();
        }
        // The submap: keyframes between the baseline and 1.5 x it back, hits only.
        let mut grid = OccupancyGrid::new(&self.map)?;
        let (mut n, mut baseline_sum_m) = (0usize, 0.0);
        for k in &self.keyframes {
            if travel_m - k.travel_m >= near {
                to_world(&k.scan, &k.odom, &mut self.world);
                grid.insert_scan(&self.world, &mut self.insert)?;
                n += 1;
                baseline_sum_m += (now.x_m - k.odom.x_m).hypot(now.y_m - k.odom.y_m);
            }
        }
        let oldest = self.keyframes.front().map(|k| k.odom);
        self.keyframes.push_back(Keyframe {
            odom: now,
            travel_m,
            scan: body.clone(),
        });
        let Some(oldest) = oldest else {
            return Ok(());
        };
        if n == 0 {
            return Ok(());
        }
        let predicted = now;
        let baseline_m = baseline_sum_m / n as f64;
        scanmatch::match_points(
            body,
            o.match_range_max_m,
            o.beam_decimation,
            &mut self.points,
        );
        if self.points.is_empty() {
            return Ok(());
        }
        let rect = super::slam::field_window(
            grid.limits(),
            std::slice::from_ref(&predicted),
            predicted,
            &self.points,
            self.params.xy_radius_cells + 2,
        );
        self.field.build(&grid, &rect, o.field_sigma_m, 0.0);
        let m = scanmatch::match_scan(
            &self.field,
            &self.points,
            &predicted,
            &self.params,
            &mut self.scratch,
        );
        tracing::debug!(
            "scale match: fit {:.3} dx {:.4} dy {:.4} baseline {:.1} scale {:.5}",
            m.fit,
            m.pose.x_m - predicted.x_m,
            m.pose.y_m - predicted.y_m,
            baseline_m,
            self.scale
        );
        // Straight travel only: after a turn the submap sees other streets.
        if m.fit < o.scale_min_fit
            || baseline_m < 0.5 * near
            || wrap_angle(predicted.yaw_rad - oldest.yaw_rad).abs() > 0.1
        {
            return Ok(());
        }
        let old = oldest;
        let (dx, dy) = (m.pose.x_m - predicted.x_m, m.pose.y_m - predicted.y_m);
        let (ux, uy) = {
            let (tx, ty) = (predicted.x_m - old.x_m, predicted.y_m - old.y_m);
            let n = tx.hypot(ty).max(1e-9);
            (tx / n, ty / n)
        };
        let along_m = dx * ux + dy * uy;
        self.scale =
            (self.scale * (1.0 + o.odometry_scale_gain * along_m / baseline_m)).clamp(0.95, 1.05);
        self.matches += 1;
        Ok(())
    }
}
