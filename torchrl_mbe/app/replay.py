"""Replay for DQN: the buffer, and the transitions stored in it (n-step, through TorchRL)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import ClassVar

import torch
from omegaconf import DictConfig
from tensordict import TensorDict, TensorDictBase
from torchrl._torchrl import MinSegmentTreeFp32, SumSegmentTreeFp32  # private: see ReplayState
from torchrl.data import LazyTensorStorage, ReplayBuffer, TensorDictPrioritizedReplayBuffer, TensorDictReplayBuffer
from torchrl.envs import MultiStepTransform

from torchrl_mbe.app.members import select_members
from torchrl_mbe.app.settings import ConfigError
from torchrl_mbe.rundir import CHECKPOINT

__all__ = [
    "SUCCESSOR_KEY",
    "SUCCESSOR_TERMINATED_KEY",
    "PopulationReplayBuffer",
    "ReplayState",
    "ReplayTransitions",
    "check_replay_fits",
    "flatten_frames",
    "make_replay_buffer",
    "one_step_transitions",
]

SUCCESSOR_KEY = "successor_observation"
"""The observation one step later, which the dynamics model learns (``("next", "observation")`` is n steps later)."""
SUCCESSOR_TERMINATED_KEY = "successor_terminated"
"""Whether the observation one step later ended the episode (the value of novelty stops there)."""


OBSERVATIONS_PER_TRANSITION = 3  # the observation, the one n steps on, and the one-step successor (SUCCESSOR_KEY)


def check_replay_fits(buffer: DictConfig, observation_size: int, population: int, device: str, run_dir: Path) -> None:
    """Refuses, in one line, a replay buffer whose observations (``observation_size`` features, for each of the
    ``population`` runs) exceed the CPU memory available now,
    or whose checkpoints would not fit on ``run_dir``'s disk.

    TorchRL's ``LazyTensorStorage`` allocates its whole capacity at the first
    ``extend`` and a checkpoint keeps all of it (DeepSea at N=50: 3 GB at the
    default size), so such a run would be killed after its first batch, or fail at
    its first checkpoint. A checkpoint is written beside the previous one, so a run
    that has none yet needs room for two.
    """
    needed = OBSERVATIONS_PER_TRANSITION * 4 * observation_size * buffer.size * population
    kept = f"{population} x {buffer.size:,}" if population > 1 else f"{buffer.size:,}"
    transitions = f"buffer.size={buffer.size}: {kept} transitions of {observation_size:,}-feature observations take about {needed / 2**30:.1f} GiB"
    available = _available_memory_bytes() if torch.device(device).type == "cpu" else None
    if available is not None and needed > available:
        raise ConfigError(
            f"{transitions}, more than the {available / 2**30:.1f} GiB available; lower buffer.size (or population)."
        )
    on_disk = needed if (run_dir / CHECKPOINT).exists() else 2 * needed
    free = _free_disk_bytes(run_dir)
    if on_disk > free:
        raise ConfigError(
            f"{transitions}, and every checkpoint keeps them: writing one needs {on_disk / 2**30:.1f} GiB, "
            f"more than the {free / 2**30:.1f} GiB free for {run_dir}; free disk space or lower buffer.size (or population)."
        )


def _free_disk_bytes(path: Path) -> int:
    """Free bytes on the disk that holds ``path`` (its nearest existing parent, before the run creates it)."""
    while not path.exists():
        path = path.parent
    return shutil.disk_usage(path).free


def _available_memory_bytes() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` in bytes; ``None`` where there is no such file."""
    try:
        with open("/proc/meminfo") as meminfo:
            line = next(line for line in meminfo if line.startswith("MemAvailable:"))
    except (OSError, StopIteration):
        return None
    return int(line.split()[1]) * 1024


