//! Images and plots (placeholder).
