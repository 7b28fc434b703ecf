"""Type stubs of the native module ``pfslam._pfslam`` (re-exported by ``pfslam``)."""

import os
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

Config = Union[None, str, Mapping[str, Any]]
"""None (the defaults), TOML text, or a dict of sections such as ``{"filter": {"particles": 30}}``.
Unknown sections or keys raise :class:`ConfigError` naming them, as ``pfslam run --config`` does."""

Pose = Tuple[float, float, float, float]
"""``(t_s, x_m, y_m, yaw_rad)``."""

class PfslamError(Exception):
    """An error of pfslam; the message is the Rust error's, causes joined by ": "."""

class ConfigError(PfslamError):
    """A configuration that is malformed, has an unknown key or a value out of range."""

class Result:
    """What :func:`run` or :meth:`Slam.finish` produced."""

    trajectory: npt.NDArray[np.float64]
    """``(N, 4)`` rows ``t_s, x_m, y_m, yaw_rad``: the final trajectory, a pose per scan handled."""
    stamps_ns: npt.NDArray[np.int64]
    """``(N,)`` the exact stamps (ns) of ``trajectory``'s rows (``t_s`` is ``stamp_ns / 1e9``)."""
    trajectory_tum: str
    """``trajectory`` as the TUM text ``pfslam run`` writes to ``trajectory.tum``."""
    front_end: npt.NDArray[np.float64]
    """``(N, 4)`` the filter's trajectory before the loop-closure back end."""
    dead_reckoning: npt.NDArray[np.float64]
    """``(N, 4)`` the odometry at every scan handled."""
    occupancy: npt.NDArray[np.float32]
    """``(rows, cols)`` log-odds of the final map over the cells observed (0: never observed;
    > 0 occupied, < 0 free). ``occupancy[r, c]`` is the cell ``c`` steps along world x and ``r``
    steps along world y from ``origin``: row 0 is the lowest y (``imshow(origin="lower")``)."""
    resolution_m: float
    """Cell size of ``occupancy`` (m)."""
    origin: Tuple[float, float]
    """World ``(x_m, y_m)`` of the lower-left corner of cell ``occupancy[0, 0]``."""
    summary: Dict[str, Any]
    """The library's part of ``summary.json``: ``recording``, ``seed``, ``config``, ``stats``
    (counts, Neff, stage timings), ``quality`` (the self-check: ``status`` ``ok`` or ``suspect``,
    ``reasons``, ``signals``), ``odometry_timing`` (the odometry's measured lag and the shift
    applied), ``timings_s``, ``graph`` and ``graph_input`` (the back end, when it ran) and,
    from :func:`run`, ``input`` (what the reader read, kept and dropped)."""

class Recording:
    """A recording file's contents as read (see :func:`read_recording`)."""

    name: str
    scan_stamps_ns: npt.NDArray[np.int64]
    """``(S,)`` scan stamps (ns)."""
    ranges: Union[npt.NDArray[np.float32], List[npt.NDArray[np.float32]]]
    """``(S, B)`` ranges (m) when every scan has ``B`` beams, else one ``(B_i,)`` array per scan."""
    lidar: Dict[str, Any]
    """The beams: ``angle_min_rad``, ``angle_increment_rad``, ``beam_count``, ``range_min_m``,
    ``range_max_m``."""
    lidar_per_scan: Optional[List[Dict[str, Any]]]
    """Each scan's beams when scans differ, else None."""
    odometry: npt.NDArray[np.float64]
    """``(M, 4)`` rows ``t_s, x_m, y_m, yaw_rad`` in the odometry's own frame."""
    odometry_stamps_ns: npt.NDArray[np.int64]
    """``(M,)`` odometry stamps (ns)."""
    body_from_lidar: npt.NDArray[np.float64]
    """``4x4`` homogeneous transform of the LiDAR's mount on the robot's body."""
    ground_truth: Optional[npt.NDArray[np.float64]]
    """``(K, 4)`` ground-truth rows, when the recording has them."""
    account: Dict[str, Any]
    """What the reader read, kept, dropped and repaired, and why."""

def read_recording(path: Union[str, os.PathLike[str]], config: Config = None) -> Recording:
    """Reads a dataset as ``pfslam run`` reads it: a CARMEN log (``.clf``/``.log``, gzipped or
    not), ROS 1 bag, MCAP file, rosbag2 directory, or a directory of the UCSD car's or the
    humanoid's layout (with a simulator's ``ground_truth.tum``). ``config``'s ``[input]``
    section picks topics, frames and the span. Raises
    :class:`PfslamError` naming the file (and line) on a missing or malformed file."""