def make_replay_buffer(
    buffer: DictConfig, device: str, num_members: int | None = None
) -> ReplayBuffer | PopulationReplayBuffer:
    """Uniform ``TensorDictReplayBuffer`` or ``TensorDictPrioritizedReplayBuffer`` (TD-error priorities);
    with ``num_members``, a population's :class:`PopulationReplayBuffer` (uniform, each member its own samples).

    ``compilable=True`` keeps the buffer's counters in plain tensors instead of
    multiprocessing values: the buffer never leaves this process, and a killed
    run then leaves no semaphores behind.
    """
    if num_members is not None:
        return PopulationReplayBuffer(buffer.size, num_members, device=device)
    storage = LazyTensorStorage(buffer.size, device=device, compilable=True)
    if buffer.name == "prioritized":
        return TensorDictPrioritizedReplayBuffer(
            alpha=buffer.alpha, beta=buffer.beta, storage=storage, priority_key="td_error", compilable=True
        )
    return TensorDictReplayBuffer(storage=storage, compilable=True)


class ReplayState:
    """A replay buffer's state for a checkpoint, in tensors and plain containers only (it loads with ``weights_only``).

    TorchRL's ``state_dict`` of a prioritized buffer holds its segment trees as
    C++ objects, which ``torch.load(weights_only=True)`` refuses and TorchRL offers no
    tensor form of (pytorch/rl#3056); they are kept here as the tensors of their leaves
    and rebuilt on load from its private ``torchrl._torchrl`` classes.

    Examples:
        >>> import torch
        >>> from omegaconf import OmegaConf
        >>> from tensordict import TensorDict
        >>> from torchrl_mbe.app.replay import ReplayState, make_replay_buffer
        >>> config = OmegaConf.create({"name": "prioritized", "size": 8, "alpha": 0.6, "beta": 0.4})
        >>> buffer, copy = make_replay_buffer(config, "cpu"), make_replay_buffer(config, "cpu")
        >>> indices = buffer.extend(TensorDict({"x": torch.arange(4.0)}, [4]))
        >>> buffer.update_priority(torch.arange(4), torch.tensor([1.0, 2.0, 3.0, 4.0]))
        >>> ReplayState(copy).load_state_dict(ReplayState(buffer).state_dict())
        >>> torch.equal(copy[:4]["x"], buffer[:4]["x"]), copy.sampler._sum_tree.query(0, 8) == buffer.sampler._sum_tree.query(0, 8)
        (True, True)
    """

    _TREES: ClassVar[dict[str, type]] = {"_sum_tree": SumSegmentTreeFp32, "_min_tree": MinSegmentTreeFp32}

    def __init__(self, buffer: ReplayBuffer | PopulationReplayBuffer) -> None:
        self.buffer = buffer

    def state_dict(self) -> dict:
        state = self.buffer.state_dict()
        sampler = state.get("_sampler", {})  # a PopulationReplayBuffer's state is tensors already
        for name in self._TREES.keys() & sampler.keys():
            sampler[name] = sampler[name][torch.arange(sampler[name].size)]
        return state

    def load_state_dict(self, state: dict) -> None:
        sampler = state.get("_sampler", {})
        for name in self._TREES.keys() & sampler.keys():
            leaves = sampler[name]
            tree = self._TREES[name](len(leaves))
            tree[torch.arange(len(leaves))] = leaves
            sampler[name] = tree
        self.buffer.load_state_dict(state)

    @staticmethod
    def select_members(state: dict, index: list[int], num_members: int) -> dict:
        """A population buffer's state with only the members ``index`` (storage columns, ``[capacity, M]``)."""
        return select_members(state, index, num_members, dim=1)


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

    KEYS = (
        "observation",
        "action",
        ("next", "observation"),
        ("next", "reward"),
        ("next", "done"),
        ("next", "terminated"),
    )

    def __init__(
        self,
        n_steps: int,
        gamma: float,
        *,
        intrinsic_coef: float | None = None,
        num_members: int | None = None,
        extra_keys: tuple = (),
    ) -> None:
        self.multistep = MultiStepTransform(n_steps, gamma, done_keys=["done", "truncated"]) if n_steps > 1 else None
        self.intrinsic_coef = intrinsic_coef
        self.num_members = num_members
        self.extra_keys = tuple(extra_keys)

    def __call__(self, frames: TensorDictBase) -> TensorDictBase | None:
        """Transitions of ``frames`` (``(time,)`` or ``(envs, time)``) as a flat batch; ``None`` while held back.

        With ``num_members``, ``frames`` are a population's ``(envs, M, time)`` and the
        batch is ``(envs * time, M)``, each member's transitions in its own column.
        With ``intrinsic_coef``, the stored reward is ``reward + intrinsic_coef * ("next", "intrinsic_reward")``;
        ``extra_keys`` are stored too (an explorer's: Bootstrapped DQN's mask).
        """
        transitions = one_step_transitions(frames, self.extra_keys)
        if self.intrinsic_coef is not None:
            reward = frames.get(("next", "reward")) + self.intrinsic_coef * frames.get(("next", "intrinsic_reward"))
            transitions.set(("next", "reward"), reward)
        frames = transitions
        if self.multistep is not None:
            frames = self.multistep.inv(frames)
            if frames is None:
                return None
            frames = frames.exclude("gamma", "nonterminal", ("next", "original_reward"))
        return flatten_frames(frames, self.num_members)

    def state_dict(self) -> dict:
        """The frames held back for the next batch's n-step windows (none with ``n_steps=1``)."""
        # Private: MultiStepTransform keeps the frames held back for the next batch's windows outside its
        # state_dict (no public accessor; no upstream issue filed yet).
        held_back = self.multistep._buffer if self.multistep is not None else None
        if held_back is None:
            return {"held_back": None}
        return {"held_back": held_back.to_dict(), "batch_size": list(held_back.batch_size)}

    def load_state_dict(self, state: dict) -> None:
        if state["held_back"] is not None:
            self.multistep._buffer = TensorDict(state["held_back"], batch_size=state["batch_size"])

    @staticmethod
    def select_members(state: dict, index: list[int], num_members: int) -> dict:
        """The held-back frames of the members ``index`` only (``(envs, M, n)``: the member is dimension 1)."""
        if state["held_back"] is None:
            return state
        num_envs, _, held = state["batch_size"]
        return {
            "held_back": select_members(state["held_back"], index, num_members, dim=1),
            "batch_size": [num_envs, len(index), held],
        }


