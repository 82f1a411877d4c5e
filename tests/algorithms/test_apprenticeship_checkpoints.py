"""An apprenticeship learner's checkpoint (imitation.algorithms.apprenticeship.Apprenticeship) in
process: a damaged one is refused as one line naming the learner, its iteration counter out of
range by name and bounds, and one written before the stop reasons were recorded resumes and
iterates on. On a two-state MDP, where each iteration takes milliseconds."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_apprenticeship_run import two_state_mdp

from imitation.algorithms.apprenticeship import Apprenticeship, ApprenticeshipConfig, TabularSolver
from imitation.checkpoints import snapshot
from imitation.errors import ImitationError

ITERATIONS = 4


def learner() -> Apprenticeship:
    """μ_E = (1, 2): neither converged nor stalled in its 4 iterations (α = 2/3, then 0)."""
    config = ApprenticeshipConfig(iterations=ITERATIONS, tolerance=0.0)
    return Apprenticeship(TabularSolver(two_state_mdp(3), 1.0), np.array([1.0, 2.0]), config)


def checkpoint_after(steps: int) -> tuple[dict[str, torch.Tensor], dict]:
    first = learner()
    for _ in range(steps):
        first.step()
    return snapshot(*first.state_dict())


@pytest.mark.parametrize(
    ("name", "damaged"),
    [
        ("mus", torch.zeros((2, 2), dtype=torch.float64)),
        ("lambdas", torch.full((4,), 0.25, dtype=torch.float64)),
        ("mu_bar", torch.zeros(3, dtype=torch.float64)),
    ],
    ids=["mus", "lambdas", "mu_bar"],
)
def test_a_tensor_of_the_wrong_size_is_refused_naming_the_learner(name: str, damaged: torch.Tensor) -> None:
    """After 2 iterations the checkpoint holds μ^(0..2) (3 × 2), λ (3) and μ̄ (2): any other
    count of values fails the load, which names the run it does not fit."""
    tensors, state = checkpoint_after(2)
    with pytest.raises(ImitationError, match=r"^the checkpoint does not fit this apprenticeship learning run \(ValueError: "):
        learner().load_state_dict((tensors | {name: damaged}, state))


@pytest.mark.parametrize("iteration", [0, ITERATIONS + 2])
def test_an_iteration_counter_out_of_range_is_refused_by_name_and_bounds(iteration: int) -> None:
    """The next iteration lies in 1..iterations + 1 (the last: a run that ran them all)."""
    tensors, state = checkpoint_after(2)
    message = f"^the checkpoint's next iteration is {iteration}, outside 1..{ITERATIONS + 1} for this run"
    with pytest.raises(ImitationError, match=message):
        learner().load_state_dict((tensors, state | {"iteration": iteration}))


def test_the_last_iterations_checkpoint_loads_as_done() -> None:
    tensors, state = checkpoint_after(ITERATIONS)
    assert state["iteration"] == ITERATIONS + 1
    resumed = learner()
    resumed.load_state_dict((tensors, state))
    assert resumed.iterations == ITERATIONS and resumed.done and not (resumed.converged or resumed.stalled)


def test_a_checkpoint_without_stop_reasons_resumes_and_iterates_on() -> None:
    """A checkpoint written before `converged` and `stalled` were recorded: the run stopped for
    neither, so the resumed one takes the iterations left, as the uninterrupted one did."""
    whole = learner()
    rows = [whole.step() for _ in range(ITERATIONS)]
    tensors, state = checkpoint_after(2)
    older = {key: value for key, value in state.items() if key not in ("converged", "stalled")}
    resumed = learner()
    resumed.load_state_dict((tensors, older))
    assert (resumed.iterations, resumed.converged, resumed.stalled, resumed.done) == (2, False, False, False)
    tail = [resumed.step() for _ in range(ITERATIONS - 2)]
    assert tail == rows[2:] and resumed.done
    np.testing.assert_array_equal(resumed.lambdas, whole.lambdas)
    np.testing.assert_array_equal(resumed.mu_bar, whole.mu_bar)
