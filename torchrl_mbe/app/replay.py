"""Replay for DQN: the buffer, and the transitions stored in it (n-step, through TorchRL)."""
from __future__ import annotations

from omegaconf import DictConfig
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, ReplayBuffer, TensorDictPrioritizedReplayBuffer, TensorDictReplayBuffer
from torchrl.envs import MultiStepTransform

__all__ = ["SUCCESSOR_KEY", "make_replay_buffer", "ReplayTransitions", "one_step_transitions"]

SUCCESSOR_KEY = "successor_observation"
"""The observation one step later, which the dynamics model learns (``("next", "observation")`` is n steps later)."""


def make_replay_buffer(buffer: DictConfig, device: str) -> ReplayBuffer:
    """Uniform ``TensorDictReplayBuffer`` or ``TensorDictPrioritizedReplayBuffer`` (TD-error priorities).

    ``compilable=True`` keeps the buffer's counters in plain tensors instead of
    multiprocessing values: the buffer never leaves this process, and a killed
    run then leaves no semaphores behind.
    """
    storage = LazyTensorStorage(buffer.size, device=device, compilable=True)
    if buffer.name == "prioritized":
        return TensorDictPrioritizedReplayBuffer(
            alpha=buffer.alpha, beta=buffer.beta, storage=storage, priority_key="td_error", compilable=True
        )
    return TensorDictReplayBuffer(storage=storage, compilable=True)


class ReplayTransitions:
    """Turns collected frames into the transitions the losses read, and nothing more.

    With ``n_steps > 1``, TorchRL's :class:`~torchrl.envs.MultiStepTransform` sums
    the next ``n`` discounted rewards, points ``("next", "observation")`` ``n`` steps
    ahead and writes ``steps_to_next_obs`` (the DQN target then discounts by
    ``gamma ** steps_to_next_obs``). A window never crosses an episode's end; the
    ``terminated`` flag is taken from the window's last step (left out of the
    transform's pass-through ``done_keys``), so a window that ends in a time-limit
    truncation bootstraps and one that ends in a termination does not. The
    transform holds back the last ``n`` frames of each env until the next batch.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_mbe.app.replay import ReplayTransitions
        >>> flag = lambda *bits: torch.tensor(bits, dtype=torch.bool).unsqueeze(-1)
        >>> frames = TensorDict({  # 5 steps; the episode terminates at step 2
        ...     "observation": torch.arange(5.0).unsqueeze(-1), "action": torch.zeros(5, 1),
        ...     "next": {"observation": torch.arange(1.0, 6.0).unsqueeze(-1), "reward": torch.ones(5, 1),
        ...              "done": flag(0, 0, 1, 0, 0), "terminated": flag(0, 0, 1, 0, 0), "truncated": flag(0, 0, 0, 0, 0)},
        ... }, [5])
        >>> stored = ReplayTransitions(n_steps=3, gamma=0.5)(frames)  # the last 3 frames wait for the next batch
        >>> stored["next", "reward"].flatten().tolist(), stored["steps_to_next_obs"].flatten().tolist()
        ([1.75, 1.5], [3, 2])
        >>> stored["next", "observation"].flatten().tolist(), stored["next", "terminated"].flatten().tolist()
        ([3.0, 3.0], [True, True])
    """

    KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"), ("next", "terminated"))

    def __init__(self, n_steps: int, gamma: float, *, intrinsic_coef: float | None = None) -> None:
        self.multistep = MultiStepTransform(n_steps, gamma, done_keys=["done", "truncated"]) if n_steps > 1 else None
        self.intrinsic_coef = intrinsic_coef

    def __call__(self, frames: TensorDictBase) -> TensorDictBase | None:
        """Transitions of ``frames`` (``(time,)`` or ``(envs, time)``) as a flat batch; ``None`` while held back.

        With ``intrinsic_coef``, the stored reward is ``reward + intrinsic_coef * ("next", "intrinsic_reward")``.
        """
        transitions = one_step_transitions(frames)
        if self.intrinsic_coef is not None:
            reward = frames.get(("next", "reward")) + self.intrinsic_coef * frames.get(("next", "intrinsic_reward"))
            transitions.set(("next", "reward"), reward)
        frames = transitions
        if self.multistep is not None:
            frames = self.multistep.inv(frames)
            if frames is None:
                return None
            frames = frames.exclude("gamma", "nonterminal", ("next", "original_reward"))
        return frames.reshape(-1)


def one_step_transitions(frames: TensorDictBase) -> TensorDictBase:
    """The keys the losses read from collected ``frames``, with the one-step successor the dynamics model learns."""
    transitions = frames.select(*ReplayTransitions.KEYS)
    return transitions.set(SUCCESSOR_KEY, transitions.get(("next", "observation")))
