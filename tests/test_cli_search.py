"""`train hill-climb`, `train cem`, `train cmaes` from the command line: a complete run directory
whose policy `eval policy` evaluates exactly as the search's own final evaluation did, help text
that states the config's defaults, and a NaN from the env as one line."""

from __future__ import annotations

import dataclasses
import json
import re

import pytest
from support import run_cli_many
from test_cli import assert_one_line_error, last_json
from test_numerical_faults import assert_checkpoint_kept

PENDULUM = ["--env", "Pendulum-v1", "--hidden", "4", "--population", "3", "--steps", "1600", "--quiet", "--json"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every command these tests check, in one process (see run_cli_many): a CEM run on CartPole
    and `eval policy` on the final evaluation's episodes; hill climbing and CMA-ES of a small MLP on
    Pendulum, each evaluated; CEM on an env that returns NaN (tests/nan_envs.py)."""
    root = tmp_path_factory.mktemp("search")
    cases = {
        "cem": ["train", "cem", "--env", "CartPole-v1", "--steps", "12000", "--seed", "1", "--out", root / "cem", "--json"],
        "cem eval": ["eval", "policy", root / "cem", "--env", "CartPole-v1", "--episodes", "10", "--seed", "10000", "--json"],
        "hill-climb": ["train", "hill-climb", *PENDULUM, "--out", root / "hill-climb"],
        "hill-climb eval": ["eval", "policy", root / "hill-climb", "--env", "Pendulum-v1", "--episodes", "2", "--json"],
        "cmaes": ["train", "cmaes", *PENDULUM, "--out", root / "cmaes"],
        "cmaes eval": ["eval", "policy", root / "cmaes", "--env", "Pendulum-v1", "--episodes", "2", "--json"],
        "nan": ["train", "cem", "--env", "nan_envs:NaNObservation-v0", "--steps", "5000", "--quiet", "--out", root / "nan"],
    }
    return root, dict(zip(cases, run_cli_many(list(cases.values()))))


def test_train_cem_writes_a_run_directory_eval_policy_reads(runs) -> None:
    root, results = runs
    out, result, evaluation = root / "cem", last_json(results["cem"]), last_json(results["cem eval"])
    assert result["run"] == str(out) and result["method"] == "cem" and result["parameters"] == 10  # linear: 2 × 4 + 2
    assert 12000 - 17 * 500 < result["steps"] <= 12000 and result["generations"] >= 2
    names = {path.name for path in out.iterdir()}
    assert {"config.json", "model.safetensors", "metrics.json", "progress.csv", "learning_curve.png"} <= names
    config = json.loads((out / "config.json").read_text())
    assert config["kind"] == "search" and config["search"]["method"] == "cem" and config["policy"]["hidden_sizes"] == []
    rows = (out / "progress.csv").read_text().splitlines()
    assert rows[0].startswith("step,") and len(rows) == 1 + result["generations"]
    # `eval policy` on the final evaluation's episodes gives its figure: the saved policy is the searched one.
    assert evaluation["mean_return"] == pytest.approx(result["eval"]["mean_return"])
    assert result["eval"]["mean_return"] > 100  # the initial policy of seed 1 balances for ~28 steps


def test_hill_climb_and_cmaes_train_mlp_policies_on_continuous_actions(runs) -> None:
    _, results = runs
    for method in ("hill-climb", "cmaes"):
        result, evaluation = last_json(results[method]), last_json(results[f"{method} eval"])
        # Full-length generations of 4 policies × 200 steps: the 1600-step budget is two.
        assert result["method"] == method and result["steps"] == 1600 and result["generations"] == 2
        assert result["parameters"] == 3 * 4 + 4 + 4 + 1
        assert evaluation["episodes"] == 2


def test_a_nan_from_the_env_is_one_line(runs) -> None:
    root, results = runs
    assert_one_line_error(
        results["nan"],
        "nan_envs:NaNObservation-v0: the environment returned a non-finite observation by env step",
        "CEM needs finite observations and rewards",
    )
    assert_checkpoint_kept(results["nan"], root / "nan")  # the NaN comes after a checkpoint


def _shown(value: object) -> str:
    """A default as the help text writes it: layer widths comma-separated, [] as linear."""
    if isinstance(value, list):
        return ",".join(map(str, value)) or "linear"
    return str(value)


def test_search_help_names_the_configs_own_defaults() -> None:
    """The flags have no argparse defaults (an absent flag leaves the preset's or SearchConfig's
    value), so the help text must state those."""
    from cli import make_parser
    from imitation.algorithms.policy_search import SearchConfig
    from imitation.flags import flag_name, flagged
    from imitation.jobs.search import DEFAULT_STEPS, PRESETS

    defaults = {
        f.name: f.default if f.default is not dataclasses.MISSING else f.default_factory()
        for f in dataclasses.fields(SearchConfig)
        if f.name != "env_id"
    }
    train = make_parser()._subparsers._group_actions[0].choices["train"]._subparsers._group_actions[0]
    for method in ("hill-climb", "cem", "cmaes"):
        parser = train.choices[method]
        helps = {option: action.help for action in parser._actions for option in action.option_strings}
        for field, flag in ((field.name, flag_name(field)) for field in flagged(SearchConfig) if field.name != "env_id"):
            assert parser.get_default(flag.lstrip("-").replace("-", "_")) is None, flag
            shown = re.search(r"\(default: ([^)]+)\)", helps[flag])
            assert shown is not None, flag
            preset = {env_id: settings[field] for env_id, settings in PRESETS.items() if field in settings}
            fallback = DEFAULT_STEPS if field == "total_steps" else defaults[field]
            for env_id, value in preset.items():
                assert f"{_shown(value)} for {env_id}" in shown[1], flag
            text = _shown(fallback)
            assert shown[1].endswith(f"else {text}") if preset else shown[1] == text, (flag, shown[1])
