"""What a checkpoint keeps of the collecting side, so that a resumed run continues where it stopped.

A torch-batched env (the registry's ``Task.torch_env``: MountainCar, CartPole,
Acrobot, DeepSea) holds its whole state in its ``state_dict`` (physics, step
counts, the generator of its start states); with the collector's carrier (the
current observations, step counts and running returns that the next step
starts from) a resumed run takes exactly the steps the uninterrupted one would
have taken. A gymnasium-backed env (LunarLander, or ``backend=gym``) cannot be
saved: a resumed run starts fresh episodes there, and its unfinished ones are
never logged.
"""

from __future__ import annotations

from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs import EnvBase

from torchrl_mbe.app.members import select_members
from torchrl_mbe.envs.gym_batch import GymBatchEnv
from torchrl_mbe.envs.registry import TASKS

__all__ = ["CollectorState", "EnvState", "saves_exactly"]

_CARRIER_OWN_KEYS = ("collector",)  # the collector's trajectory ids, renumbered by every collector


def saves_exactly(env: EnvBase) -> bool:
    """Whether ``env`` (as ``make_env`` wraps it) is one of the torch-batched envs whose state a checkpoint can hold."""
    torch_envs = tuple(task.torch_env for task in TASKS.values() if task.torch_env is not None)
    return isinstance(getattr(env, "base_env", env), torch_envs)


class EnvState:
    """An env's state for a checkpoint: all of a torch-batched env's, nothing of a gymnasium env's."""

    def __init__(self, env: EnvBase) -> None:
        self.env = env
        self.exact = saves_exactly(env)

    def state_dict(self) -> dict:
        return self.env.base_env.state_dict() if self.exact else {}

    def load_state_dict(self, state: dict) -> None:
        if self.exact:
            self.env.base_env.load_state_dict(state)

    def select_members(self, state: dict, index: list[int], num_members: int) -> dict:
        """A population env's state with only the members ``index``, for this env (built for ``len(index)`` members)."""
        return select_members(state, index, num_members, like=self.state_dict())


class CollectorState:
    """A collector's env and its carrier (the step the next batch starts from), for a torch-batched env.

    TorchRL's ``Collector.state_dict`` leaves the carrier out ("runtime env state
    is not generally serializable"); for the torch-batched envs it is, so this
    keeps it, apart from the collector's own trajectory ids. Within a process,
    :meth:`handover_state` holds a gymnasium batch's copies too, so that members
    leaving a population's batch cut no other member's episode.
    """

    def __init__(self, collector: Collector) -> None:
        self.collector = collector
        self.env = EnvState(collector.env)

    def state_dict(self) -> dict:
        if not self.env.exact:
            return {}
        return {"env": self.env.state_dict(), "carrier": self._carrier_state()}

    def handover_state(self) -> dict:
        """:meth:`state_dict`, or for a gymnasium batch its live copies and the carrier (for this process only: not saved)."""
        base_env = self.collector.env.base_env
        if self.env.exact or not isinstance(base_env, GymBatchEnv):
            return self.state_dict()
        return {"copies": base_env.copies(), "carrier": self._carrier_state()}

    def load_state_dict(self, state: dict) -> None:
        if "copies" in state:
            self.collector.env.base_env.adopt(state["copies"])
        elif self.env.exact:
            self.env.load_state_dict(state["env"])
        else:
            return
        carrier = self.collector._carrier
        carrier.update(TensorDict(state["carrier"], batch_size=carrier.batch_size, device=carrier.device))

    def select_members(self, state: dict, index: list[int], num_members: int) -> dict:
        """The env's (or copies') and the carrier's state of the members ``index`` only (the batch is ``(num_envs, M)``)."""
        if not state:
            return state
        carrier = select_members(state["carrier"], index, num_members, dim=1)
        if "copies" in state:
            copies = state["copies"]
            kept = [row + member for row in range(0, len(copies), num_members) for member in index]
            return {"copies": [copies[flat] for flat in kept], "carrier": carrier}
        return {"env": self.env.select_members(state["env"], index, num_members), "carrier": carrier}

    def _carrier_state(self) -> dict:
        # Private: the collector's carrier (the next step's input) is outside Collector.state_dict
        # (pytorch/rl#4230's review: step counters and simulator state are not restored).
        return self.collector._carrier.exclude(*_CARRIER_OWN_KEYS).to_dict()
