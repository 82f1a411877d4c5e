"""`imitation demo`: the whole chain on the bundled data, offline, with one report at the end.

bundled demos → behavioural cloning and DAgger (CartPole-v1) → MaxEnt IRL on a gridworld (exact
MCE IRL, judged exactly) and on a continuous env (guided cost learning on fixed-horizon
CartPole) → PPO from scratch on the recovered reward → `eval policy` and `eval reward` (EPIC,
retraining, controls) → report.md.

Guided cost learning, the longest stage, runs in a second process beside the short stages, and
`eval reward` retrains its three PPO policies (recovered reward and two controls) side by side:
on 2 cores the demo takes about three minutes.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import closing
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from imitation.algorithms.bc import BCConfig
from imitation.algorithms.dagger import DAggerConfig
from imitation.algorithms.gcl import GCLConfig
from imitation.algorithms.maxent_irl import MaxEntIRLConfig
from imitation.algorithms.ppo import PPOConfig
from imitation.bundled import bundled_datasets
from imitation.data.summary import summarize
from imitation.envs.make import make_env
from imitation.errors import ImitationError
from imitation.evaluation.policy import EVAL_EPISODES, EVAL_SEED
from imitation.evaluation.report import write_report
from imitation.evaluation.reward import reward_report
from imitation.evaluation.video import record_video
from imitation.jobs.bc import bc_job
from imitation.jobs.dagger import dagger_job
from imitation.jobs.evaluate_policy import eval_policy_job
from imitation.jobs.evaluate_policy_config import PolicyEvaluationConfig
from imitation.jobs.evaluate_reward import RewardEvaluationConfig, evaluate_reward
from imitation.jobs.irl import gcl_job, tabular_irl_job
from imitation.jobs.presets import ppo_settings, preset
from imitation.jobs.run_config import RunConfig
from imitation.policies import SingleObservationPolicy
from imitation.policy_kinds import load_policy
from imitation.runs import read_run

BUNDLED = bundled_datasets()
GRIDWORLD = "imitation/GridWorld8x8Slippery-v0"
CARTPOLE_FH = "imitation/CartPoleFixedHorizon-v0"
QUICK_STEPS = 4096


def run_demo(
    out: str | os.PathLike, *, datasets: str | os.PathLike = BUNDLED, quick: bool = False, progress: bool = True
) -> dict[str, Any]:
    """Run every stage into `out`; returns the results and the report's path. `quick` shrinks
    every training to a smoke test (a minute; the learning results then mean nothing)."""
    out, datasets = Path(out), Path(datasets)
    for name in ("CartPole-v1.mcap", f"{GRIDWORLD.split('/')[1]}.mcap", f"{CARTPOLE_FH.split('/')[1]}.mcap"):
        if not (datasets / name).is_file():
            raise ImitationError(f"--datasets {datasets}: no {name} (the bundled datasets; `make datasets` rebuilds them)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ImitationError(f"--out {out}: cannot create: {error.strerror or error}") from None
    started = time.perf_counter()
    results: dict[str, Any] = {"datasets": _dataset_summaries(datasets)}
    _say(f"guided cost learning on {CARTPOLE_FH} runs in the background meanwhile", progress)
    with ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn")) as pool:
        gcl = pool.submit(_timed, _gcl_stage, datasets, out, steps=QUICK_STEPS if quick else preset(CARTPOLE_FH).irl_steps)
        results["bc"] = _timed(_bc_stage, datasets, out, epochs=2 if quick else 40, progress=progress)
        results["dagger"] = _timed(_dagger_stage, datasets, out, epochs=2 if quick else 30, progress=progress)
        results["tabular_irl"] = _timed(_tabular_irl_stage, datasets, out, iterations=20 if quick else 500, progress=progress)
        results["gcl"] = gcl.result()
    _say(
        f"guided cost learning done in {results['gcl']['seconds']:.0f} s; evaluating its reward (PPO retrained from scratch "
        "on it and on two controls)",
        progress,
    )
    results["gcl_eval"] = _timed(
        _gcl_evaluation_stage, out, steps=QUICK_STEPS if quick else preset(CARTPOLE_FH).retrain_steps, progress=progress
    )
    results["seconds"] = time.perf_counter() - started
    report, page = write_report(out / "report.md", demo_report(results, out), title="imitation demo")
    return {"report": str(report), "report_html": str(page), **results}


def _say(text: str, progress: bool) -> None:
    if progress:
        print(f"[demo] {text}", flush=True)


def _timed(stage: Any, *args: Any, **kwargs: Any) -> dict[str, Any]:
    started = time.perf_counter()
    result = stage(*args, **kwargs)
    return {**result, "seconds": time.perf_counter() - started}


def _dataset_summaries(datasets: Path) -> list[dict[str, Any]]:
    return [summarize(path) for path in sorted(datasets.glob("*.mcap"))]


def _policy_eval(run: str | os.PathLike, env_id: str, demos: list[str]) -> dict[str, Any]:
    return eval_policy_job(run, env_id, PolicyEvaluationConfig(episodes=EVAL_EPISODES, seed=EVAL_SEED, demos=demos))


def _bc_stage(datasets: Path, out: Path, *, epochs: int, progress: bool) -> dict[str, Any]:
    _say("behavioural cloning on the bundled CartPole-v1 demos", progress)
    demos = [str(datasets / "CartPole-v1.mcap")]
    run = bc_job(demos, "CartPole-v1", BCConfig(epochs=epochs), out / "bc-cartpole", progress=False)
    return {
        "run": run["run"],
        "epochs": run["epochs"],
        "validation_loss": run["best_validation_loss"],
        "eval": _policy_eval(run["run"], "CartPole-v1", demos),
    }


def _dagger_stage(datasets: Path, out: Path, *, epochs: int, progress: bool) -> dict[str, Any]:
    _say("DAgger on CartPole-v1 with the scripted expert (3 rounds)", progress)
    run = dagger_job(
        "CartPole-v1",
        "scripted",
        DAggerConfig(rounds=3, episodes_per_round=3, bc=BCConfig(epochs=epochs)),
        out / "dagger-cartpole",
        progress=False,
    )
    evaluation = _policy_eval(run["run"], "CartPole-v1", [str(datasets / "CartPole-v1.mcap")])
    return {
        "run": run["run"],
        "rounds": run["rounds"],
        "expert_labels": run["expert_labels"],
        "round_returns": run["round_returns"],
        "eval": evaluation,
    }


def _tabular_irl_stage(datasets: Path, out: Path, *, iterations: int, progress: bool) -> dict[str, Any]:
    _say(f"maximum causal entropy IRL on the bundled {GRIDWORLD} demos, then its reward evaluated exactly", progress)
    run = tabular_irl_job(
        [str(datasets / f"{GRIDWORLD.split('/')[1]}.mcap")],
        GRIDWORLD,
        MaxEntIRLConfig(method="mce", iterations=iterations),
        out / "irl-gridworld",
        progress=False,
    )
    evaluation = evaluate_reward(
        run["run"], GRIDWORLD, RewardEvaluationConfig(), Path(run["run"]) / "eval-reward", progress=False
    )
    return {
        "run": run["run"],
        "iterations": run["iterations"],
        "occupancy_error": run["occupancy_error"],
        "normalized_return": run["normalized_return"],
        "evaluation": evaluation,
    }


def _gcl_stage(datasets: Path, out: Path, *, steps: int) -> dict[str, Any]:
    """In a worker process: guided cost learning with `train irl --method gcl`'s defaults."""
    import torch

    torch.set_num_threads(1)
    with closing(make_env(CARTPOLE_FH)) as env:
        settings = ppo_settings(CARTPOLE_FH, env.action_space, beside_irl=True)
    demos = [str(datasets / f"{CARTPOLE_FH.split('/')[1]}.mcap")]
    run = gcl_job(
        demos,
        CARTPOLE_FH,
        GCLConfig(),
        PPOConfig(env_id=CARTPOLE_FH, total_steps=steps, **settings),
        out / "gcl-cartpole",
        progress=False,
    )
    return {
        "run": run["run"],
        "steps": run["steps"],
        "demo_return": run["demo_return"],
        "demo_accuracy": run["demo_accuracy"],
        "sample_accuracy": run["sample_accuracy"],
        "eval": run["eval"],
    }


