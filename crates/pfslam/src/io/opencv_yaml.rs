//! OpenCV calibration YAML (placeholder).
