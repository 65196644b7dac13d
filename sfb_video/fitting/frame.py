"""Shape from Blur's test-time optimisation of one blurred frame (paper, Sec. 3.2).

For each prototype, Adam minimises L = w_I L_I + w_S L_S (or w_D L_D) + w_T L_T + w_L L_L over
vertex offsets, texture and motion; the parameters with the lowest L_I seen are kept. Several
prototypes all run for the first ``prototype_trial`` of the steps, then only the one with the
lowest L_I goes on. A warm start (the video pipeline's next
frame) starts from a previous result and stops early on a plateau.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch

from sfb_video.config import FitConfig, RenderConfig
from sfb_video.crop import Crop
from sfb_video.errors import SfbError
from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model import losses
from sfb_video.model.formation import exposure_times
from sfb_video.model.motion import Motion, MotionParams, Streak, streak_from_mask
from sfb_video.model.scene import ObjectState
from sfb_video.model.shape import ShapeParams
from sfb_video.render import MeshRenderer

StepCallback = Callable[[int, dict[str, float]], None]


class NoObjectError(SfbError):
    """The frame shows nothing that differs from the background."""


@dataclass(frozen=True)
class FitResult:
    """The outcome of fitting one frame.

    Attributes:
        prototype: name of the winning prototype.
        state: the recovered mesh, texture and motion (camera coordinates, object sizes).
        reconstruction: (3, h, w) I_hat in the crop.
        losses: the loss terms at the kept parameters.
        curves: per prototype, the loss terms at every step.
        iterations: steps run for the winning prototype.
        seconds: wall time of the whole fit.
    """

    prototype: str
    state: ObjectState
    reconstruction: torch.Tensor
    losses: dict[str, float]
    curves: dict[str, list[dict[str, float]]]
    iterations: int
    seconds: float


@dataclass(frozen=True)
class WarmStart:
    """Where a warm-started fit begins: a previous frame's shape and texture, a predicted motion."""

    prototype: str
    vertices: torch.Tensor
    texture: torch.Tensor
    motion: Motion


def _joint_loss(
    crop: Crop,
    shape: ShapeParams,
    motion: MotionParams,
    renderer: MeshRenderer,
    taus: torch.Tensor,
    masks: torch.Tensor | None,
    config: FitConfig,
    progress: float,
) -> tuple[torch.Tensor, dict[str, float], torch.Tensor]:
    """The weighted loss at ``progress``, the fraction of the fit's iterations done (L_D fades)."""
    rotations, positions = motion(taus)
    vertices, texture = shape.vertices(), shape.texture()
    posed = pose_vertices(vertices, rotations, positions)
    rendered, alpha = renderer.blurred(posed, shape.topology, texture, crop.background)
    terms = {
        "image": losses.image_loss(crop.image, rendered, crop.object_mask),
        "texture": losses.texture_tv(texture),
        "laplacian": losses.laplacian(vertices, shape.topology.edges),
    }
    weights = {"image": config.w_image, "texture": config.w_texture, "laplacian": config.w_laplacian}
    if masks is not None:
        terms["silhouette"] = losses.silhouette_loss(masks, alpha)
        weights["silhouette"] = config.w_silhouette
    else:
        terms["difference"] = losses.difference_loss(crop.object_mask, alpha)
        weights["difference"] = config.w_difference * max(0.0, 1 - progress / config.difference_fade)
    total = sum(weights[k] * v for k, v in terms.items() if weights[k] != 0)
    record = {k: float(v.detach()) for k, v in terms.items()}
    record["total"] = float(total.detach())
    return total, record, rendered