def _gcl_evaluation_stage(out: Path, *, steps: int, progress: bool) -> dict[str, Any]:
    reward_run = out / "gcl-cartpole"
    config = RewardEvaluationConfig(retrain_steps=steps, seeds=1, jobs=3)
    evaluation = evaluate_reward(reward_run, CARTPOLE_FH, config, reward_run / "eval-reward", progress=progress)
    retrained = Path(evaluation["out"]) / evaluation["retrain"]["seed_runs"][0]
    video = out / "ppo-on-gcl-reward.gif"
    demos = RunConfig.from_json(read_run(reward_run)[0]).existing_demos()
    policy = eval_policy_job(
        retrained, CARTPOLE_FH, PolicyEvaluationConfig(episodes=EVAL_EPISODES, seed=EVAL_SEED, demos=demos)
    )
    video_return = record_video(CARTPOLE_FH, SingleObservationPolicy(load_policy(retrained)), video, seed=0)["return"]
    return {
        "evaluation": evaluation,
        "retrained_policy": {"run": str(retrained), "eval": policy, "video": video.name, "video_return": video_return},
    }


# ------------------------------------------------------------------------------------------------
# The report


def _relative(path: str | os.PathLike, root: Path) -> str:
    return os.path.relpath(path, root)


def _policy_row(stage: str, what: str, evaluation: dict[str, Any], seconds: float) -> str:
    normalized = evaluation.get("normalized_return")
    shown = "" if normalized is None else f" (normalised {normalized:.2f})"
    return f"| {stage} | {what} | {evaluation['mean_return']:.1f} ± {evaluation['std_return']:.1f}{shown} | {seconds:.0f} s |"


