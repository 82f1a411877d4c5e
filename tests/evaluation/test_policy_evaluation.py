"""`eval policy`: normalised score against the run's demos and a random policy; --video."""

from __future__ import annotations

import json

import pytest
from support import DATASETS, run_cli


@pytest.fixture(scope="module")
def bc_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bc") / "run"
    result = run_cli("train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--env", "CartPole-v1", "--epochs", "3", "--out", str(out), "--quiet")
    assert result.returncode == 0, result.stderr
    return out


def test_normalised_score_uses_the_runs_demos_and_a_random_policy(bc_run) -> None:
    result = run_cli("eval", "policy", str(bc_run), "--env", "CartPole-v1", "--episodes", "3", "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    reference = report["reference"]
    assert reference["demos"] == [str(DATASETS / "CartPole-v1.mcap")]
    assert reference["expert_return"] == pytest.approx(500.0)
    assert 8 < reference["random_return"] < 60
    expected = (report["mean_return"] - reference["random_return"]) / (reference["expert_return"] - reference["random_return"])
    assert report["normalized_return"] == pytest.approx(expected)


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_video_holds_every_frame_of_the_episode(bc_run, tmp_path, suffix) -> None:
    video = tmp_path / f"episode{suffix}"
    result = run_cli("eval", "policy", str(bc_run), "--env", "CartPole-v1", "--episodes", "1", "--video", str(video), "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    frames = int(report["mean_length"]) + 1
    assert report["video"]["frames"] == frames
    if suffix == ".gif":
        from PIL import Image

        # Pillow merges identical consecutive frames into one longer frame: count by duration.
        with Image.open(video) as image:
            duration = 0
            for index in range(image.n_frames):
                image.seek(index)
                duration += image.info["duration"]
        assert duration == frames * round(1000 / report["video"]["fps"])
    else:
        import av

        with av.open(str(video)) as container:
            assert sum(1 for _ in container.decode(video=0)) == frames
    assert [p.name for p in tmp_path.iterdir()] == [video.name]


def test_video_with_an_unknown_suffix_is_one_line(bc_run, tmp_path) -> None:
    result = run_cli("eval", "policy", str(bc_run), "--env", "CartPole-v1", "--episodes", "1", "--video", str(tmp_path / "episode.avi"))
    assert result.returncode == 1 and result.stderr.strip().splitlines()[-1].startswith("error: --video")
    assert not list(tmp_path.iterdir())
