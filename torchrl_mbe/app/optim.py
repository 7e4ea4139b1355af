"""Optimization steps shared by the algorithms: fused Adam and one gradient step of a loss."""

from __future__ import annotations

import logging
from collections.abc import Iterable

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from torchrl.objectives import HardUpdate, LossModule, SoftUpdate, TargetNetUpdater

__all__ = [
    "GradientStep",
    "UpdateSchedule",
    "adam",
    "clip_grad_norm_per_member_",
    "load_target_state",
    "make_target_updater",
    "target_state",
]

log = logging.getLogger(__name__)


def adam(parameters, lr: float) -> torch.optim.Adam:
    """Adam with its fused kernel (one kernel for every parameter, on CPU and CUDA), over the trainable ``parameters``.

    Parameters that do not require a gradient (a frozen randomized prior) are
    left out. The same update as the default per-parameter loop (up to floating-point
    rounding, so a seed's trajectory differs), in one kernel call instead of a
    few per parameter.
    """
    return torch.optim.Adam([parameter for parameter in parameters if parameter.requires_grad], lr=lr, fused=True)


def make_target_updater(algo: DictConfig, loss: LossModule) -> TargetNetUpdater:
    """TorchRL's ``HardUpdate`` (copy every ``algo.hard_update_interval`` updates) or ``SoftUpdate`` (Polyak) of a loss's target network."""
    if algo.target_update == "hard":
        return HardUpdate(loss, value_network_update_interval=algo.hard_update_interval)
    return SoftUpdate(loss, tau=algo.soft_update_tau)


def target_state(loss: LossModule, updater: TargetNetUpdater) -> dict:
    """A loss's target network and its updater's counter (a ``HardUpdate``'s; ``None`` for ``SoftUpdate``), for a checkpoint."""
    return {
        "target_network": loss.target_value_network_params.data.clone().to_dict(),
        "target_updater_counter": getattr(updater, "counter", None),
    }


def load_target_state(loss: LossModule, updater: TargetNetUpdater, state: dict) -> None:
    """Restores :func:`target_state`."""
    loss.target_value_network_params.data.update_(state["target_network"])
    if state["target_updater_counter"] is not None:
        updater.counter = state["target_updater_counter"]


class UpdateSchedule:
    """The gradient updates collected frames pay for: ``updates_per_frame`` a frame once ``learning_starts`` frames are in.

    The Q-network and the dynamics model each keep one; fractions of an update carry
    over as credit, and both counters travel in checkpoints (:meth:`state_dict`).

    Examples:
        >>> from torchrl_mbe.app.optim import UpdateSchedule
        >>> schedule = UpdateSchedule(learning_starts=100, updates_per_frame=0.25)
        >>> list(schedule.due(frames=64, new_frames=64)), list(schedule.due(frames=128, new_frames=64))
        ([], [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15])
        >>> list(schedule.due(frames=134, new_frames=6)), schedule.credit  # one and a half updates
        ([16], 0.5)
    """

    def __init__(self, learning_starts: int, updates_per_frame: float) -> None:
        self.learning_starts, self.updates_per_frame = learning_starts, updates_per_frame
        self.updates, self.credit = 0, 0.0

    def due(self, frames: int, new_frames: int):
        """Yields the index of each update that ``new_frames`` more frames pay for (``frames`` collected in all); 0 is the first ever.

        The update counter advances as each one is taken (after the caller's loop body).
        """
        if frames < self.learning_starts:
            return
        self.credit += new_frames * self.updates_per_frame
        while self.credit >= 1:
            yield self.updates
            self.updates += 1
            self.credit -= 1

    def state_dict(self) -> dict:
        return {"updates": self.updates, "credit": self.credit}

    def load_state_dict(self, state: dict) -> None:
        self.updates, self.credit = state["updates"], state["credit"]


