"""The optimisation engine both fits run: Adam steps on one candidate, its stop rules, the
snapshot of its best parameters, and the race between candidates.

A candidate is an :class:`Objective` (what one step's loss is, and which modules hold its
parameters) and an optimiser. :class:`Optimisation` steps it, in parts if asked (a trial, then
the rest), and keeps the modules' state at the lowest L_I seen (the image term, the one loss
that says how well the frames are explained, whatever the other terms weigh). :func:`race` runs
every candidate for a trial's share of the steps and lets the leader go on.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

import torch

from sfb_video.errors import DivergenceError, PoseError
from sfb_video.model.shape import ShapeParams

StepCallback = Callable[[int, dict[str, float]], None]
"""Called with (step, loss terms) after every step of a fit."""

DIVERGED = "the fit diverged from its first step (non-finite loss); check the input images"


@dataclass(frozen=True)
class Step:
    """One evaluation of an objective.

    Attributes:
        total: () the weighted loss to minimise.
        record: the loss terms as floats (``image`` among them) and ``total``.
        kept: what the best snapshot keeps beside the parameters (a render, per-frame terms).
    """

    total: torch.Tensor
    record: dict[str, float]
    kept: Any = None


class Objective(Protocol):
    """The loss of one candidate: evaluated at ``progress``, the fraction of its steps done."""

    modules: tuple[torch.nn.Module, ...]
    """The modules whose parameters are fitted; the best snapshot holds their state dicts."""

    def __call__(self, progress: float) -> Step: ...


@dataclass(frozen=True)
class Snapshot:
    """A candidate at its lowest L_I: its modules' state dicts, the step's record and kept value."""

    states: tuple[dict[str, torch.Tensor], ...]
    record: dict[str, float]
    kept: Any


def read_terms(terms: dict[str, torch.Tensor]) -> dict[str, float]:
    """``terms``' () tensors as floats, read from the device at once: one host sync a step, not
    one a term (each ``float()`` of a GPU tensor waits for the device)."""
    if not terms:
        return {}
    values = torch.stack([v.detach().reshape(()).to(torch.float64) for v in terms.values()]).tolist()
    return dict(zip(terms, values, strict=True))


def weighted_sum(terms: dict[str, torch.Tensor], weights: dict[str, float]) -> torch.Tensor:
    """sum_k weights[k] * terms[k] over the terms with a non-zero weight, in ``terms``' order
    (a zero-weight term is not even multiplied: a NaN there must not poison the total)."""
    total = torch.zeros((), device=next(iter(terms.values())).device)
    for key, value in terms.items():
        if weights[key] != 0:
            total = total + weights[key] * value
    return total


class Optimisation:
    """Adam (or any optimiser) on one candidate, run in parts, keeping its best parameters.

    Args:
        objective: the candidate's loss.
        optimiser: over the objective's parameters.
        iterations: the steps the candidate runs at most; ``progress`` is step / iterations.
        patience, tolerance: with ``patience``, stop once L_I has not fallen by ``tolerance``
            (relative) for that many steps in a row (a warm start's plateau); None runs on.
    """

    def __init__(
        self,
        objective: Objective,
        optimiser: torch.optim.Optimizer,
        iterations: int,
        patience: int | None = None,
        tolerance: float = 0.0,
    ) -> None:
        self.objective, self.optimiser, self.iterations = objective, optimiser, iterations
        self.patience, self.tolerance = patience, tolerance
        self.best: Snapshot | None = None
        self.curve: list[dict[str, float]] = []
        self.step, self.since_improved, self.done = 0, 0, False

    @property
    def best_image_loss(self) -> float:
        """The lowest L_I seen (inf before the first finite step)."""
        return float("inf") if self.best is None else self.best.record["image"]

    def run(self, steps: int, on_step: StepCallback | None = None) -> None:
        """Run up to ``steps`` more steps: fewer at the end of its iterations, on a plateau, on a
        non-finite loss or a step that moved the mesh behind the camera (the best parameters so
        far are kept: such a step would only spoil them) or when nothing is left to optimise. A
        stopped candidate stays stopped."""
        for _ in range(min(steps, self.iterations - self.step)):
            if self.done:
                return
            self.optimiser.zero_grad(set_to_none=True)
            try:
                step = self.objective(self.step / self.iterations)
            except PoseError:
                # Adam moved the path through the camera (a shaped start brought near it on
                # circle_fast.avi): the candidate has diverged, as on a NaN.
                self.done = True
                return
            record = step.record
            if not math.isfinite(record["total"]):  # the record holds the total, read already
                self.done = True
                return
            self.curve.append(record)
            if on_step is not None:
                on_step(self.step, record)
            if record["image"] < self.best_image_loss * (1 - self.tolerance):
                self.since_improved = 0
            else:
                self.since_improved += 1
            if record["image"] < self.best_image_loss:
                modules = self.objective.modules
                states = tuple({k: v.detach().clone() for k, v in m.state_dict().items()} for m in modules)
                self.best = Snapshot(states, record, step.kept)
            if self.patience is not None and self.since_improved >= self.patience:
                self.done = True
                return
            if not step.total.requires_grad:  # every weight that touches a parameter is 0 now
                self.done = True
                return
            step.total.backward()
            self.optimiser.step()
            self.step += 1

    def restore(self) -> Snapshot:
        """Load the best parameters back into the modules and return their snapshot.

        Raises:
            DivergenceError: when no step was finite.
        """
        if self.best is None:
            raise DivergenceError(DIVERGED)
        for module, state in zip(self.objective.modules, self.best.states, strict=True):
            module.load_state_dict(state)
        return self.best


def race(
    candidates: dict[str, Optimisation], trial_steps: int | None, on_step: StepCallback | None = None
) -> tuple[str, dict[str, float]]:
    """Run the candidates and return the winner's key and each candidate's L_I after its trial.

    With ``trial_steps``, every candidate runs that many steps, then only the one with the lowest
    L_I goes on to its end; without (None), every candidate runs to its end. The winner is the
    lowest L_I seen, among the candidates that had a finite step.

    Raises:
        DivergenceError: when no candidate had a finite step.
    """
    trials: dict[str, float] = {}
    if trial_steps is not None:
        for key, fit in candidates.items():
            fit.run(trial_steps, on_step)
            trials[key] = fit.best_image_loss
        leader = min(candidates, key=lambda k: candidates[k].best_image_loss)
        candidates[leader].run(candidates[leader].iterations, on_step)
    else:
        for fit in candidates.values():
            fit.run(fit.iterations, on_step)
    fitted = [k for k, fit in candidates.items() if fit.best is not None]
    if not fitted:
        raise DivergenceError(DIVERGED)
    return min(fitted, key=lambda k: candidates[k].best_image_loss), trials


def seed_texture(shape: ShapeParams, texture: torch.Tensor) -> None:
    """Start ``shape``'s learnt texture at ``texture`` (3, Ht, Wt) in [0, 1] (its logits; kept
    off 0 and 1, where the logit is infinite)."""
    with torch.no_grad():
        shape.texture_logits.copy_(torch.logit(texture.to(shape.texture_logits).clamp(1e-4, 1 - 1e-4)))


@contextmanager
def seeded(seed: int) -> Iterator[None]:
    """Torch's random numbers seeded with ``seed`` inside, the caller's random state restored
    after: a fit is reproducible without changing what the caller draws next."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        yield


@contextmanager
def deterministic(device: torch.device) -> Iterator[None]:
    """Serial CPU kernels while fitting, restoring the caller's setting after.

    The backward of every gather is index_put_ with accumulation, which torch runs on several
    threads with atomic float adds, in whatever order the threads get there: on a busy machine
    the same fit came out different in the fourth decimal. The deterministic kernels cost no
    measurable time here. CUDA is left alone (some of its kernels would only warn).
    """
    if device.type != "cpu":
        yield
        return
    previous = torch.are_deterministic_algorithms_enabled()
    warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(previous, warn_only=warn_only)
