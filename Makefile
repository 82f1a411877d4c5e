# `make demo` and `make test` work on a fresh clone: both bootstrap .venv first.
PY := .venv/bin/python
IMITATION := $(PY) cli.py
DEMO_OUT := demo-output
# Bundled datasets: seeds start at 1000 so evaluations on seeds 0, 1, 2, ... see fresh starts.
DATASET_SEED := 1000

.PHONY: venv demo test test-all bench datasets clean

venv:
	@bash scripts/bootstrap.sh

demo: venv
	@mkdir -p $(DEMO_OUT)
	@for f in datasets/*.mcap; do echo "== $$f"; $(IMITATION) info $$f || exit 1; echo; done
	@echo "== recording 3 scripted Pendulum-v1 episodes to $(DEMO_OUT)/pendulum.mcap"
	@$(IMITATION) record --env Pendulum-v1 --expert scripted --episodes 3 --seed 0 --out $(DEMO_OUT)/pendulum.mcap
	@$(IMITATION) info $(DEMO_OUT)/pendulum.mcap
	@echo; echo "== behavioural cloning on the bundled CartPole-v1 demos"
	@$(IMITATION) train bc --demos datasets/CartPole-v1.mcap --env CartPole-v1 --epochs 40 --out $(DEMO_OUT)/bc-cartpole --quiet
	@echo; echo "== DAgger on CartPole-v1 with the scripted expert (3 rounds)"
	@$(IMITATION) train dagger --env CartPole-v1 --expert scripted --rounds 3 --episodes-per-round 3 --epochs 30 --out $(DEMO_OUT)/dagger-cartpole --quiet
	@echo; echo "== PPO on CartPole-v1 (100k steps)"
	@$(IMITATION) train ppo --env CartPole-v1 --steps 100000 --out $(DEMO_OUT)/ppo-cartpole --quiet
	@$(IMITATION) eval policy $(DEMO_OUT)/ppo-cartpole --env CartPole-v1 --episodes 10
	@echo; echo "== maximum causal entropy IRL on the bundled slippery-gridworld demos"
	@$(IMITATION) train irl --method mce --env imitation/GridWorld8x8Slippery-v0 --demos datasets/GridWorld8x8Slippery-v0.mcap --iterations 500 --out $(DEMO_OUT)/irl-gridworld --quiet
	@echo; echo "== guided cost learning on the bundled fixed-horizon CartPole demos, then PPO from scratch on the recovered reward"
	@$(IMITATION) train irl --method gcl --env imitation/CartPoleFixedHorizon-v0 --demos datasets/CartPoleFixedHorizon-v0.mcap --steps 200000 --out $(DEMO_OUT)/gcl-cartpole --quiet
	@$(IMITATION) train ppo --env imitation/CartPoleFixedHorizon-v0 --reward $(DEMO_OUT)/gcl-cartpole --steps 300000 --out $(DEMO_OUT)/ppo-on-gcl-reward --quiet
	@$(IMITATION) eval policy $(DEMO_OUT)/ppo-on-gcl-reward --env imitation/CartPoleFixedHorizon-v0 --episodes 10

# pytest exits 5 when it collects nothing; that is not a pass, but not a crash either: say so.
test: venv
	@$(PY) -m pytest -q; rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "make test: pytest collected no tests"; exit 0; fi; exit $$rc

test-all: venv
	@$(PY) -m pytest -q -m "slow or not slow"

# Peers (LeRobot, stable-baselines3, HumanCompatibleAI/imitation) are measured side by side, each peer in its own venv under bench/
bench: venv
	$(PY) bench/load.py
	$(PY) bench/ppo.py
	$(PY) bench/bc.py
	$(PY) bench/dagger_vs_bc.py
	$(PY) bench/irl.py
	$(PY) bench/irl.py --continuous

datasets: venv
	$(IMITATION) record --env CartPole-v1 --expert scripted --episodes 25 --seed $(DATASET_SEED) --out datasets/CartPole-v1.mcap
	$(IMITATION) record --env MountainCar-v0 --expert scripted --episodes 50 --seed $(DATASET_SEED) --out datasets/MountainCar-v0.mcap
	$(IMITATION) record --env Pendulum-v1 --expert scripted --episodes 50 --seed $(DATASET_SEED) --out datasets/Pendulum-v1.mcap
	$(IMITATION) record --env imitation/CartPoleFixedHorizon-v0 --expert scripted --episodes 25 --seed $(DATASET_SEED) --out datasets/CartPoleFixedHorizon-v0.mcap
	$(IMITATION) record --env imitation/GridWorld8x8-v0 --expert scripted --episodes 50 --seed $(DATASET_SEED) --out datasets/GridWorld8x8-v0.mcap
	$(IMITATION) record --env imitation/GridWorld8x8Slippery-v0 --expert scripted --episodes 50 --seed $(DATASET_SEED) --out datasets/GridWorld8x8Slippery-v0.mcap

clean:
	rm -rf $(DEMO_OUT) .pytest_cache
