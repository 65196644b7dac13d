"""Shape from Blur's test-time optimisation of one blurred frame (paper, Sec. 3.2).

For each prototype in turn, Adam minimises L = w_I L_I + w_S L_S (or w_D L_D) + w_T L_T +
w_L L_L over vertex offsets, texture and motion; the parameters with the lowest L_I seen are
kept, and the prototype with the lowest L_I wins. A warm start (the video pipeline's next
frame) starts from a previous result and stops early on a plateau.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch

from sfb_video.checks import SfbError
from sfb_video.config import FitConfig, RenderConfig
from sfb_video.crop import Crop
from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model import losses
from sfb_video.model.formation import composite, exposure_times
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
    vertices = shape.vertices()
    out = renderer(pose_vertices(vertices, rotations, positions), shape.topology, shape.texture())
    rendered = composite(out.rgb, out.alpha, crop.background)
    terms = {
        "image": losses.image_loss(crop.image, rendered, crop.object_mask),
        "texture": losses.texture_tv(shape.texture()),
        "laplacian": losses.laplacian(vertices, shape.topology.edges),
    }
    weights = {"image": config.w_image, "texture": config.w_texture, "laplacian": config.w_laplacian}
    if masks is not None:
        terms["silhouette"] = losses.silhouette_loss(masks, out.alpha)
        weights["silhouette"] = config.w_silhouette
    else:
        terms["difference"] = losses.difference_loss(crop.object_mask, out.alpha)
        weights["difference"] = config.w_difference * max(0.0, 1 - progress / config.difference_fade)
    total = sum(weights[k] * v for k, v in terms.items() if weights[k] != 0)
    record = {k: float(v.detach()) for k, v in terms.items()}
    record["total"] = float(total.detach())
    return total, record, rendered


def _optimise(
    crop: Crop,
    shape: ShapeParams,
    motion: MotionParams,
    iterations: int,
    early_stop: bool,
    masks: torch.Tensor | None,
    config: FitConfig,
    render_config: RenderConfig,
    on_step: StepCallback | None,
) -> tuple[tuple[dict, dict] | None, dict[str, float], torch.Tensor | None, list[dict[str, float]]]:
    renderer = MeshRenderer(crop.camera, render_config)
    taus = exposure_times(render_config.time_steps, crop.image.device)
    rotation = (motion.quat0, motion.omega_raw)
    trained = [p for p in (*shape.parameters(), *motion.parameters()) if p.requires_grad]
    groups = [
        {"params": [p for p in trained if all(p is not r for r in rotation)]},
        {"params": [p for p in trained if any(p is r for r in rotation)], "lr": config.lr_rotation},
    ]
    optimiser = torch.optim.Adam(groups, lr=config.lr)
    best: tuple[dict, dict] | None = None  # state dicts of shape and motion
    best_record: dict[str, float] = {"image": float("inf")}
    best_render: torch.Tensor | None = None
    curve: list[dict[str, float]] = []
    since_improved = 0
    for step in range(iterations):
        optimiser.zero_grad(set_to_none=True)
        total, record, rendered = _joint_loss(crop, shape, motion, renderer, taus, masks, config, step / iterations)
        if not torch.isfinite(total):
            break  # keep the best parameters seen; a NaN step would only spoil them
        curve.append(record)
        if on_step is not None:
            on_step(step, record)
        if record["image"] < best_record["image"] * (1 - config.plateau_tolerance):
            since_improved = 0
        else:
            since_improved += 1
        if record["image"] < best_record["image"]:
            best_record, best_render = record, rendered.detach()
            best = tuple({k: v.detach().clone() for k, v in m.state_dict().items()} for m in (shape, motion))
        if early_stop and since_improved >= config.plateau_patience:
            break
        total.backward()
        optimiser.step()
    return best, best_record, best_render, curve


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
    best: tuple[float, str, tuple[dict, dict], dict[str, float], torch.Tensor, ShapeParams, MotionParams] | None
    best = None
    curves: dict[str, list[dict[str, float]]] = {}
    learnt = (config.deform, config.learn_texture)
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
        with deterministic(device):
            params, record, rendered, curve = _optimise(
                crop, shape, motion, iterations, warm is not None, masks, config, render_config, on_step
            )
        curves[name] = curve
        if params is not None and (best is None or record["image"] < best[0]):
            best = (record["image"], name, params, record, rendered, shape, motion)
    if best is None:
        raise SfbError("the fit diverged from its first step (non-finite loss); check the input images")
    _, name, params, record, rendered, shape, motion = best
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
