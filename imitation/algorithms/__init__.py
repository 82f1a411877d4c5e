"""Learning algorithms, each module stating its equations and citing docs/THEORY.md:

- imitation from demos and experts: `bc` (behavioural cloning), `dagger` (DAgger; `ray_dagger` plays its
  rounds on Ray workers);
- inverse RL: `maxent_irl` (tabular MaxEnt and MCE IRL), `gcl` (guided cost learning), `adversarial` with
  `gail` and `airl` (the discriminator on PPO's loop), `apprenticeship` (feature matching, the projection
  method);
- reinforcement learning: `ppo` (the bundled PPO trainer; `ray_rollouts` collects its rollouts on Ray
  actors), `policy_gradient` (REINFORCE, with a baseline, actor-critic), `policy_search` (hill climbing, the
  cross-entropy method, CMA-ES);
- shared by several: `advantages` (GAE: PPO, policy gradient), `beside_ppo` (the loop GCL, GAIL and AIRL
  run beside PPO).

Each learner's settings live in `<module>_config.py` beside it, light (no torch), because their fields
are the command line's flags (imitation/flags.py) and `--help` reads them.
"""
