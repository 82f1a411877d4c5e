"""Zarr replay buffers (the Diffusion Policy code's layout): the PushT human demos as published, and
small buffers written by the zarr package from their first episodes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import zarr

import cli
from imitation.data.dataset import DemoDataset
from imitation.data.mcap.reader import DemoFile

PUSHT = Path("manipulation/pusht/pusht_cchi_v7_replay.zarr")


def _pusht(testdata: Path) -> zarr.Group:
    return zarr.open_group(str(testdata / PUSHT), mode="r")


def _write_buffer(path: Path, arrays: dict[str, np.ndarray], ends: list[int]) -> Path:
    """A replay buffer written by the zarr package, as the Diffusion Policy code writes them (format 2)."""
    group = zarr.open_group(str(path), mode="w", zarr_format=2)
    data = group.create_group("data")
    for name, rows in arrays.items():
        data.create_array(name, data=rows, chunks=(min(len(rows), 161), *rows.shape[1:]))
    group.create_group("meta").create_array("episode_ends", data=np.asarray(ends, dtype=np.int64))
    return path


def _first_episodes(testdata: Path, tmp_path: Path, episodes: int, names: tuple[str, ...]) -> tuple[Path, dict, list[int]]:
    source = _pusht(testdata)
    ends = [int(end) for end in source["meta/episode_ends"][:episodes]]
    arrays = {name: np.asarray(source[f"data/{name}"][: ends[-1]]) for name in names}
    return _write_buffer(tmp_path / "few.zarr", arrays, ends), arrays, ends


def test_the_pusht_demos_convert_for_gym_pusht(testdata: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "pusht.mcap"
    assert cli.main(["convert", str(testdata / PUSHT), "--env", "gym_pusht/PushT-v0", "--out", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    source = _pusht(testdata)
    ends = source["meta/episode_ends"][:]
    # 206 episodes of 25,650 rows: each loses its last action (the state after it is not recorded).
    assert (result["from"], result["episodes"], result["transitions"]) == ("zarr", 206, 25650 - 206)
    assert result["observation_space"] == "Box(float64, (5,))" and result["dt"] == pytest.approx(0.1)
    assert any("the observation is data/state, which fits gym_pusht/PushT-v0; left out: " in w for w in result["warnings"])
    assert any("rewards are zero" in warning for warning in result["warnings"])
    demos = DemoDataset([out])
    second = demos[1]
    np.testing.assert_array_equal(second.observations, source["data/state"][ends[0] : ends[1]].astype(np.float64))
    np.testing.assert_array_equal(second.actions, source["data/action"][ends[0] : ends[1] - 1])
    assert second.truncated and not second.terminated
    # The block's angle (state position 4) wraps through 0 within 91 of the 206 episodes: why --angles reads it as (cos, sin).
    angles = [episode.observations[:, 4] for episode in demos]
    assert sum(bool(np.any(np.abs(np.diff(angle)) > np.pi)) for angle in angles) == 91


def test_without_an_env_every_array_is_observed_and_frames_are_images(testdata: Path, tmp_path: Path) -> None:
    buffer, arrays, ends = _first_episodes(testdata, tmp_path, 2, ("state", "keypoint", "img", "action"))
    out = tmp_path / "few.mcap"
    assert cli.main(["convert", str(buffer), "--image-codec", "png", "--out", str(out), "--quiet"]) == 0
    demo = DemoFile(out)
    space = demo.observation_space
    assert sorted(space.spaces) == ["img", "keypoint", "state"]
    assert space["img"].dtype == np.uint8 and space["img"].shape == (96, 96, 3)
    assert space["keypoint"].shape == (9, 2)
    episode = demo.read_episodes([1])[0]
    rows = slice(ends[0], ends[1])
    np.testing.assert_array_equal(episode.observations["img"], arrays["img"][rows].astype(np.uint8))  # PNG: lossless
    np.testing.assert_array_equal(episode.observations["keypoint"], arrays["keypoint"][rows])


def test_frames_resize_as_they_convert(testdata: Path, tmp_path: Path) -> None:
    buffer, _, _ = _first_episodes(testdata, tmp_path, 1, ("state", "img", "action"))
    out = tmp_path / "small.mcap"
    assert cli.main(["convert", str(buffer), "--image-size", "48x48", "--out", str(out), "--quiet"]) == 0
    demo = DemoFile(out)
    assert demo.observation_space["img"].shape == (48, 48, 3)
    assert demo.user_metadata["cameras"] == {"img": {"resized_from": [96, 96], "filter": "area"}}


@pytest.mark.parametrize(
    ("arrays", "ends", "message"),
    [
        ({"state": np.zeros((4, 5), np.float32)}, [4], "data/ holds no action array (it holds state)"),
        (
            {"state": np.zeros((4, 5), np.float32), "action": np.zeros((3, 2), np.float32)},
            [3],
            "data/state has 4 rows where data/action has 3",
        ),
        (
            {"state": np.zeros((4, 5), np.float32), "action": np.zeros((4, 2), np.float32)},
            [1, 4],
            "meta/episode_ends must rise by at least 2 rows per episode and end at data/action's 4 rows",
        ),
        (
            {"state": np.zeros((4, 5), np.float32), "action": np.zeros((4, 2), np.float32)},
            [2, 3],
            "meta/episode_ends must rise by at least 2 rows per episode",
        ),
        (
            {"img": np.full((4, 2, 2, 3), 0.5, np.float32), "action": np.zeros((4, 2), np.float32)},
            [4],
            "data/img has frame values that are not whole numbers in [0, 255]",
        ),
    ],
)
def test_malformed_buffers_are_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], arrays: dict[str, np.ndarray], ends: list[int], message: str
) -> None:
    buffer = _write_buffer(tmp_path / "bad.zarr", arrays, ends)
    out = tmp_path / "bad.mcap"
    assert cli.main(["convert", str(buffer), "--out", str(out), "--quiet"]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error, error
    assert not out.exists()


def test_an_env_whose_observation_no_array_fits_is_refused(testdata: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    buffer, _, _ = _first_episodes(testdata, tmp_path, 1, ("keypoint", "action"))
    assert cli.main(["convert", str(buffer), "--env", "gym_pusht/PushT-v0", "--out", str(tmp_path / "x.mcap")]) == 1
    error = capsys.readouterr().err
    assert "0 of the arrays (keypoint) have rows of 5 numbers like gym_pusht/PushT-v0's observations; one must" in error
