"""Particle-filter SLAM for 2-D LiDAR (the Rust library ``pfslam``).

- :func:`run` runs a recording file exactly as ``pfslam run FILE`` does.
- :class:`Slam` takes odometry and scans as they arrive and reports the pose after each scan.
- :func:`read_recording` reads a recording file into numpy arrays.

Poses are rows ``(t_s, x_m, y_m, yaw_rad)``: seconds, metres, radians counter-clockwise, in
the odometry's frame (the ground truth's when the recording has one). Maps are log-odds
arrays with row 0 at the lowest y and column 0 at the lowest x.
"""

from ._pfslam import (
    ConfigError,
    PfslamError,
    Recording,
    Result,
    Slam,
    __version__,
    read_recording,
    run,
)

__all__ = [
    "ConfigError",
    "PfslamError",
    "Recording",
    "Result",
    "Slam",
    "__version__",
    "read_recording",
    "run",
]
