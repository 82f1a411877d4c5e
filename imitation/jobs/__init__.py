"""What runs a job: the command line calls exactly one function of this package per command.

- `loop`: the one training loop (checkpoints, resume, deferred Ctrl-C, logging, progress);
- `presets`: per-environment settings in one table;
- `run_config`: the typed config.json of a run directory;
- `run_directory`: what every training job does around its learner;
- `bc`, `dagger`, `ppo`, `pg` (policy gradient), `search` (hill climbing, CEM, CMA-ES), `irl` (MaxEnt,
  MCE, guided cost learning, GAIL, AIRL) and `apprenticeship`: the `train` jobs; `record`;
  `evaluate_policy`, `evaluate_reward`: the `eval` jobs; `demo`: the whole chain on the bundled data;
- `irl_methods`: the table of `train irl --method` (each method's configs, how it trains, a sweep's metric);
- `record_config`, `evaluate_policy_config`, `evaluate_reward_config`: those commands' settings, light
  like the learners' `algorithms/*_config.py` (their fields are the commands' flags);
- `sweep` (with `sweep_config`, `sweep_process`, `sweep_tune`, `sweep_trials`, `sweep_results`):
  `imitation sweep`, a hyperparameter search over a `train` command with Ray Tune;
- `distributed`: the processes of a data-parallel job under torchrun.

The data commands (`info`, `recover`, `convert`, `export`) are one call each into
`imitation.data` and need nothing of this layer.
"""
