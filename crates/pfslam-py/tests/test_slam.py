"""`pfslam.Slam` fed a log message by message gives `pfslam.run`'s result bit for bit."""

import numpy as np
import pytest

import pfslam
from feed import messages, push


def assert_same_result(a: "pfslam.Result", b: "pfslam.Result") -> None:
    assert np.array_equal(a.stamps_ns, b.stamps_ns)
    assert np.array_equal(a.trajectory, b.trajectory)
    assert np.array_equal(a.front_end, b.front_end)
    assert np.array_equal(a.dead_reckoning, b.dead_reckoning)
    assert a.trajectory_tum == b.trajectory_tum
    assert np.array_equal(a.occupancy, b.occupancy)
    assert (a.resolution_m, a.origin) == (b.resolution_m, b.origin)


def test_incremental_run_equals_the_file_run(sim_recording, sim_run):
    rec = sim_recording
    slam = pfslam.Slam(body_from_lidar=rec.body_from_lidar)
    assert slam.pose() is None and slam.occupancy() is None
    reported = 0
    for kind, i in messages(rec):
        pose = push(slam, rec, kind, i)
        reported += pose is not None
    assert reported > 100
    online = slam.trajectory()
    assert online.shape == (len(rec.scan_stamps_ns), 4)
    assert slam.pose() == tuple(online[-1])
    logodds, resolution_m, origin = slam.occupancy()
    assert logodds.ndim == 2 and logodds.size > 0 and resolution_m > 0 and len(origin) == 2
    result = slam.finish()
    assert_same_result(result, sim_run)
    assert result.summary["stats"] == {
        **sim_run.summary["stats"],
        "timings": result.summary["stats"]["timings"],
    }


def test_scans_wait_for_the_odometry(sim_recording, sim_run):
    # Every scan first (each waits), then the odometry: the same result.
    rec = sim_recording
    slam = pfslam.Slam(body_from_lidar=rec.body_from_lidar)
    order = sorted(messages(rec), key=lambda m: m[0] == "odometry")
    returned = [push(slam, rec, kind, i) for kind, i in order]
    assert all(p is None for p in returned[: len(rec.scan_stamps_ns)])
    assert any(p is not None for p in returned)
    assert len(slam.trajectory()) == len(rec.scan_stamps_ns)
    assert_same_result(slam.finish(), sim_run)


def test_seconds_and_lists_are_accepted(sim_recording):
    # Stamps in seconds round to the nearest nanosecond; plain lists of ranges work too.
    rec = sim_recording
    slam = pfslam.Slam({"filter": {"particles": 5}}, seed=4, body_from_lidar=(0.05, 0.0, 0.0))
    g = rec.lidar
    for kind, i in messages(rec):
        if i >= 200:
            continue
        if kind == "odometry":
            slam.add_odometry(*rec.odometry[i])
        else:
            t = float(rec.scan_stamps_ns[i]) / 1e9
            ranges = rec.ranges[i].tolist()
            beams = (g["angle_min_rad"], g["angle_increment_rad"], g["range_min_m"], g["range_max_m"])
            slam.add_scan(t, ranges, *beams)
    pose = slam.pose()
    assert pose is not None and abs(pose[0] - rec.scan_stamps_ns[199] / 1e9) < 1e-6
    result = slam.finish()
    assert result.summary["seed"] == 4 and result.summary["stats"]["particles"] == 5


def test_scans_may_change_their_beams(sim_recording):
    # Every other scan thinned to half its beams: each keeps its own geometry.
    rec = sim_recording
    slam = pfslam.Slam({"filter": {"particles": 5}, "graph": {"enabled": False}})
    g = rec.lidar
    for kind, i in messages(rec):
        if i >= 300:
            continue
        if kind == "odometry":
            slam.add_odometry_ns(int(rec.odometry_stamps_ns[i]), *rec.odometry[i, 1:])
            continue
        step = 2 if i % 2 else 1
        slam.add_scan_ns(
            int(rec.scan_stamps_ns[i]),
            rec.ranges[i][::step],
            g["angle_min_rad"],
            g["angle_increment_rad"] * step,
            g["range_min_m"],
            g["range_max_m"],
        )
    result = slam.finish()
    assert len(result.trajectory) == 300
    assert result.summary["stats"]["scans_total"] == 300