def demo_report(results: dict[str, Any], out: Path) -> str:
    """Every stage's numbers and plots as one Markdown page (image paths relative to `out`)."""
    bc, dagger, tabular, gcl, gcl_eval = (
        results["bc"],
        results["dagger"],
        results["tabular_irl"],
        results["gcl"],
        results["gcl_eval"],
    )
    retrained = gcl_eval["retrained_policy"]
    tabular_eval, continuous_eval = tabular["evaluation"], gcl_eval["evaluation"]
    lines = [
        "# imitation demo",
        "",
        f"The whole chain on the bundled demos, offline, in {results['seconds']:.0f} s. Returns are deterministic evaluations "
        "(10 episodes, seeds 10000+); normalised returns put a uniform random policy at 0 and the demos at 1.",
        "",
        "| stage | what | result | time |",
        "|---|---|---|---:|",
        _policy_row("behavioural cloning", "CartPole-v1, bundled demos", bc["eval"], bc["seconds"]),
        _policy_row(
            "DAgger",
            f"CartPole-v1, scripted expert, {dagger['rounds']} rounds, {dagger['expert_labels']} labels",
            dagger["eval"],
            dagger["seconds"],
        ),
        f"| MCE IRL | {GRIDWORLD}, bundled demos | EPIC {tabular_eval['epic']:.3f}, optimal policy for it normalised "
        f"{tabular_eval['retrain']['normalized']:.2f} | {tabular['seconds']:.0f} s |",
        f"| guided cost learning | {CARTPOLE_FH}, bundled demos, {gcl['steps']:,} PPO steps | its maximum-entropy sampler "
        f"{gcl['eval']['mean_return']:.1f} (not for use) | {gcl['seconds']:.0f} s |",
        _policy_row(
            "PPO on the recovered reward",
            f"{CARTPOLE_FH}, from scratch, {continuous_eval['retrain']['steps']:,} steps",
            retrained["eval"],
            gcl_eval["seconds"],
        ),
        f"| eval reward | GCL reward vs the true one | EPIC {continuous_eval['epic']:.3f}; controls: constant "
        f"{continuous_eval['controls']['constant']['normalized']:.2f}, random network "
        f"{continuous_eval['controls']['random']['normalized']:.2f} (normalised, retrained) | (with the row above) |",
        "",
        "## Bundled datasets",
        "",
        "| file | env | episodes | transitions | return (mean ± std) |",
        "|---|---|---:|---:|---:|",
        *(
            f"| {Path(s['file']).name} | {s['env_id']} | {s['episodes']} | {s['transitions']:,} | {s['return']['mean']:.2f} "
            f"± {s['return']['std']:.2f} |"
            for s in results["datasets"]
        ),
        "",
        "## Behavioural cloning",
        "",
        f"{bc['epochs']} epochs, best validation loss {bc['validation_loss']:.4f}; run `{_relative(bc['run'], out)}`.",
        "",
        f"![BC loss]({_relative(Path(bc['run']) / 'loss_curve.png', out)})",
        "",
        "## DAgger",
        "",
        "Return after each round: "
        + ", ".join(f"{value:.1f}" for value in dagger["round_returns"])
        + f"; run `{_relative(dagger['run'], out)}`.",
        "",
        f"![DAgger]({_relative(Path(dagger['run']) / 'return_curve.png', out)})",
        "",
        "## MaxEnt IRL on a gridworld",
        "",
        f"MCE IRL, {tabular['iterations']} iterations, final visitation error {tabular['occupancy_error']:.2e}; run "
        f"`{_relative(tabular['run'], out)}`.",
        "",
        f"![visitation]({_relative(Path(tabular['run']) / 'occupancy_maps.png', out)})",
        "",
        reward_report(tabular_eval, heading="###", image_prefix=_relative(tabular_eval["out"], out) + "/"),
        "## Guided cost learning, then PPO on the recovered reward",
        "",
        "GCL alternates reward updates with PPO on the current reward plus an entropy term, the maximum-entropy policy its "
        "model assumes, which stays far more random than the demos (its return above); at the end its discriminator calls "
        f"{gcl['demo_accuracy']:.2f} of demo states and {gcl['sample_accuracy']:.2f} of policy states correctly; run "
        f"`{_relative(gcl['run'], out)}`. A fresh PPO policy trained on the recovered reward alone earns "
        f"{retrained['eval']['mean_return']:.1f} of the true reward (normalised "
        f"{retrained['eval']['normalized_return']:.2f}); an episode of it: [{retrained['video']}]({retrained['video']}).",
        "",
        f"![GCL reward learning]({_relative(Path(gcl['run']) / 'reward_curve.png', out)})",
        f"![PPO on the recovered reward]({_relative(Path(retrained['run']) / 'learning_curve.png', out)})",
        "",
        reward_report(continuous_eval, heading="###", image_prefix=_relative(continuous_eval["out"], out) + "/"),
    ]
    return "\n".join(lines) + "\n"
