"""Fixtures: the pfslam command-line tool, a small CARMEN log it makes, the shared data."""

import os
import subprocess
from pathlib import Path

import pytest

import pfslam

REPO = Path(__file__).resolve().parents[3]


def cli_path() -> Path:
    """The `pfslam` binary: $PFSLAM_BIN, else the workspace's release build."""
    target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    return Path(os.environ.get("PFSLAM_BIN", target / "release" / "pfslam"))


def cli(*args: str) -> str:
    """Runs the CLI, failing the test with its output when it fails."""
    exe = cli_path()
    if not exe.is_file():
        pytest.fail(f"{exe} is missing: build it first (cargo build --release)")
    done = subprocess.run([str(exe), *args], capture_output=True, text=True)
    assert done.returncode == 0, f"pfslam {' '.join(args)}:\n{done.stdout}\n{done.stderr}"
    return done.stdout


def cli_trajectory_tum(recording: Path, out: Path, *flags: str) -> str:
    """The `trajectory.tum` text of `pfslam run RECORDING --out OUT FLAGS`."""
    cli("run", str(recording), "--out", str(out), *flags)
    return (out / "trajectory.tum").read_text()


@pytest.fixture(scope="session")
def sim_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A CARMEN log of 30 s of the simulated humanoid walking in the office world (1200
    scans of 1081 beams), its odometry degraded as a well-calibrated robot's."""
    d = tmp_path_factory.mktemp("sim")
    sim = d / "humanoid"
    cli("simulate", "--vehicle", "humanoid", "--duration-s", "30", "--seed", "3", "--out", str(sim))
    log = d / "humanoid.log"
    cli("perturb", str(sim), "--out", str(log), "--level", "1")
    return log


@pytest.fixture(scope="session")
def sim_run(sim_log: Path) -> "pfslam.Result":
    """`pfslam.run` on the log with the defaults."""
    return pfslam.run(sim_log)


@pytest.fixture(scope="session")
def sim_recording(sim_log: Path) -> "pfslam.Recording":
    return pfslam.read_recording(sim_log)


def data_dir() -> Path:
    """The shared recordings: $PFSLAM_DATA, else `shared/data` beside the workspace root."""
    return Path(os.environ.get("PFSLAM_DATA", REPO.parent / "shared" / "data"))
