"""BatchedDeepSeaEnv against bsuite's DeepSea.

bsuite is not a dependency (it pulls pandas, plotnine, scipy and scikit-image), so
:class:`BsuiteDeepSea` below transcribes the deterministic rules of
``DeepSea._step``, ``_reset`` and ``_get_observation`` from
``bsuite/environments/deep_sea.py`` (google-deepmind/bsuite, commit
6d8f64997ca256473c3d10be021431facc5a14d7, the same file as in the bsuite 0.3.6 release).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from torchrl_mbe.envs import Episode, first_episodes, make_env, reached_goal
from torchrl_mbe.envs.deepsea import BatchedDeepSeaEnv


class BsuiteDeepSea:
    """bsuite's ``DeepSea(size, deterministic=True, mapping_seed=...)``, transcribed line by line."""

    def __init__(self, size: int, mapping_seed: int, unscaled_move_cost: float = 0.01) -> None:
        self._size = size
        self._unscaled_move_cost = unscaled_move_cost
        self._action_mapping = np.random.RandomState(mapping_seed).binomial(1, 0.5, [size, size])
        self._row = 0
        self._column = 0

    def observation(self) -> np.ndarray:
        obs = np.zeros(shape=(self._size, self._size), dtype=np.float32)
        if self._row >= self._size:
            return obs
        obs[self._row, self._column] = 1.0
        return obs

    def step(self, action: int) -> tuple[float, np.ndarray, bool]:
        reward = 0.0
        action_right = action == self._action_mapping[self._row, self._column]
        if self._column == self._size - 1 and action_right:
            reward += 1.0
        if action_right:
            self._column = np.clip(self._column + 1, 0, self._size - 1)
            reward -= self._unscaled_move_cost / self._size
        else:
            self._column = np.clip(self._column - 1, 0, self._size - 1)
        self._row += 1
        return reward, self.observation(), self._row == self._size


def _always_right(mapping: np.ndarray, row: int, column: int, step: int) -> int:
    return int(mapping[row, column])


def _always_left(mapping: np.ndarray, row: int, column: int, step: int) -> int:
    return 1 - int(mapping[row, column])


PATHS = {
    "always right": _always_right,
    "always left": _always_left,
    "action 0": lambda mapping, row, column, step: 0,
    "action 1": lambda mapping, row, column, step: 1,
    "right then left": lambda mapping, row, column, step: (
        _always_right(mapping, row, column, step) if step < 2 else _always_left(mapping, row, column, step)
    ),
    "right but the last": lambda mapping, row, column, step: (
        _always_right(mapping, row, column, step)
        if row < len(mapping) - 1
        else _always_left(mapping, row, column, step)
    ),
    "random": lambda mapping, row, column, step: int(np.random.RandomState(step).randint(2)),
}


