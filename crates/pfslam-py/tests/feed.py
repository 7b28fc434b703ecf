"""Feeding a recording into `pfslam.Slam` message by message, as a robot delivers them."""

from typing import Iterator, Tuple

import pfslam


def messages(rec: "pfslam.Recording") -> Iterator[Tuple[str, int]]:
    """("odometry" | "scan", index) merged by stamp, a scan before odometry of the same stamp
    (the file order of `examples/incremental.rs`)."""
    scans, odometry = rec.scan_stamps_ns, rec.odometry_stamps_ns
    s = o = 0
    while s < len(scans) or o < len(odometry):
        if s < len(scans) and (o == len(odometry) or scans[s] < odometry[o]):
            yield "scan", s
            s += 1
        else:
            yield "odometry", o
            o += 1


def push(slam: "pfslam.Slam", rec: "pfslam.Recording", kind: str, i: int):
    """One message of `rec` into `slam`; what the push returned."""
    if kind == "odometry":
        _, x, y, yaw = rec.odometry[i]
        return slam.add_odometry_ns(int(rec.odometry_stamps_ns[i]), x, y, yaw)
    g = rec.lidar if rec.lidar_per_scan is None else rec.lidar_per_scan[i]
    return slam.add_scan_ns(
        int(rec.scan_stamps_ns[i]),
        rec.ranges[i],
        g["angle_min_rad"],
        g["angle_increment_rad"],
        g["range_min_m"],
        g["range_max_m"],
    )
