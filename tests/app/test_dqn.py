from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from torchrl_mbe.app.dqn import SUCCESSOR_KEY, ReplayTransitions


def trajectory(end: str) -> TensorDict:
    """5 steps of reward 1; the episode ends at step 2 by ``end`` ("terminated" or "truncated")."""
    flag = torch.zeros(5, 1, dtype=torch.bool)
    ended = flag.clone()
    ended[2] = True
    return TensorDict(
        {
            "observation": torch.arange(5.0).unsqueeze(-1),
            "action": torch.zeros(5, 1),
            "next": {
                "observation": torch.arange(1.0, 6.0).unsqueeze(-1),
                "reward": torch.ones(5, 1),
                "done": ended,
                "terminated": ended if end == "terminated" else flag,
                "truncated": ended if end == "truncated" else flag,
            },
        },
        [5],
    )


@pytest.mark.parametrize("end, bootstraps", [("terminated", False), ("truncated", True)])
def test_n_step_transitions_stop_at_the_episode_end_and_bootstrap_only_through_a_truncation(end, bootstraps):
    transitions = ReplayTransitions(n_steps=3, gamma=0.5)
    first = transitions(trajectory(end))
    second = transitions(trajectory(end))  # the held-back frames of the first batch come out now
    stored = torch.cat([first, second])
    assert stored["next", "reward"][:3].flatten().tolist() == [1.75, 1.5, 1.0]  # cut at step 2
    assert stored["steps_to_next_obs"][:3].flatten().tolist() == [3, 2, 1]
    assert stored["next", "observation"][:3].flatten().tolist() == [3.0, 3.0, 3.0]
    assert stored["next", "terminated"][:3].flatten().tolist() == [not bootstraps] * 3
    assert stored[SUCCESSOR_KEY][:3].flatten().tolist() == [1.0, 2.0, 3.0]  # the dynamics model's 1-step target
    assert set(stored.keys(True, True)) >= {"observation", "action", ("next", "reward"), "steps_to_next_obs"}
    assert "episode_reward" not in stored.keys() and ("next", "original_reward") not in stored.keys(True)


def test_learning_rate_decays_linearly_after_learning_starts_and_then_stays(compose_config):
    from torchrl_mbe.app.dqn import q_learning_rate

    algo = compose_config("algo.lr=0.01", "algo.lr_decay_frames=1000", "algo.lr_end_factor=0.1", "algo.learning_starts=100").algo
    assert [round(q_learning_rate(algo, frames), 6) for frames in (0, 100, 600, 1100, 5000)] == [0.01, 0.01, 0.0055, 0.001, 0.001]
    assert q_learning_rate(compose_config().algo, 10_000) == compose_config().algo.lr  # no decay by default
