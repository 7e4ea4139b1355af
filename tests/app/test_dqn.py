from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from torchrl_mbe.app.replay import SUCCESSOR_KEY, ReplayTransitions


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

    algo = compose_config(
        "algo.lr=0.01", "algo.lr_decay_frames=1000", "algo.lr_end_factor=0.1", "algo.learning_starts=100"
    ).algo
    assert [round(q_learning_rate(algo, frames), 6) for frames in (0, 100, 600, 1100, 5000)] == [
        0.01,
        0.01,
        0.0055,
        0.001,
        0.001,
    ]
    assert q_learning_rate(compose_config().algo, 10_000) == compose_config().algo.lr  # no decay by default


def build_agent(compose_config, *overrides):
    from torchrl_mbe.app.dqn import build_dqn_agent
    from torchrl_mbe.envs import make_env

    cfg = compose_config(*overrides)
    env = make_env("mountaincar", num_envs=4, seed=0)
    return cfg, env, build_dqn_agent(cfg, env)


def test_rnd_adds_its_intrinsic_reward_to_what_the_q_network_learns_and_its_predictor_learns(compose_config):
    from torchrl.collectors import Collector
    from torchrl.objectives import RNDLoss

    _, env, agent = build_agent(compose_config, "exploration=rnd", "exploration.intrinsic_coef=0.5")
    rnd = agent.explorer
    batch = next(iter(Collector(env, rnd.policy, frames_per_batch=64, total_frames=-1)))
    intrinsic = batch["next", "intrinsic_reward"]
    assert intrinsic.shape == batch["next", "reward"].shape and (intrinsic > 0).all()
    stored = ReplayTransitions(n_steps=1, gamma=0.99, intrinsic_coef=rnd.intrinsic_coef)(batch)
    assert torch.allclose(stored["next", "reward"], (batch["next", "reward"] + 0.5 * intrinsic).reshape(-1, 1))
    observations = stored.select(("next", "observation"))
    whole_batch_loss = RNDLoss(
        rnd.loss.predictor_network, rnd.loss.target_network, obs_rms=rnd.rnd.obs_rms, update_fraction=1.0
    )
    error = lambda: whole_batch_loss(observations)["loss_predictor"].item()
    before = error()
    for _ in range(100):
        rnd.after_q_update(observations)
    assert rnd.loss.obs_rms is rnd.rnd.obs_rms  # the loss normalizes as the transform does
    assert error() < 0.5 * before  # visited states become familiar: their intrinsic reward falls


def test_a_noisy_q_network_explores_by_its_noise_and_is_greedy_without_it(compose_config):
    from tensordict import TensorDict
    from torchrl.envs import ExplorationType, set_exploration_type

    from torchrl_mbe.app.dqn import update_q
    from torchrl_mbe.app.replay import make_replay_buffer

    cfg, env, agent = build_agent(compose_config, "exploration=noisy")
    assert agent.explorer.policy is agent.actor and agent.eps == 0.0  # no eps: the noise explores
    states = TensorDict({"observation": torch.randn(256, 2) * 0.3}, [256])
    act = lambda: agent.actor(states.clone())["action"].argmax(-1)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        greedy = act()
        assert torch.equal(greedy, act())
    buffer = make_replay_buffer(cfg.buffer, "cpu")
    rollout = env.rollout(64, break_when_any_done=False)
    buffer.extend(ReplayTransitions(1, 0.99)(rollout))
    noise_scale = lambda: next(p for name, p in agent.actor.named_parameters() if name.endswith("weight_sigma"))
    sigma = noise_scale().detach().clone()
    with set_exploration_type(ExplorationType.RANDOM):
        noisy = act()
        update_q(agent, buffer)  # resamples the noise
        resampled = act()
    assert not torch.equal(noisy, greedy) and not torch.equal(noisy, resampled)
    assert not torch.equal(sigma, noise_scale())  # the noise scale learns: the loss samples the noise


def test_compiled_updates_take_the_same_steps_as_eager_ones_and_are_traced_once(compose_config):
    from torchrl.envs.utils import RandomPolicy

    from torchrl_mbe.app.dqn import update_q
    from torchrl_mbe.app.replay import make_replay_buffer

    torch.manual_seed(0)
    cfg, env, eager = build_agent(compose_config, "algo.batch_size=32", "dynamics.batch_size=32")
    torch.manual_seed(0)
    _, _, compiled = build_agent(compose_config, "algo.batch_size=32", "dynamics.batch_size=32", "compile=true")
    buffer = make_replay_buffer(cfg.buffer, "cpu")
    buffer.extend(ReplayTransitions(1, 0.99)(env.rollout(64, RandomPolicy(env.action_spec), break_when_any_done=False)))
    for agent in (eager, compiled):
        agent.explorer.training.model.fit_normalization(buffer, next_observation_key=SUCCESSOR_KEY)
    graphs = []
    for step in range(3):
        torch.manual_seed(step)
        eager_losses = update_q(eager, buffer)["loss_q"], eager.explorer.training.update(buffer)
        torch.manual_seed(step)
        compiled_losses = update_q(compiled, buffer)["loss_q"], compiled.explorer.training.update(buffer)
        assert compiled_losses == pytest.approx(eager_losses, rel=1e-4)
        graphs.append(torch._dynamo.utils.counters["stats"]["unique_graphs"])
    assert graphs[0] > 0 and graphs[-1] == graphs[0]  # traced at the first step only
    assert compiled.q_step._loss_and_backward != compiled.q_step._eager_loss_and_backward  # still compiled
    for eager_p, compiled_p in zip(eager.q_loss.parameters(), compiled.q_loss.parameters()):
        torch.testing.assert_close(compiled_p, eager_p, rtol=1e-4, atol=1e-5)
