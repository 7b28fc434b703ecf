"""Bad configurations and files raise exceptions carrying the Rust errors' messages."""

from pathlib import Path

import pytest

import pfslam


def test_an_unknown_key_is_named(sim_log: Path):
    with pytest.raises(pfslam.ConfigError, match="unknown field `partcles`"):
        pfslam.run(sim_log, config={"filter": {"partcles": 10}})
    with pytest.raises(pfslam.ConfigError, match="unknown field `fliter`"):
        pfslam.run(sim_log, config="[fliter]\nparticles = 10\n")
    with pytest.raises(pfslam.ConfigError, match="unknown field `partcles`"):
        pfslam.Slam(config={"filter": {"partcles": 10}})


def test_a_value_out_of_range_is_named(sim_log: Path):
    with pytest.raises(pfslam.ConfigError, match=r"configuration \[filter\]: .*particles"):
        pfslam.run(sim_log, config={"filter": {"particles": 0}})
    with pytest.raises(pfslam.ConfigError, match="input.end_s must be finite and >= 0"):
        pfslam.read_recording(sim_log, config={"input": {"end_s": -1.0}})


def test_malformed_configurations_are_refused(sim_log: Path):
    with pytest.raises(pfslam.ConfigError, match="<config>"):
        pfslam.run(sim_log, config="[filter\n")
    with pytest.raises(pfslam.ConfigError, match="has no TOML form"):
        pfslam.run(sim_log, config={"filter": {"particles": None}})
    with pytest.raises(pfslam.ConfigError, match="not int"):
        pfslam.run(sim_log, config=3)
    assert issubclass(pfslam.ConfigError, pfslam.PfslamError)
    assert issubclass(pfslam.PfslamError, Exception)


def test_a_missing_file_is_named(tmp_path: Path):
    path = tmp_path / "nowhere.clf"
    with pytest.raises(pfslam.PfslamError) as e:
        pfslam.run(path)
    assert str(e.value) == f"loading {path}: {path}: no such file or directory"
    with pytest.raises(pfslam.PfslamError, match="nowhere.clf: no such file or directory"):
        pfslam.read_recording(path)


def test_an_unknown_format_is_named(tmp_path: Path):
    path = tmp_path / "notes.txt"
    path.write_text("hello\n")
    with pytest.raises(pfslam.PfslamError, match="notes.txt: not a recognised recording"):
        pfslam.run(path)