BEAMS = dict(angle_min=-1.5, angle_increment=0.01, range_min=0.0, range_max=30.0)


def test_bad_pushes_are_refused_with_their_reason():
    slam = pfslam.Slam()
    slam.add_odometry_ns(2_000, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="odometry at 1000 ns comes before the previous one at 2000 ns"):
        slam.add_odometry_ns(1_000, 0.0, 0.0, 0.0)
    slam.add_scan_ns(5_000, [1.0] * 10, **BEAMS)
    with pytest.raises(ValueError, match="scan at 4000 ns comes before the previous one at 5000 ns"):
        slam.add_scan_ns(4_000, [1.0] * 10, **BEAMS)
    with pytest.raises(ValueError, match="scan at 6000 ns: no ranges"):
        slam.add_scan_ns(6_000, [], **BEAMS)
    with pytest.raises(ValueError, match="range_min 5 and range_max 1"):
        slam.add_scan_ns(6_000, [1.0] * 10, -1.5, 0.01, 5.0, 1.0)
    with pytest.raises(ValueError, match="ranges: a 1-D sequence of numbers"):
        slam.add_scan_ns(6_000, "abc", **BEAMS)
    with pytest.raises(ValueError, match="odometry at 3000 ns: x, y and yaw must be finite"):
        slam.add_odometry_ns(3_000, float("nan"), 0.0, 0.0)
    with pytest.raises(ValueError, match="not a finite time"):
        slam.add_odometry(float("nan"), 0.0, 0.0, 0.0)


def test_finish_without_data_says_what_is_missing():
    with pytest.raises(pfslam.PfslamError, match="no scan was added"):
        pfslam.Slam().finish()
    # A scan before the odometry's first pose is left out: no scan lies within its span.
    slam = pfslam.Slam()
    assert slam.add_scan(1.0, [2.0] * 10, **BEAMS) is None
    slam.add_odometry(2.0, 0.0, 0.0, 0.0)
    slam.add_odometry(3.0, 0.1, 0.0, 0.0)
    with pytest.raises(pfslam.PfslamError, match="no scan lies within the odometry's time span"):
        slam.finish()
    with pytest.raises(pfslam.PfslamError, match="takes no more data"):
        slam.add_odometry(4.0, 0.0, 0.0, 0.0)


def test_a_bad_mount_is_refused():
    with pytest.raises(ValueError, match="body_from_lidar: a 4x4 matrix"):
        pfslam.Slam(body_from_lidar=np.eye(3))
    with pytest.raises(ValueError, match="body_from_lidar"):
        pfslam.Slam(body_from_lidar="front")


def test_a_scan_waits_for_the_imu_once_it_is_given():
    slam = pfslam.Slam()
    slam.add_imu_yaw(0.0, 0.0)
    slam.add_odometry(0.0, 0.0, 0.0, 0.0)
    slam.add_odometry(1.0, 0.5, 0.0, 0.0)
    beams = dict(angle_min=-1.5, angle_increment=0.01, range_min=0.0, range_max=30.0)
    assert slam.add_scan(0.5, [3.0] * 301, **beams) is None, "the IMU does not reach it yet"
    pose = slam.add_imu_yaw(0.6, 0.01)
    assert pose is not None and pose[0] == 0.5
    with pytest.raises(ValueError, match="IMU yaw at 400000000 ns comes before the previous one"):
        slam.add_imu_yaw(0.4, 0.0)
    with pytest.raises(ValueError, match="IMU yaw at 700000000 ns: yaw must be finite"):
        slam.add_imu_yaw(0.7, float("inf"))
