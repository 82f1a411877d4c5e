"""The mutation score of the numerical core, per module, from the last `mutmut run` (`make mutate`).

Every mutant mutmut generated in the modules [tool.mutmut] names is counted: killed (a test
failed, or the mutant ran past mutmut's time limit), equivalent (it survived, and
bench/mutation_equivalents.toml says why no test can tell it from the original), or surviving.
The score is killed / (generated - equivalent). Surviving mutants are listed by name: `mutmut
show NAME` prints the change.

    python tools/mutation_report.py            # the table, then the survivors
    python tools/mutation_report.py --json     # one JSON object
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tomllib
from collections import Counter, defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
EQUIVALENTS = REPO / "bench" / "mutation_equivalents.toml"
DETECTED = ("killed", "timeout", "caught by type check", "segfault")
# imitation.algorithms.ppo.x_compute_gae__mutmut_17, imitation.policies.xǁActorCriticǁsample__mutmut_3
_NAME = re.compile(r"^(?P<module>[\w.]+)\.x(?:_|ǁ)")


def mutant_statuses() -> dict[str, str]:
    """Every mutant's status, as `mutmut results --all true` prints them."""
    mutmut = Path(sys.executable).with_name("mutmut")
    listing = subprocess.run([str(mutmut), "results", "--all", "true"], cwd=REPO, capture_output=True, text=True, check=True).stdout
    statuses = {}
    for line in listing.splitlines():
        name, _, status = line.strip().rpartition(": ")
        if name:
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
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    equivalents = tomllib.loads(EQUIVALENTS.read_text()) if EQUIVALENTS.exists() else {}
    statuses = mutant_statuses()
    stale = sorted(set(equivalents) - set(statuses))
    table = report(statuses, equivalents)
    if args.json:
        print(json.dumps({"modules": table, "stale_equivalents": stale}, indent=2))
        return 0
    print(f"{'module':40} {'generated':>9} {'killed':>7} {'equiv.':>7} {'surviving':>9} {'other':>6} {'score':>7}")
    for module, row in sorted(table.items()):
        other = row["generated"] - row["killed"] - row.get("equivalent", 0) - row.get("surviving", 0)
        print(f"{module:40} {row['generated']:9d} {row['killed']:7d} {row.get('equivalent', 0):7d} {row.get('surviving', 0):9d} {other:6d} {row['score']:7.1%}")
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