class GradientStep:
    """One gradient step of a loss: loss and backward (compiled with ``compile=True``), clipping, optimizer step.

    With ``compile``, ``torch.compile`` traces the loss and its backward on the
    first call (seconds on a CPU) and then runs that graph; if compilation fails,
    a warning says so and the step runs eagerly from then on. Clipping and the
    optimizer step stay eager (they break graphs).

    A population's step (``num_members``) takes ``loss(batch) -> [M]``, one loss per
    member, back-propagates their sum and clips each member's gradient on its own
    (:func:`clip_grad_norm_per_member_`): members
    never share a norm, and Adam's update is elementwise. An ensemble's heads are
    members too (``M * K`` of them for a population of ensembles): with
    ``heads_per_member`` the step reports each agent's mean over its ``K`` heads.

    Args:
        loss (callable): ``loss(batch) -> scalar tensor`` (``[M]`` with ``num_members``).
        optimizer (torch.optim.Optimizer): steps the parameters the loss depends on.
        max_grad_norm (float, optional): clips the gradient norm of each parameter group (of each member's).

    Keyword Args:
        compile (bool): compile the loss and backward. Defaults to ``False``.
        num_members (int, optional): the population size, whose parameters are stacked ``[M, ...]``.
        heads_per_member (int, optional): report the mean loss of each run of this many consecutive
            members (an ensemble's ``K`` heads): one value for one ensemble, ``M`` for a population's.
    """

    def __init__(
        self,
        loss,
        optimizer: torch.optim.Optimizer,
        max_grad_norm: float | None,
        *,
        compile: bool = False,
        num_members: int | None = None,
        heads_per_member: int | None = None,
    ) -> None:
        self.loss = loss
        self.heads_per_member = heads_per_member
        self.optimizer = optimizer
        self.max_grad_norm = max_grad_norm
        self.num_members = num_members
        self._loss_and_backward = (
            torch.compile(self._eager_loss_and_backward) if compile else self._eager_loss_and_backward
        )

    def __call__(self, batch: TensorDictBase) -> float | list[float]:
        """Takes the step on ``batch`` and returns the loss before it (each member's with ``num_members``, each ensemble's mean)."""
        self.optimizer.zero_grad(set_to_none=True)
        loss = self._compiled_or_eager(batch)
        if self.max_grad_norm is not None:
            for group in self.optimizer.param_groups:
                self._clip(group["params"])
        self.optimizer.step()
        if self.heads_per_member is not None:
            loss = loss.unflatten(0, (-1, self.heads_per_member)).mean(-1).squeeze(0)  # one ensemble's: a scalar
        return loss.tolist()

    def _clip(self, parameters: list[torch.Tensor]) -> None:
        if self.num_members is None:
            torch.nn.utils.clip_grad_norm_(parameters, self.max_grad_norm)
        else:
            clip_grad_norm_per_member_(parameters, self.max_grad_norm, self.num_members)

    def _eager_loss_and_backward(self, batch: TensorDictBase) -> torch.Tensor:
        loss = self.loss(batch)
        loss.sum().backward()
        return loss.detach()

    def _compiled_or_eager(self, batch: TensorDictBase) -> torch.Tensor:
        if self._loss_and_backward == self._eager_loss_and_backward:
            return self._loss_and_backward(batch)
        try:
            return self._loss_and_backward(batch)
        except torch._dynamo.exc.TorchDynamoException as error:  # the compiler, not the loss, failed
            log.warning("torch.compile failed (%s); this update runs eagerly from now on.", type(error).__name__)
            self._loss_and_backward = self._eager_loss_and_backward
            self.optimizer.zero_grad(set_to_none=True)
            return self._loss_and_backward(batch)


def clip_grad_norm_per_member_(parameters: Iterable[torch.Tensor], max_norm: float, num_members: int) -> torch.Tensor:
    """Clips each member's gradient norm to ``max_norm``, as ``torch.nn.utils.clip_grad_norm_`` clips one network's.

    Member ``m``'s norm is taken over its slice ``p.grad[m]`` of every parameter
    ``p`` (stacked ``[M, ...]``), and only its slices are scaled, by
    ``min(1, max_norm / (norm + 1e-6))``: one member's gradient never changes
    another's. Parameters without a gradient are skipped.

    Args:
        parameters (iterable of tensors): stacked parameters, each ``[num_members, ...]``.
        max_norm (float): the largest norm a member's gradient keeps.
        num_members (int): the population size ``M``.

    Returns:
        each member's norm before clipping, ``[M]``.

    Raises:
        ValueError: a parameter's leading dimension is not ``num_members`` (a parameter
            shared by the members, which per-member clipping cannot split).

    Examples:
        >>> import torch
        >>> from torchrl_mbe.app.optim import clip_grad_norm_per_member_
        >>> weight = torch.zeros(2, 3, requires_grad=True)
        >>> weight.grad = torch.tensor([[3.0, 4.0, 0.0], [0.3, 0.4, 0.0]])
        >>> clip_grad_norm_per_member_([weight], max_norm=1.0, num_members=2)
        tensor([5.0000, 0.5000])
        >>> weight.grad.norm(dim=1)
        tensor([1.0000, 0.5000])
    """
    parameters = list(parameters)
    for parameter in parameters:
        if parameter.ndim == 0 or parameter.shape[0] != num_members:
            raise ValueError(
                f"clip_grad_norm_per_member_ needs parameters stacked over {num_members} members, got one of shape {tuple(parameter.shape)}."
            )
    grads = [parameter.grad for parameter in parameters if parameter.grad is not None]
    if not grads:
        return torch.zeros(num_members)
    slice_norms = [torch.linalg.vector_norm(grad.reshape(num_members, -1), dim=1) for grad in grads]
    member_norms = torch.linalg.vector_norm(torch.stack(slice_norms), dim=0)
    scale = (max_norm / (member_norms + 1e-6)).clamp(max=1.0)
    for grad in grads:
        grad.mul_(scale.view(num_members, *(1,) * (grad.ndim - 1)))
    return member_norms
