//! The run's self-check without ground truth: signals a run can measure on itself, and a
//! verdict (`ok` / `suspect`) with its reasons. The thresholds and the runs they were
//! measured on are in `docs/decisions/0006-self-check-and-back-end-guard.md`.

use serde::Serialize;

/// Above this share of scan returns in cells the final map calls free, a run is suspect:
/// the good runs of the development corpus stay below it, the failed ones above.
pub const SUSPECT_FREE_SHARE: f64 = 0.15;

/// What the run measured on itself.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct QualitySignals {
    /// Share of scan returns in cells the final map calls free.
    pub free_share: f64,
    /// The same along the front end's trajectory and its map, when the back end ran.
    pub free_share_front_end: Option<f64>,
    /// The same along the back end's trajectory and its map, when it ran.
    pub free_share_back_end: Option<f64>,
    /// Whether the back end's trajectory was kept (`None` when it did not run).
    pub back_end_kept: Option<bool>,
    /// Whether the back end ran a second time, tied by the front end's motion alone,
    /// because its first map was much less consistent than the front end's.
    pub back_end_retried: bool,
}

/// `ok` or `suspect`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum QualityStatus {
    /// No signal out of its range.
    Ok,
    /// At least one signal says the result may be wrong.
    Suspect,
}

impl QualityStatus {
    /// `"ok"` or `"suspect"`, as in `summary.json`.
    pub fn as_str(self) -> &'static str {
        match self {
            QualityStatus::Ok => "ok",
            QualityStatus::Suspect => "suspect",
        }
    }
}

/// The verdict with its reasons and signals (`summary.json`'s `"quality"`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Quality {
    /// The verdict.
    pub status: QualityStatus,
    /// Why it is suspect, one sentence each (empty when ok).
    pub reasons: Vec<String>,
    /// The measured signals.
    pub signals: QualitySignals,
}

impl Quality {
    /// The verdict on `signals`.
    pub fn assess(signals: QualitySignals) -> Self {
        let mut reasons = Vec::new();
        if signals.free_share > SUSPECT_FREE_SHARE {
            reasons.push(format!(
                "{:.1} % of the scan returns land in cells the map calls free (above {:.0} %): \
                 parts of the map disagree with each other",
                100.0 * signals.free_share,
                100.0 * SUSPECT_FREE_SHARE
            ));
        }
        if signals.back_end_kept == Some(false) {
            reasons.push(
                "the back end's loop closures made the map less consistent; the front end's \
                 trajectory was kept"
                    .into(),
            );
        }
        let status = if reasons.is_empty() {
            QualityStatus::Ok
        } else {
            QualityStatus::Suspect
        };
        Quality {
            status,
            reasons,
            signals,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_consistent_run_is_ok_and_crossed_corridors_or_a_rejected_back_end_are_suspect() {
        let ok = Quality::assess(QualitySignals {
            free_share: 0.08,
            back_end_kept: Some(true),
            ..QualitySignals::default()
        });
        assert_eq!((ok.status, ok.reasons.len()), (QualityStatus::Ok, 0));
        // the label is the serialised name
        for status in [QualityStatus::Ok, QualityStatus::Suspect] {
            assert_eq!(serde_json::to_value(status).unwrap(), status.as_str());
        }
        let crossed = Quality::assess(QualitySignals {
            free_share: 0.34,
            ..QualitySignals::default()
        });
        assert_eq!(crossed.status, QualityStatus::Suspect);
        assert!(
            crossed.reasons[0].contains("34.0 %"),
            "{:?}",
            crossed.reasons
        );
        let rejected = Quality::assess(QualitySignals {
            free_share: 0.10,
            back_end_kept: Some(false),
            ..QualitySignals::default()
        });
        assert_eq!(rejected.status, QualityStatus::Suspect);
        assert!(
            rejected.reasons[0].contains("front end"),
            "{:?}",
            rejected.reasons
        );
    }
}
