# `make demo` and `make test` work on a fresh clone: both bootstrap .venv first.
PY := .venv/bin/python
IMITATION := $(PY) cli.py
DEMO_OUT := demo-output
# Bundled datasets: seeds start at 1000 so evaluations on seeds 0, 1, 2, ... see fresh starts.
DATASET_SEED := 1000

.PHONY: venv demo lint test test-all bench bench-mujoco bench-claims fuzz mutate datasets clean

venv:
	@bash scripts/bootstrap.sh

demo: venv
	@$(IMITATION) demo --out $(DEMO_OUT)

# The guardrails ([tool.ruff] and [tool.mypy] in pyproject.toml): formatting, lint and types of
# the package and the command line. `make test` runs them first, so CI does too.
lint: venv
	@$(PY) -m ruff format --check --quiet imitation cli.py
	@$(PY) -m ruff check --quiet imitation cli.py
	@$(PY) -m mypy

# Two pytest workers (pytest-xdist), one per core of the 2-core CI machine: most tests spend their
# time in subprocesses and imports, so the pair keeps both cores busy. TEST_WORKERS=0 runs in one process.
TEST_WORKERS ?= 2

# pytest exits 5 when it collects nothing; that is not a pass, but not a crash either: say so.
test: venv lint
	@$(PY) -m pytest -q -n $(TEST_WORKERS); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "make test: pytest collected no tests"; exit 0; fi; exit $$rc

test-all: venv
	@$(PY) -m pytest -q -n $(TEST_WORKERS) -m "slow or not slow"

# Peers (LeRobot, stable-baselines3, HumanCompatibleAI/imitation) are measured side by side, each peer in its own venv under bench/
bench: venv
	$(PY) bench/load.py
	$(PY) bench/ppo.py
	$(PY) bench/bc.py
	$(PY) bench/dagger_vs_bc.py
	$(PY) bench/irl.py
	$(PY) bench/irl.py --continuous

# The MuJoCo table (issue 20): BC, DAgger, GAIL, AIRL and PPO on recovered rewards, 3 seeds, beside
# imitation 1.0.1 run on the same demos (its venv under bench/). The experts are our PPO's, as imitation's
# are; HalfCheetah's demos are recorded without DART noise. GAIL pays PPO the logit log D − log(1 − D)
# with a gradient penalty; AIRL's discriminator keeps every rollout, half of each minibatch's negatives
# from the latest; HalfCheetah's g is retrained on after a second AIRL run whose policy starts afresh
# (--airl-restart). Why each setting, and the figures: bench/RESULTS.md, "The MuJoCo table" sections.
# Hours on 2 cores; resumes where it stopped.
bench-mujoco: venv
	$(PY) bench/mujoco_table.py --peer --ppo-expert Hopper --ppo-expert HalfCheetah --action-noise HalfCheetah=0 \
		--gail-args "--gail-reward logit --gradient-penalty 10" --airl-args "--pool-rollouts 1000 --latest-share 0.5" \
		--airl-restart HalfCheetah=1000000

# The notes' claims as experiments, each ending in a verdict line (figures and plots: bench/RESULTS.md,
# "The notes' claims as experiments"); under an hour on 2 cores.
bench-claims: venv
	$(PY) bench/claim_baseline_variance.py
	$(PY) bench/claim_gradient_free.py
	$(PY) bench/claim_compounding.py
	$(PY) bench/claim_clip_vs_kl.py
	$(PY) bench/claim_apprenticeship.py

# Mutation fuzzing of every file reader, 10,000 inputs per target (figures: bench/RESULTS.md, "Current figures").
fuzz: venv
	$(PY) tools/fuzz.py

# Mutation testing of the numerical core ([tool.mutmut] in pyproject.toml); mutmut keeps its
# results in mutants/ and re-tests only what changed. Figures: bench/RESULTS.md, "Current figures".
mutate: venv
	OMP_NUM_THREADS=1 $(PY) tools/mutation_report.py --run

datasets: venv
	$(IMITATION) record --env CartPole-v1 --expert scripted --episodes 25 --seed $(DATASET_SEED) --out datasets/CartPole-v1.mcap
	$(IMITATION) record --env MountainCar-v0 --expert scripted --episodes 50 --seed $(DATASET_SEED) --out datasets/MountainCar-v0.mcap
	$(IMITATION) record --env Pendulum-v1 --expert scripted --episodes 50 --seed $(DATASET_SEED) --out datasets/Pendulum-v1.mcap
	$(IMITATION) record --env imitation/CartPoleFixedHorizon-v0 --expert scripted --episodes 25 --seed $(DATASET_SEED) --out datasets/CartPoleFixedHorizon-v0.mcap
	$(IMITATION) record --env imitation/GridWorld8x8-v0 --expert scripted --episodes 50 --seed $(DATASET_SEED) --out datasets/GridWorld8x8-v0.mcap
	$(IMITATION) record --env imitation/GridWorld8x8Slippery-v0 --expert scripted --episodes 50 --seed $(DATASET_SEED) --out datasets/GridWorld8x8Slippery-v0.mcap

clean:
	rm -rf $(DEMO_OUT) .pytest_cache .mypy_cache .ruff_cache mutants
