//! Accuracy metrics (placeholder).