class Optimisation:
    """Adam on one candidate's shape and motion, run in parts (a trial, then the rest), keeping
    the parameters at the lowest L_I seen; a warm start stops early on a plateau."""

    def __init__(
        self,
        crop: Crop,
        shape: ShapeParams,
        motion: MotionParams,
        iterations: int,
        early_stop: bool,
        masks: torch.Tensor | None,
        config: FitConfig,
        render_config: RenderConfig,
    ) -> None:
        self.crop, self.shape, self.motion, self.masks, self.config = crop, shape, motion, masks, config
        self.iterations, self.early_stop = iterations, early_stop
        self.renderer = MeshRenderer(crop.camera, render_config)
        self.taus = exposure_times(render_config.time_steps, crop.image.device)
        rotation = (motion.quat0, motion.omega_raw)
        trained = [p for p in (*shape.parameters(), *motion.parameters()) if p.requires_grad]
        groups = [
            {"params": [p for p in trained if all(p is not r for r in rotation)]},
            {"params": [p for p in trained if any(p is r for r in rotation)], "lr": config.lr_rotation},
        ]
        # fused: one kernel per step instead of a dozen small operations per parameter.
        self.optimiser = torch.optim.Adam(groups, lr=config.lr, fused=True)
        self.best: tuple[dict, dict] | None = None  # state dicts of shape and motion
        self.best_record: dict[str, float] = {"image": float("inf")}
        self.best_render: torch.Tensor | None = None
        self.curve: list[dict[str, float]] = []
        self.step, self.since_improved, self.done = 0, 0, False

    def run(self, steps: int, on_step: StepCallback | None) -> None:
        """Run up to ``steps`` more steps (fewer at the end, on a plateau or a non-finite loss)."""
        config = self.config
        for _ in range(min(steps, self.iterations - self.step)):
            if self.done:
                return
            self.optimiser.zero_grad(set_to_none=True)
            total, record, rendered = _joint_loss(
                self.crop,
                self.shape,
                self.motion,
                self.renderer,
                self.taus,
                self.masks,
                config,
                self.step / self.iterations,
            )
            if not torch.isfinite(total):
                self.done = True  # keep the best parameters seen; a NaN step would only spoil them
                return
            self.curve.append(record)
            if on_step is not None:
                on_step(self.step, record)
            if record["image"] < self.best_record["image"] * (1 - config.plateau_tolerance):
                self.since_improved = 0
            else:
                self.since_improved += 1
            if record["image"] < self.best_record["image"]:
                self.best_record, self.best_render = record, rendered.detach()
                modules = (self.shape, self.motion)
                self.best = tuple({k: v.detach().clone() for k, v in m.state_dict().items()} for m in modules)
            if self.early_stop and self.since_improved >= config.plateau_patience:
                self.done = True
                return
            total.backward()
            self.optimiser.step()
            self.step += 1


def planned_steps(config: FitConfig, prototypes: int) -> int:
    """The steps a cold fit of ``prototypes`` prototypes runs at most (for progress bars)."""
    if prototypes > 1 and config.prototype_trial < 1:
        return (prototypes - 1) * max(1, round(config.prototype_trial * config.iterations)) + config.iterations
    return prototypes * config.iterations


def _oriented(streak: Streak, motion: Motion, crop: Crop) -> Streak:
    """``streak`` with its start at the end nearer where ``motion`` starts in the crop."""
    start_uv = crop.camera.project(motion.x0.to(streak.start))[0]
    if float((streak.end - start_uv).norm()) < float((streak.start - start_uv).norm()):
        return Streak(streak.end, streak.start, streak.diameter)
    return streak


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


def _check_crop(crop: Crop) -> None:
    if not bool(torch.isfinite(crop.image).all() and torch.isfinite(crop.background).all()):
        raise SfbError("image or background contains NaN or infinite values")
    if float(crop.object_mask.sum()) == 0:
        raise NoObjectError("no object: the image does not differ from the background in the object box")


