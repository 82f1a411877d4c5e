"""Learning algorithms: BC, DAgger, MaxEnt IRL and the bundled PPO trainer."""