def _bsuite_paths(size: int, mapping_seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Actions, rewards, observations and terminations of every path of :data:`PATHS` in the transcription."""
    actions, rewards, observations, terminated = [], [], [], []
    for path in PATHS.values():
        env = BsuiteDeepSea(size, mapping_seed)
        steps = []
        for step in range(size):
            action = path(env._action_mapping, env._row, env._column, step)
            steps.append((action, *env.step(action)))
        path_actions, path_rewards, path_observations, path_terminated = zip(*steps)
        actions.append(path_actions)
        rewards.append(path_rewards)
        observations.append(np.stack(path_observations).reshape(size, -1))
        terminated.append(path_terminated)
    return np.array(actions), np.array(rewards), np.stack(observations), np.array(terminated)


def _play(env: BatchedDeepSeaEnv, actions: torch.Tensor):
    """Steps ``env`` from a reset through ``actions`` of shape ``(num_envs, steps)``; the stacked step outputs."""
    td = env.reset()
    steps = []
    for action in actions.unbind(1):
        td["action"] = torch.nn.functional.one_hot(action, 2)
        td = env.step(td)
        steps.append(td["next"].clone())
        td = td["next"]
    return torch.stack(steps, 1)


@pytest.mark.parametrize("size, mapping_seed", [(1, 0), (2, 3), (5, 42), (10, 42), (12, 7)])
def test_steps_match_bsuite_on_hand_picked_paths_one_path_per_sub_env(size, mapping_seed):
    actions, rewards, observations, terminated = _bsuite_paths(size, mapping_seed)
    env = BatchedDeepSeaEnv(len(PATHS), size=size, mapping_seed=mapping_seed)
    steps = _play(env, torch.from_numpy(actions))
    torch.testing.assert_close(steps["reward"].squeeze(-1), torch.from_numpy(rewards).float())
    torch.testing.assert_close(steps["observation"], torch.from_numpy(observations))
    assert steps["terminated"].squeeze(-1).tolist() == terminated.tolist()
    assert steps["done"].squeeze(-1).tolist() == terminated.tolist() and not steps["truncated"].any()


def test_the_mapping_is_bsuites_reproducible_and_differs_between_seeds():
    mapping = BatchedDeepSeaEnv(1, size=20, mapping_seed=42).action_mapping
    assert mapping.tolist() == np.random.RandomState(42).binomial(1, 0.5, [20, 20]).tolist()
    assert torch.equal(mapping, BatchedDeepSeaEnv(3, size=20, mapping_seed=42, seed=1).action_mapping)
    assert not torch.equal(mapping, BatchedDeepSeaEnv(1, size=20, mapping_seed=43).action_mapping)
    assert torch.equal(
        BatchedDeepSeaEnv(1, size=4, randomize_actions=False).action_mapping, torch.ones(4, 4, dtype=torch.int64)
    )


def test_envs_seeded_differently_play_the_same_mdp():
    """``make_env`` seeds the train and evaluation envs differently: the mapping must not follow."""
    train, evaluation = make_env("deepsea", num_envs=2, seed=0), make_env("deepsea", num_envs=3, seed=10_000)
    assert torch.equal(train.base_env.action_mapping, evaluation.base_env.action_mapping)


def _always_right_policy(env: BatchedDeepSeaEnv):
    def policy(td):
        return td.set("action", torch.nn.functional.one_hot(env.action_mapping[env.row, env.column], 2))

    return policy


@pytest.mark.parametrize("size", [10, 20])
def test_the_always_correct_path_finds_the_treasure_and_returns_0_99(size):
    env = make_env("deepsea", num_envs=4, seed=0, size=size)
    rollout = env.rollout(3 * size, _always_right_policy(env.base_env))
    assert rollout.shape == (4, size)  # episode length N, then done
    assert rollout["next", "step_count"][:, -1].squeeze(-1).tolist() == [size] * 4
    torch.testing.assert_close(rollout["next", "episode_reward"][:, -1].squeeze(-1), torch.full((4,), 0.99))
    torch.testing.assert_close(rollout["next", "reward"][:, -1].squeeze(-1), torch.full((4,), 1 - 0.01 / size))
    cells = rollout["observation"].argmax(-1)  # the diagonal: row r, column r
    assert cells.tolist() == [[row * size + row for row in range(size)]] * 4
    assert all(reached_goal("DeepSea", episode) for episode in first_episodes(rollout))


def test_the_all_left_path_returns_0_without_the_treasure():
    env = make_env("deepsea", num_envs=2, seed=0, size=10)
    left = lambda td: td.set(
        "action", torch.nn.functional.one_hot(1 - env.base_env.action_mapping[env.base_env.row, env.base_env.column], 2)
    )
    rollout = env.rollout(100, left)
    assert rollout.shape == (2, 10)
    assert rollout["next", "reward"].abs().sum() == 0
    assert rollout["observation"].argmax(-1).tolist() == [[row * 10 for row in range(10)]] * 2  # column 0
    assert not any(reached_goal("DeepSea", episode) for episode in first_episodes(rollout))


def test_the_goal_rule_is_the_treasure():
    assert reached_goal("DeepSea", Episode(0.99, 10, terminated=True, final_reward=0.999))
    assert not reached_goal("DeepSea", Episode(-0.009, 10, terminated=True, final_reward=-0.001))
    assert not reached_goal("DeepSea", Episode(-0.01, 10, terminated=True, final_reward=0.0))


def test_sub_envs_reset_independently_and_finished_ones_stay_put():
    env = BatchedDeepSeaEnv(3, size=4, randomize_actions=False)  # action 1 moves right everywhere
    td = env.reset()
    for _ in range(2):
        td = env.step(td.set("action", torch.nn.functional.one_hot(torch.ones(3, dtype=torch.int64), 2)))["next"]
    td = env.reset(td.set("_reset", torch.tensor([[False], [True], [False]])))
    assert env.row.tolist() == [2, 0, 2] and env.column.tolist() == [2, 0, 2]
    assert td["observation"].argmax(-1).tolist() == [10, 0, 10]
    for _ in range(2):
        td = env.step(td.set("action", torch.nn.functional.one_hot(torch.ones(3, dtype=torch.int64), 2)))["next"]
    assert td["terminated"].squeeze(-1).tolist() == [True, False, True]
    rewards = []
    for _ in range(2):  # the finished copies are stepped again, as rollout(break_when_all_done=True) does
        td = env.step(td.set("action", torch.nn.functional.one_hot(torch.ones(3, dtype=torch.int64), 2)))["next"]
        rewards.append(td["reward"].squeeze(-1).tolist())
    assert env.row.tolist() == [4, 4, 4] and env.column.tolist() == [3, 3, 3]
    assert rewards == [[0.0, pytest.approx(-0.01 / 4), 0.0], [0.0, pytest.approx(1 - 0.01 / 4), 0.0]]
    assert td["observation"].sum() == 0 and td["terminated"].all()


def test_the_stochastic_variant_fails_right_moves_with_probability_one_over_n_and_is_seeded():
    size, num_envs = 10, 1000
    env = BatchedDeepSeaEnv(num_envs, size=size, deterministic=False, randomize_actions=False, seed=0)
    right = torch.ones(num_envs, size, dtype=torch.int64)
    steps = _play(env, right)
    last_row_cells = steps["observation"][:, size - 2].argmax(-1)  # after N - 1 steps: row N - 1
    at_treasure = (last_row_cells == size * size - 1).float().mean().item()  # N - 1 right moves all succeeded
    success = (1 - 1 / size) ** (size - 1)  # bsuite's optimal_no_cost
    assert abs(at_treasure - success) < 5 * (success * (1 - success) / num_envs) ** 0.5
    torch.testing.assert_close(steps["reward"][:, :-1], torch.full((num_envs, size - 1, 1), -0.01 / size))  # no noise
    assert steps["reward"][:, -1].std() > 0.5  # N(0, 1) noise in the last row's end cells
    torch.testing.assert_close(
        _play(BatchedDeepSeaEnv(num_envs, size=size, deterministic=False, randomize_actions=False, seed=0), right),
        steps,
    )


@pytest.mark.parametrize("deterministic", [True, False])
def test_specs(deterministic):
    check_env_specs(BatchedDeepSeaEnv(3, size=5, deterministic=deterministic, seed=0))
    check_env_specs(make_env("deepsea", seed=0, size=5))


@pytest.mark.parametrize("size", [0, -3, 2.5, "10", True, None])
def test_a_bad_size_gets_one_clear_error(size):
    with pytest.raises(
        ValueError, match=r"DeepSea's size must be an integer >= 1 \(bsuite's sweep: 10, 12, ..., 50\), got"
    ) as error:
        make_env("deepsea", num_envs=16, seed=0, size=size)
    assert "\n" not in str(error.value)


def test_make_env_errors_name_what_is_accepted():
    with pytest.raises(ValueError, match="DeepSea has no gymnasium version; it runs with backend='torch' only"):
        make_env("deepsea", backend="gym")
    with pytest.raises(ValueError, match=r"CartPole-v1 does not take the keyword arguments \{'size': 10\}"):
        make_env("cartpole", backend="gym", size=10)
    with pytest.raises(
        ValueError, match=r"Unknown environment 'deep-sea': expected a gymnasium id .*deepsea \(DeepSea\)"
    ):
        make_env("deep-sea")


@pytest.mark.parametrize("size", [1, 5, 12])
def test_the_oracle_predicts_every_step_the_env_takes_from_every_cell(size):
    from torchrl_mbe.envs.deepsea import DeepSeaDynamics

    env = BatchedDeepSeaEnv(64, size=size, seed=0)
    oracle = DeepSeaDynamics(env.action_spec, size=size)
    td = env.reset()
    for _ in range(size):  # random paths through the grid: both actions from the cells they reach, then the null row
        td["action"] = env.action_spec.rand()
        predicted = oracle(td.clone())["predicted_observation"]
        td = env.step(td)
        assert torch.equal(predicted, td["next", "observation"])
        td = td["next"]