def flatten_frames(frames: TensorDictBase, num_members: int | None = None) -> TensorDictBase:
    """Collected ``(time,)`` or ``(envs, time)`` frames as ``(frames,)``; a population's ``(envs, M, time)`` as ``(frames, M)``."""
    if num_members is None:
        return frames.reshape(-1)
    return frames.transpose(-2, -1).contiguous().reshape(-1, num_members)


def one_step_transitions(frames: TensorDictBase, extra_keys: tuple = ()) -> TensorDictBase:
    """The keys the losses read from collected ``frames`` (and ``extra_keys``), with the one-step successor the dynamics model learns and whether it ended the episode."""
    transitions = frames.select(*ReplayTransitions.KEYS, *extra_keys)
    transitions.set(SUCCESSOR_TERMINATED_KEY, transitions.get(("next", "terminated")))
    return transitions.set(SUCCESSOR_KEY, transitions.get(("next", "observation")))


class PopulationReplayBuffer:
    """A ring buffer of ``[capacity, M]`` transitions in which every member draws its own indices.

    :meth:`extend` writes ``N`` rows of all members at once (a batch ``[N, M]``,
    or ``[*N, M]``, flattened); :meth:`sample` draws a ``[batch_size, M]`` index
    tensor from torch's generator (of the storage's device) in one call and takes
    member ``m``'s column ``m`` of it from member ``m``'s storage only, so a member's
    sample depends on its own transitions and the generator's state, never on another
    member's data. TorchRL's ``TensorDictReplayBuffer`` over the same storage would
    draw one index per row shared by every member (or, with ``ndim=2``, indices over
    all ``capacity * M`` transitions, mixing members).

    The storage is a TensorDict allocated at the first :meth:`extend`, with that
    batch's entries. The sample carries its indices under ``"index"``, as TorchRL's
    buffers do.

    Args:
        capacity (int): rows kept; the oldest are overwritten first.
        num_members (int): the population size ``M``.

    Keyword Args:
        device (torch.device or str): where the storage lives. Defaults to ``"cpu"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_mbe.app.replay import PopulationReplayBuffer
        >>> buffer = PopulationReplayBuffer(capacity=4, num_members=3)
        >>> _ = buffer.extend(TensorDict(reward=torch.arange(18.0).view(6, 3, 1), batch_size=[6, 3]))
        >>> len(buffer), buffer.state_dict()["storage"]["reward"][:, 0, 0].tolist()  # rows 4, 5 overwrote 0, 1
        (4, [12.0, 15.0, 6.0, 9.0])
        >>> sample = buffer.sample(8)
        >>> sample.batch_size, sample["index"].shape
        (torch.Size([8, 3]), torch.Size([8, 3]))
    """

    def __init__(self, capacity: int, num_members: int, *, device: torch.device | str = "cpu") -> None:
        if capacity < 1 or num_members < 1:
            raise ValueError(f"capacity and num_members must be positive, got {capacity} and {num_members}.")
        self.capacity = capacity
        self.num_members = num_members
        self.device = torch.device(device)
        self._storage: TensorDictBase | None = None
        self._cursor = 0
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def __getitem__(self, rows: slice) -> TensorDictBase:
        """Stored rows of every member (storage order, ``[rows, M]``): ``buffer[: len(buffer)]`` reads them all, as for TorchRL's buffers."""
        if self._storage is None:
            raise RuntimeError("PopulationReplayBuffer is empty.")
        return self._storage[: self._size][rows]

    def extend(self, data: TensorDictBase) -> torch.Tensor:
        """Writes ``data`` (batch ``[*N, M]``) after the newest rows, overwriting the oldest; returns the rows written."""
        if data.batch_size[-1:] != (self.num_members,):
            raise ValueError(f"extend expects a batch [*N, {self.num_members}], got {list(data.batch_size)}.")
        data = data.reshape(-1, self.num_members)
        num_rows = data.shape[0]
        # The rows a write of one row after another would leave: the last `capacity` of them.
        rows = ((self._cursor + torch.arange(num_rows, device=self.device)) % self.capacity)[-self.capacity :]
        data = data[-self.capacity :].to(self.device)
        if self._storage is None:
            self._storage = data.apply(
                lambda entry: entry.new_zeros((self.capacity, *entry.shape[1:])),
                batch_size=[self.capacity, self.num_members],
            )
        self._storage[rows] = data
        self._cursor = (self._cursor + num_rows) % self.capacity
        self._size = min(self._size + num_rows, self.capacity)
        return rows

    def sample(self, batch_size: int) -> TensorDictBase:
        """``batch_size`` transitions per member, drawn uniformly (with replacement) and independently per member: ``[batch_size, M]``."""
        if self._size == 0:
            raise RuntimeError("cannot sample from an empty PopulationReplayBuffer.")
        index = torch.randint(self._size, (batch_size, self.num_members), device=self.device)
        # Row r of member m is entry r * M + m of the flattened storage: index_select on it is
        # 2-3x faster on a CPU than indexing the storage with [index, members] (measured at M = 20, 100).
        flat_index = (index * self.num_members + torch.arange(self.num_members, device=self.device)).reshape(-1)
        sample = self._storage.reshape(-1).apply(
            lambda entry: entry.index_select(0, flat_index).view(batch_size, self.num_members, *entry.shape[1:]),
            batch_size=[batch_size, self.num_members],
        )
        sample.set("index", index)
        return sample

    def state_dict(self) -> dict:
        """The storage as nested dicts of tensors and the ring's position, loadable with ``torch.load(weights_only=True)``."""
        storage = None if self._storage is None else self._storage.to_dict()
        return {"storage": storage, "cursor": self._cursor, "size": self._size}

    def load_state_dict(self, state: dict) -> None:
        storage = state["storage"]
        self._storage = (
            None
            if storage is None
            else TensorDict(storage, batch_size=[self.capacity, self.num_members], device=self.device)
        )
        self._cursor, self._size = state["cursor"], state["size"]