def fit_frame(
    crop: Crop,
    config: FitConfig,
    render_config: RenderConfig,
    warm: WarmStart | None = None,
    masks: torch.Tensor | None = None,
    on_step: StepCallback | None = None,
) -> FitResult:
    """Fit the textured mesh and motion that explain one blurred crop.

    Args:
        crop: the frame's working crop (image, background, camera, object mask).
        config: iterations, learning rate, loss weights, prototypes.
        render_config: time steps and soft-silhouette sharpness.
        warm: start from here (one prototype, ``warm_iterations``, early stop) instead of cold.
        masks: (N, h, w) sub-frame masks in time order for L_S; without them L_D is used. L_S
            makes the fit run in their order, so orient them to agree with ``warm``.
        on_step: called with (step, loss terms) after every step.

    Raises:
        NoObjectError: when the crop shows no difference from the background.
    """
    _check_crop(crop)
    if masks is not None and (masks.shape[1:] != crop.image.shape[1:] or render_config.time_steps % masks.shape[0]):
        raise SfbError(
            f"masks of shape {tuple(masks.shape)} do not fit a {tuple(crop.image.shape[1:])} crop "
            f"with {render_config.time_steps} time steps (need (N, h, w) with N dividing them)"
        )
    torch.manual_seed(config.seed)
    device = crop.image.device
    start = time.perf_counter()
    names = (warm.prototype,) if warm is not None else config.prototypes
    learnt = (config.deform, config.learn_texture)
    candidates: dict[str, Optimisation] = {}
    for name in names:
        proto, topology = load_prototype(name)
        topology = topology.to(device)
        if warm is not None:
            shape = ShapeParams(warm.vertices.to(device), topology, warm.texture.shape[-1], *learnt).to(device)
            with torch.no_grad():
                shape.texture_logits.copy_(torch.logit(warm.texture.to(device).clamp(1e-4, 1 - 1e-4)))
        else:
            shape = ShapeParams(proto.to(device), topology, config.texture_size, *learnt).to(device)
        motion = MotionParams(
            crop.camera, config.size_range, config.max_size_ratio, config.max_rotation_deg, config.init_size
        ).to(device)
        if warm is not None:
            motion.load_motion(warm.motion)
            # The streak locates this frame far better than a prediction carried over from the
            # last one, whose errors would add up along a track: the prediction only says which
            # end came first, and the rotation.
            motion.start_at_streak(_oriented(streak_from_mask(crop.object_mask), warm.motion, crop))
        else:
            motion.start_at_streak(streak_from_mask(crop.object_mask))
        iterations = config.warm_iterations if warm is not None else config.iterations
        candidates[name] = Optimisation(crop, shape, motion, iterations, warm is not None, masks, config, render_config)
    with deterministic(device):
        if len(candidates) > 1 and config.prototype_trial < 1:
            # Every prototype for the trial's steps, then only the one with the lowest L_I.
            for fit in candidates.values():
                fit.run(max(1, round(config.prototype_trial * fit.iterations)), on_step)
            leader = min(candidates, key=lambda n: candidates[n].best_record["image"])
            candidates[leader].run(candidates[leader].iterations, on_step)
        else:
            for fit in candidates.values():
                fit.run(fit.iterations, on_step)
    fitted = {n: f for n, f in candidates.items() if f.best is not None and f.best_render is not None}
    if not fitted:
        raise SfbError("the fit diverged from its first step (non-finite loss); check the input images")
    name = min(fitted, key=lambda n: fitted[n].best_record["image"])
    fit = fitted[name]
    params, record, rendered, shape, motion = fit.best, fit.best_record, fit.best_render, fit.shape, fit.motion
    curves = {n: f.curve for n, f in candidates.items()}
    shape.load_state_dict(params[0])
    motion.load_state_dict(params[1])
    with torch.no_grad():
        state = ObjectState(shape.vertices(), shape.topology, shape.texture(), motion.motion())
    return FitResult(
        prototype=name,
        state=state,
        reconstruction=rendered,
        losses=record,
        curves=curves,
        iterations=len(curves[name]),
        seconds=time.perf_counter() - start,
    )
