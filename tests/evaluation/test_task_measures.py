"""The task's own measures from step infos (imitation/evaluation/task_measures.py), against values worked by hand."""

from __future__ import annotations

import numpy as np

from imitation.evaluation.task_measures import EpisodeMeasures, averaged, measures_line


def _episode(*infos: dict) -> dict[str, float]:
    measures = EpisodeMeasures()
    for info in infos:
        measures.step(info)
    return measures.result()


def test_an_episode_succeeds_if_any_step_did_and_keeps_its_largest_coverage() -> None:
    first = _episode({"is_success": False, "coverage": 0.2}, {"is_success": np.bool_(True), "coverage": 0.97}, {"coverage": 0.5})
    second = _episode({"is_success": False, "coverage": np.float64(0.4)}, {"is_success": False, "coverage": 0.1})
    assert first == {"is_success": 1.0, "coverage": 0.97} and second == {"is_success": 0.0, "coverage": 0.4}
    result = averaged([first, second])
    assert result == {"success_rate": 0.5, "episode_is_success": [1.0, 0.0], "mean_max_coverage": 0.685, "episode_coverage": [0.97, 0.4]}
    assert measures_line(result) == "success rate 0.500, mean max coverage 0.685"


def test_envs_without_the_keys_report_nothing_and_a_measure_missing_from_one_episode_is_left_out() -> None:
    assert _episode({"TimeLimit.truncated": True}, {"coverage": "high"}) == {}
    assert averaged([_episode({"coverage": 0.3}), _episode({})]) == {}
    assert averaged([]) == {} and measures_line({"mean_return": 1.0}) is None