def run(path: Union[str, os.PathLike[str]], config: Config = None, seed: int = 1) -> Result:
    """SLAM on a dataset (any :func:`read_recording` reads) exactly as ``pfslam run PATH --out DIR
    [--config C] --seed SEED``:
    the filter, the loop-closure back end and the map rebuilt along its trajectory. The
    trajectory equals the CLI's ``trajectory.tum`` bit for bit. Releases the GIL while it runs."""

class Slam:
    """The filter fed as the data arrive: odometry and scans in time order, each stream on its
    own; after :meth:`finish` the result equals :func:`run`'s on the same data bit for bit.

    A scan is handled once the odometry reaches its stamp (its pose is interpolated there), so
    a scan waits for the odometry that follows it. ``body_from_lidar`` is the LiDAR's mount on
    the body: a ``4x4`` homogeneous matrix (as :attr:`Recording.body_from_lidar`) or a planar
    ``(x_m, y_m, yaw_rad)``; default: at the body's origin, looking forward.

    Stamps given in seconds (``t``) become nanoseconds as ``round(t * 1e9)`` in float64
    arithmetic (halves away from zero); float64 seconds hold about 0.2 µs near today's Unix
    time, so give ``stamp_ns`` to the ``*_ns`` methods when nanoseconds matter.
    """

    def __init__(
        self,
        config: Config = None,
        seed: int = 1,
        body_from_lidar: Union[None, npt.NDArray[np.float64], Tuple[float, float, float]] = None,
    ) -> None: ...
    def add_odometry(self, t: float, x: float, y: float, yaw: float) -> Optional[Pose]:
        """The odometry's pose at ``t`` (s); returns the pose of the latest scan it let the filter
        handle, else None. Raises ValueError when ``t`` is not after the previous odometry."""
    def add_odometry_ns(self, stamp_ns: int, x: float, y: float, yaw: float) -> Optional[Pose]:
        """:meth:`add_odometry` with the stamp in integer nanoseconds."""
    def add_imu_yaw(self, t: float, yaw: float) -> Optional[Pose]:
        """The IMU's absolute yaw (rad) at ``t`` (s), for the motion model that takes the turn
        from it (``[filter.odometry_model] model = "ese650"``); once any is given, a scan also
        waits for the IMU to reach its stamp. Returns like :meth:`add_odometry`."""
    def add_scan(
        self,
        t: float,
        ranges: Union[npt.ArrayLike, Sequence[float]],
        angle_min: float,
        angle_increment: float,
        range_min: float,
        range_max: float,
    ) -> Optional[Pose]:
        """A scan at ``t`` (s): ``ranges`` (m, float32 kept as is, other numbers rounded to
        float32; 0, NaN or beyond the limits: no return) of beams from ``angle_min`` (rad) in
        steps of ``angle_increment`` (rad, counter-clockwise), with the sensor's ``range_min``
        and ``range_max`` (m). Scans may change geometry (beam count) from one to the next.
        Returns the scan's pose, or None while it waits for the odometry (or when it lies before
        the first odometry pose and is left out). Raises ValueError for a scan before the
        previous one, no ranges or unusable limits."""
    def add_scan_ns(
        self,
        stamp_ns: int,
        ranges: Union[npt.ArrayLike, Sequence[float]],
        angle_min: float,
        angle_increment: float,
        range_min: float,
        range_max: float,
    ) -> Optional[Pose]:
        """:meth:`add_scan` with the stamp in integer nanoseconds."""
    def pose(self) -> Optional[Pose]:
        """The pose of the latest scan handled, None before the first."""
    def trajectory(self) -> npt.NDArray[np.float64]:
        """``(N, 4)`` the pose reported after each scan handled so far (the online estimates;
        :meth:`finish` gives the final trajectory)."""
    def occupancy(self) -> Optional[Tuple[npt.NDArray[np.float32], float, Tuple[float, float]]]:
        """The filter's current map (its best particle's) as ``(occupancy, resolution_m, origin)``,
        in the form of :class:`Result`'s fields of those names; None before the first scan is
        handled."""
    def finish(self) -> Result:
        """Ends the run: scans still waiting for odometry count as beyond it; then the back end
        and the final map. The object takes no data afterwards."""
