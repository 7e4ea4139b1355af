"""Exact resume: a torch env's ``state_dict`` loaded into a fresh env makes it go on exactly as the saved one."""

from __future__ import annotations

import copy
import io
from collections.abc import Callable

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from torchrl_mbe import make_env
from torchrl_mbe.envs import BatchedAcrobotEnv, BatchedCartPoleEnv, BatchedDeepSeaEnv, BatchedMountainCarEnv

NUM_ENVS = 6
ENVS: dict[str, Callable[..., EnvBase]] = {
    # Short time limits, random pushes and DeepSea's 8-step episodes: copies restart often, at different times.
    "mountaincar": lambda seed, **kwargs: BatchedMountainCarEnv(NUM_ENVS, max_episode_steps=25, seed=seed, **kwargs),
    "cartpole": lambda seed, **kwargs: BatchedCartPoleEnv(NUM_ENVS, seed=seed, **kwargs),
    "acrobot": lambda seed, **kwargs: BatchedAcrobotEnv(NUM_ENVS, max_episode_steps=25, seed=seed, **kwargs),
    # The stochastic variant draws from the generator at every step, not only at resets.
    "deepsea": lambda seed, **kwargs: BatchedDeepSeaEnv(NUM_ENVS, size=8, deterministic=False, seed=seed, **kwargs),
}
STATE_KEYS = {
    "mountaincar": {"physical_state", "elapsed_steps", "_extra_state"},
    "cartpole": {"physical_state", "elapsed_steps", "_extra_state"},
    "acrobot": {"physical_state", "elapsed_steps", "_extra_state"},
    "deepsea": {"row", "column", "_extra_state"},
}
COMPARED = [
    "observation",
    ("next", "observation"),
    ("next", "reward"),
    ("next", "done"),
    ("next", "terminated"),
    ("next", "truncated"),
]
MAKE_ENV_KWARGS = {  # what a config passes through make_env: time limits short enough for restarts
    "mountaincar": {"max_episode_steps": 50},
    "cartpole": {},
    "acrobot": {"max_episode_steps": 50},
    "deepsea": {"size": 8, "deterministic": False},
}
WRAPPER_ENTRIES = ["step_count", "is_init", ("next", "episode_reward")]


def advance(env: EnvBase, td: TensorDictBase, steps: int, seed: int) -> tuple[TensorDictBase, TensorDictBase]:
    """``steps`` seeded random actions, done copies reset as a collector resets them: the transitions and the carry."""
    generator = torch.Generator().manual_seed(seed)
    num_actions = env.action_spec.shape[-1]
    transitions = []
    for _ in range(steps):
        action = torch.randint(num_actions, env.batch_size, generator=generator)
        transition, td = env.step_and_maybe_reset(td.set("action", torch.nn.functional.one_hot(action, num_actions)))
        transitions.append(transition.clone())
    return torch.stack(transitions, -1), td


def mid_episode(env: EnvBase) -> TensorDictBase:
    """The carry after 30 random steps, with three copies restarted by hand at step 5 (besides the natural restarts)."""
    _, td = advance(env, env.reset(), 5, seed=1)
    td = env.reset(td.set("_reset", torch.tensor([True, False, True, False, True, False]).unsqueeze(-1)))
    _, td = advance(env, td, 25, seed=2)
    return td


def through_bytes(state: dict, map_location: str | None = None) -> dict:
    """``state`` as a checkpoint file gives it back (``torch.load`` with ``weights_only``)."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, map_location=map_location, weights_only=True)


def assert_same_transitions(first: TensorDictBase, second: TensorDictBase, keys: list) -> None:
    for key in keys:
        assert torch.equal(first[key], second[key]), key


@pytest.mark.parametrize("name", ENVS)
def test_a_loaded_env_goes_on_exactly_as_the_saved_one(name):
    env = ENVS[name](seed=0)
    td = mid_episode(env)
    position = env.elapsed_steps if name != "deepsea" else env.row
    assert len(position.unique()) > 1, "the copies are at different points of their episodes"
    saved = through_bytes(env.state_dict())
    assert set(saved) == STATE_KEYS[name]

    resumed = ENVS[name](seed=1)
    resumed.load_state_dict(saved)
    expected, _ = advance(env, td.clone(), 60, seed=3)
    got, _ = advance(resumed, td.clone(), 60, seed=3)
    assert expected["next", "done"].squeeze(-1).any(-1).all(), "every copy restarts within the 60 steps"
    assert_same_transitions(expected, got, COMPARED)
    assert torch.equal(env.reset()["observation"], resumed.reset()["observation"])


@pytest.mark.parametrize("name", ENVS)
def test_the_generator_is_part_of_the_state(name):
    """Without the generator's state, the same buffers give other restarts (so the test above can fail)."""
    env = ENVS[name](seed=0)
    td = mid_episode(env)
    buffers_only = {key: value.clone() for key, value in env.state_dict().items() if key != "_extra_state"}
    other = ENVS[name](seed=1)
    other.load_state_dict(buffers_only, strict=False)
    expected, _ = advance(env, td.clone(), 60, seed=3)
    got, _ = advance(other, td.clone(), 60, seed=3)
    assert not torch.equal(expected["next", "observation"], got["next", "observation"])


def test_a_state_dict_is_a_snapshot_only_once_copied_and_fits_only_its_batch_size():
    env = ENVS["cartpole"](seed=0)
    td = mid_episode(env)
    live, snapshot = env.state_dict(), copy.deepcopy(env.state_dict())
    advance(env, td, 1, seed=3)
    assert torch.equal(live["physical_state"], env.physical_state)  # the live buffers, stepped on
    assert not torch.equal(snapshot["physical_state"], env.physical_state)
    with pytest.raises(RuntimeError, match="size mismatch for physical_state"):
        BatchedCartPoleEnv(NUM_ENVS + 1, seed=0).load_state_dict(snapshot)


@pytest.mark.parametrize("name", ENVS)
def test_the_apps_wrapped_env_resumes_from_its_base_envs_state_and_the_carried_tensordict(name):
    env = make_env(name, num_envs=4, seed=0, **MAKE_ENV_KWARGS[name])
    _, td = advance(env, env.reset(), 40, seed=1)
    assert env.state_dict() == {}, "a TransformedEnv's state_dict holds its transforms' state only"
    saved = through_bytes(env.base_env.state_dict())

    resumed = make_env(name, num_envs=4, seed=1, **MAKE_ENV_KWARGS[name])
    resumed.base_env.load_state_dict(saved)
    expected, _ = advance(env, td.clone(), 60, seed=2)
    got, _ = advance(resumed, td.clone(), 60, seed=2)
    assert expected["next", "done"].squeeze(-1).any(-1).all(), "every copy restarts within the 60 steps"
    assert_same_transitions(expected, got, COMPARED + WRAPPER_ENTRIES)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("name", ["mountaincar", "cartpole", "acrobot"])
def test_a_checkpoint_loaded_onto_cuda_resumes_a_cuda_env(name):
    env = ENVS[name](seed=0)
    mid_episode(env)
    saved = through_bytes(env.state_dict(), map_location="cuda")  # the generator's state too lands on the GPU
    resumed = ENVS[name](seed=1, device="cuda")
    resumed.load_state_dict(saved)
    assert resumed.physical_state.device.type == "cuda"
    assert torch.equal(resumed.physical_state.cpu(), env.physical_state)
    assert torch.equal(resumed.elapsed_steps.cpu(), env.elapsed_steps)
    assert torch.equal(resumed.reset()["observation"].cpu(), env.reset()["observation"])  # start states: CPU draws
