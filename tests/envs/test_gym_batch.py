"""GymBatchEnv plays the episodes TorchRL's own SerialEnv of GymEnv copies plays, for any batch shape."""

from __future__ import annotations

from functools import partial

import pytest
import torch
from torchrl.envs import GymEnv, SerialEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs

from torchrl_mbe.envs import GymBatchEnv
from torchrl_mbe.envs.make import dqn_transforms


def serial_gym_envs(env_id: str, batch_shape: tuple[int, ...]) -> SerialEnv:
    """``GymEnv`` copies in nested ``SerialEnv``\\ s, one level per dimension of ``batch_shape``."""
    make = partial(GymEnv, env_id)
    for size in reversed(batch_shape):
        make = partial(SerialEnv, size, make)
    return make()


def seeded(base_env, seed: int = 5) -> TransformedEnv:
    env = TransformedEnv(base_env, dqn_transforms())  # as make_env wraps its envs
    env.set_seed(seed)
    return env


def random_actions(env, seed: int = 1):
    """A policy of uniform random one-hot actions from its own generator, so that two envs get the same actions."""
    generator = torch.Generator().manual_seed(seed)
    num_actions = env.action_spec.space.n

    def policy(tensordict):
        index = torch.randint(num_actions, tensordict.batch_size, generator=generator)
        return tensordict.set("action", torch.nn.functional.one_hot(index, num_actions))

    return policy


@pytest.mark.parametrize(
    "env_id", ["LunarLander-v3", "CartPole-v1", "FrozenLake-v1"]
)  # FrozenLake: one-hot observations
@pytest.mark.parametrize("batch_shape", [(3,), (2, 3)], ids=str)
def test_steps_and_partial_resets_equal_a_serial_env_of_gym_envs(env_id, batch_shape):
    reference, env = seeded(serial_gym_envs(env_id, batch_shape)), seeded(GymBatchEnv(env_id, batch_shape))
    expected = reference.rollout(300, random_actions(reference), break_when_any_done=False)  # done copies reset alone
    played = env.rollout(300, random_actions(env), break_when_any_done=False)
    assert expected["next", "done"].sum() >= 2 * len(
        expected["next", "done"].reshape(-1, 300)
    )  # several episodes a copy
    assert set(played.keys(True, True)) == set(expected.keys(True, True))
    for key in expected.keys(True, True):
        assert torch.equal(played[key], expected[key]), key


def test_finished_copies_wait_while_the_others_play_their_first_episodes():
    # A (2, 3) batch seeded as six SerialEnv workers, which pause finished copies the same way.
    reference, env = (
        seeded(SerialEnv(6, partial(GymEnv, "LunarLander-v3"))),
        seeded(GymBatchEnv("LunarLander-v3", (2, 3))),
    )
    for _ in range(2):  # and the next rollout starts fresh episodes from where each copy's generator stands
        expected = reference.rollout(
            2000, random_actions(reference), break_when_any_done=False, break_when_all_done=True
        )
        played = env.rollout(2000, random_actions(env), break_when_any_done=False, break_when_all_done=True)
        assert played.shape[:2] == (2, 3)
        ends = expected["next", "done"].squeeze(-1).int().argmax(-1)
        assert len(set(ends.tolist())) > 1  # copies finish at different steps
        for key in ("observation", ("next", "reward"), ("next", "done"), "episode_reward"):
            assert torch.equal(played[key].reshape(expected[key].shape), expected[key]), key


def test_specs_are_gym_envs_expanded_to_the_batch():
    env = GymBatchEnv("MountainCar-v0", (2, 4))
    reference = GymEnv("MountainCar-v0")
    for spec in ("full_observation_spec", "full_action_spec", "full_reward_spec", "full_done_spec"):
        assert getattr(env, spec) == getattr(reference, spec).expand(2, 4).to("cpu"), spec
    check_env_specs(seeded(env))
