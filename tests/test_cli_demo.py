"""`imitation demo`: every stage runs on the bundled data and lands in one report.

The default run's learning results (≤ 5 minutes on 2 cores) are recorded in bench/RESULTS.md;
here `--quick` cuts every training short, so only the chain and the report are checked."""

from __future__ import annotations

import json
import re
from pathlib import Path

from support import run_cli


def test_quick_demo_writes_a_report_with_every_stage_and_plot(tmp_path) -> None:
    out = tmp_path / "demo"
    result = run_cli("demo", "--quick", "--out", str(out), "--json", timeout=600)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    report = Path(summary["report"])
    assert report == out / "report.md"
    text = report.read_text()
    for heading in ("## Bundled datasets", "## Behavioural cloning", "## DAgger", "## MaxEnt IRL on a gridworld", "## Guided cost learning"):
        assert heading in text
    for row in ("| behavioural cloning |", "| DAgger |", "| MCE IRL |", "| guided cost learning |", "| PPO on the recovered reward |", "| eval reward |"):
        assert row in text
    assert text.count("| control: constant reward |") == 2 and text.count("| control: random reward |") == 2
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert len(images) >= 10
    assert all((out / image).is_file() for image in images), [image for image in images if not (out / image).is_file()]
    assert (out / "ppo-on-gcl-reward.gif").is_file()
    page = Path(summary["report_html"]).read_text()
    assert page.startswith("<!doctype html>") and "<table>" in page
    assert all(f'src="{image}"' in page for image in images)
    for stage in ("bc", "dagger"):
        assert summary[stage]["eval"]["reference"]["expert_return"] == 500.0
    assert summary["gcl_eval"]["evaluation"]["epic"] is not None


def test_demo_without_its_datasets_is_one_line(tmp_path) -> None:
    result = run_cli("demo", "--datasets", str(tmp_path), "--out", str(tmp_path / "out"))
    assert result.returncode == 1 and result.stderr.count("\n") == 1 and "CartPole-v1.mcap" in result.stderr
    assert not (tmp_path / "out").exists()
