//! The localisation's self-check: signals a run measures on itself, and a verdict (`ok` /
//! `suspect`) with reasons, as `pfslam run` gives for SLAM.

use super::LocalizeResult;
use crate::quality::QualityStatus;
use serde::Serialize;

/// Above this share of returns far from every wall, a localisation is suspect.
pub const SUSPECT_OFF_WALL_SHARE: f64 = 0.05;

/// What a localisation run measured on itself.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LocalizeSignals {
    /// Share of the returns at the update poses the map does not explain
    /// ([`LocalizeResult::off_wall_share`]).
    pub off_wall_share: f64,
    /// The filter was converged at the end.
    pub converged: bool,
    /// Times a converged filter lost its convergence.
    pub convergence_losses: usize,
    /// Median over the updates of the geometric mean likelihood of a return.
    pub median_fit: f64,
}

/// The verdict with its reasons and signals (`summary.json`'s `"quality"`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LocalizeQuality {
    /// The verdict.
    pub status: QualityStatus,
    /// Why it is suspect, one sentence each (empty when ok).
    pub reasons: Vec<String>,
    /// The measured signals.
    pub signals: LocalizeSignals,
}

impl LocalizeQuality {
    /// The verdict on a run.
    pub fn assess(result: &LocalizeResult) -> Self {
        let mut fits: Vec<f64> = result.updates.iter().map(|u| u.fit).collect();
        fits.sort_by(f64::total_cmp);
        let signals = LocalizeSignals {
            off_wall_share: result.off_wall_share,
            converged: result.converged_from_ns().is_some(),
            convergence_losses: result.convergence_losses(),
            median_fit: fits.get(fits.len() / 2).copied().unwrap_or(0.0),
        };
        let mut reasons = Vec::new();
        if !signals.converged {
            reasons.push("the particles had not gathered in one place at the end".to_string());
        }
        if signals.convergence_losses > 0 {
            reasons.push(format!(
                "the filter lost its fix {} time(s) and had to search again",
                signals.convergence_losses
            ));
        }
        if signals.off_wall_share > SUSPECT_OFF_WALL_SHARE {
            reasons.push(format!(
                "{:.1} % of the scan returns lie far from every wall of the map (above {:.0} %): \
                 the scans do not fit the map where the filter put them",
                100.0 * signals.off_wall_share,
                100.0 * SUSPECT_OFF_WALL_SHARE
            ));
        }
        LocalizeQuality {
            status: if reasons.is_empty() {
                QualityStatus::Ok
            } else {
                QualityStatus::Suspect
            },
            reasons,
            signals,
        }
    }
}
