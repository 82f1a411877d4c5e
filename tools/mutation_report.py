"""Mutation testing of the numerical core with mutmut, and its score per module (`make mutate`).

The core is every function of the modules SCOPE names (mutmut's own names, matched as
prefixes): PPO (its formulas, update, rollout collection, state and config), the policies (with
the observation encoding and MLPs they share with the reward models), BC,
DAgger, tabular MaxEnt IRL and its planning, EPIC, GCL, the reward models and the loader's
column placement; and since issue 50 policy gradient, policy search, apprenticeship learning,
GAIL/AIRL and their discriminator loop, PPO's rollouts and DAgger's rounds on Ray workers, the
envs' true rewards, the converters' resampling and image frames as messages; and since issue 52
the pieces moved into rooms of their own (GAE, vector envs, the loop beside PPO), the policy
protocol and its kinds, with issue 53's windows and action chunking. `--modules` runs
only some of them (their prefixes; mutmut's results for the others are kept). Each of their mutants is counted as killed (a test failed, or it ran past
mutmut's time limit), equivalent (it survived, and bench/mutation_equivalents.toml says why no
test can tell it from the original) or surviving; the score is killed / (generated -
equivalent). Survivors are listed by name: `mutmut show NAME` prints the change.

    python tools/mutation_report.py --run      # mutmut run over SCOPE (results kept in mutants/), then the table
    python tools/mutation_report.py --run --modules imitation.algorithms.gail. imitation.algorithms.airl.
    python tools/mutation_report.py --survivors  # run the last run's survivors again, then the table
    python tools/mutation_report.py            # the table of the last run, then the survivors
    python tools/mutation_report.py --json     # one JSON object
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tomllib
from collections import Counter, defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
EQUIVALENTS = REPO / "bench" / "mutation_equivalents.toml"
DETECTED = ("killed", "timeout", "caught by type check", "segfault")
SCOPE = (
    "imitation.algorithms.ppo.",
    "imitation.algorithms.ppo_config.",
    "imitation.policies.",
    "imitation.observation_encoding.",
    "imitation.mlp.",
    "imitation.algorithms.bc.",
    "imitation.algorithms.bc_config.",
    "imitation.algorithms.dagger.",
    "imitation.algorithms.dagger_config.",
    "imitation.algorithms.maxent_irl.",
    "imitation.algorithms.maxent_irl_config.",
    "imitation.envs.tabular_planning.",
    "imitation.evaluation.epic.",
    "imitation.algorithms.gcl.",
    "imitation.algorithms.gcl_config.",
    "imitation.rewards.",
    "imitation.data.columns.",
    "imitation.algorithms.policy_gradient.",
    "imitation.algorithms.policy_gradient_config.",
    "imitation.algorithms.policy_search.",
    "imitation.algorithms.policy_search_config.",
    "imitation.algorithms.apprenticeship.",
    "imitation.algorithms.apprenticeship_config.",
    "imitation.algorithms.adversarial.",
    "imitation.algorithms.adversarial_config.",
    "imitation.algorithms.gail.",
    "imitation.algorithms.airl.",
    "imitation.algorithms.ray_rollouts.",
    "imitation.algorithms.ray_dagger.",
    "imitation.envs.true_rewards.",
    "imitation.data.convert.resample.",
    "imitation.data.mcap.images.",
    "imitation.algorithms.advantages.",
    "imitation.envs.vector.",
    "imitation.algorithms.beside_ppo.",
    "imitation.policy_protocol.",
    "imitation.policy_kinds.",
    "imitation.chunk_policy.",
    "imitation.data.windows.",
)
# imitation.algorithms.ppo.x_compute_gae__mutmut_17, imitation.policies.xǁActorCriticǁsample__mutmut_3
_NAME = re.compile(r"^(?P<module>[\w.]+)\.x(?:_|ǁ)")


MUTMUT = Path(sys.executable).with_name("mutmut")


def run_mutmut(workers: int, names: list[str]) -> None:
    """`mutmut run` over the given mutants (names or globs), each run again even if checked before."""
    subprocess.run([str(MUTMUT), "run", "--max-children", str(workers), *names], cwd=REPO, check=True)


def mutant_statuses() -> dict[str, str]:
    """The status of every mutant of the core, as `mutmut results --all true` prints them."""
    listing = subprocess.run([str(MUTMUT), "results", "--all", "true"], cwd=REPO, capture_output=True, text=True, check=True).stdout
    statuses = {}
    for line in listing.splitlines():
        name, _, status = line.strip().rpartition(": ")
        if name.startswith(SCOPE):
            statuses[name] = status
    return statuses


def report(statuses: dict[str, str], equivalents: dict[str, str]) -> dict[str, dict]:
    """Per module: counts by outcome and the score; the survivors not recorded as equivalent."""
    modules: dict[str, Counter] = defaultdict(Counter)
    survivors: dict[str, list[str]] = defaultdict(list)
    for name, status in sorted(statuses.items()):
        module = _NAME.match(name).group("module")
        if status in DETECTED:
            outcome = "killed"
        elif name in equivalents:
            outcome = "equivalent"
        else:
            outcome = "surviving" if status == "survived" else status
            survivors[module].append(name)
        modules[module][outcome] += 1
    table = {}
    for module, counts in modules.items():
        generated = sum(counts.values())
        scored = generated - counts["equivalent"]
        table[module] = {"generated": generated, **counts, "score": counts["killed"] / scored if scored else 1.0, "survivors": survivors[module]}
    return table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="store_true", help="run mutmut over the core first")
    parser.add_argument("--survivors", action="store_true", help="run mutmut again over the last run's survivors only (after adding tests)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="mutants tested at once (default: the CPU count)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--modules", nargs="+", choices=SCOPE, metavar="PREFIX", help="with --run: only these of SCOPE")
    args = parser.parse_args(argv)
    if args.run:
        run_mutmut(args.workers, [f"{prefix}*" for prefix in args.modules or SCOPE])
    elif args.survivors:
        run_mutmut(args.workers, [name for name, status in mutant_statuses().items() if status not in DETECTED])
    equivalents = tomllib.loads(EQUIVALENTS.read_text()) if EQUIVALENTS.exists() else {}
    statuses = mutant_statuses()
    stale = sorted(set(equivalents) - set(statuses))
    table = report(statuses, equivalents)
    if args.json:
        print(json.dumps({"modules": table, "stale_equivalents": stale}, indent=2))
        return 0
    print(f"{'module':40} {'generated':>9} {'killed':>7} {'equiv.':>7} {'surviving':>9} {'other':>6} {'score':>7}")
    for module, row in sorted(table.items()):
        other = row["generated"] - row.get("killed", 0) - row.get("equivalent", 0) - row.get("surviving", 0)
        print(f"{module:40} {row['generated']:9d} {row.get('killed', 0):7d} {row.get('equivalent', 0):7d} {row.get('surviving', 0):9d} {other:6d} {row['score']:7.1%}")
    total = {key: sum(row.get(key, 0) for row in table.values()) for key in ("generated", "killed", "equivalent")}
    print(f"{'all':40} {total['generated']:9d} {total['killed']:7d} {total['equivalent']:7d} {'':>9} {'':>6} {total['killed'] / max(1, total['generated'] - total['equivalent']):7.1%}")
    for module, row in sorted(table.items()):
        for name in row["survivors"]:
            print(f"not killed ({statuses[name]}): {name}")
    for name in stale:
        print(f"stale entry in {EQUIVALENTS.relative_to(REPO)} (no such mutant now): {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
