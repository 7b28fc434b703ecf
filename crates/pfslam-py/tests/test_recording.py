"""`pfslam.read_recording`: a log's scans, odometry and mount as arrays."""

import numpy as np
import pytest

import pfslam


def test_the_log_is_read_whole(sim_recording):
    rec = sim_recording
    assert rec.name == "humanoid"
    assert rec.scan_stamps_ns.dtype == np.int64 and rec.scan_stamps_ns.shape == (1200,)
    assert np.all(np.diff(rec.scan_stamps_ns) > 0)
    assert rec.ranges.shape == (1200, 1081) and rec.ranges.dtype == np.float32
    assert rec.lidar["beam_count"] == 1081 and rec.lidar_per_scan is None
    assert rec.odometry.shape == (len(rec.odometry_stamps_ns), 4)
    assert np.array_equal(rec.odometry[:, 0], rec.odometry_stamps_ns / 1e9)
    assert rec.body_from_lidar.shape == (4, 4)
    assert rec.body_from_lidar[0, 3] == pytest.approx(0.05)
    assert rec.ground_truth is None
    assert rec.account["format"] == "carmen" and rec.account["scans_kept"] == 1200
    assert "1200 scans" in repr(rec)


def test_the_span_of_input_applies(sim_log):
    rec = pfslam.read_recording(sim_log, config={"input": {"end_s": 10.0}})
    assert 390 <= len(rec.scan_stamps_ns) <= 410
    assert rec.account["scans_outside_span"] > 0
