"""The bundled datasets: present, sound, expert-quality, and reproducible from their documented command."""

from __future__ import annotations

import json

import pytest
from support import DATASETS, run_cli

from imitation.data.mcap.reader import DemoFile

# (episodes, minimum mean return) as documented in datasets/README.md
BUNDLED = {
    "CartPole-v1": (25, 475.0), "MountainCar-v0": (50, -120.0), "Pendulum-v1": (50, -200.0),
    "imitation/CartPoleFixedHorizon-v0": (25, 475.0), "imitation/GridWorld8x8-v0": (50, 28.0), "imitation/GridWorld8x8Slippery-v0": (50, 18.0),
}


def _file(env_id: str):
    return DATASETS / f"{env_id.split('/')[-1]}.mcap"


@pytest.mark.parametrize("env_id", sorted(BUNDLED))
def test_bundled_dataset_is_sound_and_expert(env_id: str) -> None:
    demo = DemoFile(_file(env_id), verify=True)
    episodes, minimum_mean = BUNDLED[env_id]
    assert demo.damage is None and demo.env_id == env_id and len(demo) == episodes
    mean_return = sum(facts.episode_return for facts in demo.episodes) / len(demo)
    assert mean_return >= minimum_mean
    assert [facts.metadata["seed"] for facts in demo.episodes] == list(range(1000, 1000 + episodes))


def test_datasets_folder_holds_data_only() -> None:
    assert not list(DATASETS.rglob("*.py")), "a .py under datasets/ would make it shadow Hugging Face `datasets`"
    assert sum(path.stat().st_size for path in DATASETS.iterdir()) < 5_000_000


@pytest.mark.parametrize("env_id", ["MountainCar-v0", "imitation/GridWorld8x8Slippery-v0"])
def test_rerecording_reproduces_the_bundled_episodes(env_id: str, tmp_path) -> None:
    out = tmp_path / "again.mcap"
    result = run_cli("record", "--env", env_id, "--expert", "scripted", "--episodes", "5", "--seed", "1000", "--out", str(out), "--json")
    assert result.returncode == 0, result.stderr
    bundled = DemoFile(_file(env_id))
    again = DemoFile(out)
    assert [f.episode_return for f in again.episodes] == [f.episode_return for f in bundled.episodes[:5]]
    assert json.loads(result.stdout.splitlines()[-1])["episodes"] == 5
