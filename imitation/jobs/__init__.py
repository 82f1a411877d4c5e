"""What runs a job: the command line calls exactly one function of this package per command.

- `loop`: the one training loop (checkpoints, resume, deferred Ctrl-C, logging, progress);
- `presets`: per-environment settings in one table;
- `run_config`: the typed config.json of a run directory;
- `run_directory`: what every training job does around its learner;
- `bc`, `dagger`, `ppo`, `irl`: the `train` jobs; `record`; `evaluate_policy`, `evaluate_reward`:
  the `eval` jobs; `demo`: the whole chain on the bundled data.

The data commands (`info`, `recover`, `convert`, `export`) are one call each into
`imitation.data` and need nothing of this layer.
"""
