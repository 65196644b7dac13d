"""Shape from Blur's test-time optimisation of one blurred frame (paper, Sec. 3.2).

For each prototype, Adam minimises L = w_I L_I + w_S L_S (or w_D L_D) + w_T L_T + w_L L_L over
vertex offsets, texture and motion; the parameters with the lowest L_I seen are kept. Several
prototypes all run for the first ``prototype_trial`` of the steps, then only the one with the
lowest L_I goes on (:func:`sfb_video.fitting.engine.race`). A warm start (the video pipeline's
next frame) starts from a previous result and stops early on a plateau.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch

from sfb_video.config import FitConfig, RenderConfig
from sfb_video.crop import Crop
from sfb_video.errors import NoObjectError, SfbError
from sfb_video.fitting.engine import (
    Optimisation,
    Step,
    StepCallback,
    deterministic,
    race,
    read_terms,
    seed_texture,
    seeded,
    weighted_sum,
)
from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model import losses
from sfb_video.model.formation import exposure_times
from sfb_video.model.motion import MIN_STREAK_PIXELS, Motion, MotionParams, Streak, streak_from_mask
from sfb_video.model.scene import ObjectState
from sfb_video.model.shape import ShapeParams
from sfb_video.render import MeshRenderer


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
    """Where a warm-started fit begins: a previous frame's shape and texture, a predicted motion.

    ``at_streak`` moves the motion onto this frame's streak first (a prediction from another
    frame); off, the motion is this frame's already (a joint fit's pose, refined).
    """

    prototype: str
    vertices: torch.Tensor
    texture: torch.Tensor
    motion: Motion
    at_streak: bool = True


def frame_terms(
    crop: Crop,
    masks: torch.Tensor | None,
    rendered: torch.Tensor,
    alpha: torch.Tensor,
    config: FitConfig,
    progress: float,
) -> tuple[dict[str, torch.Tensor], dict[str, float]]:
    """One frame's data terms and their weights at ``progress`` (the fraction of the fit's steps
    done): L_I, and L_S on the sub-frame ``masks`` or else L_D, which fades out.

    Args:
        crop: the frame's crop; masks: (N, h, w) or None.
        rendered: (3, h, w) the blurred render; alpha: (T, h, w) its silhouettes.
    """
    terms = {"image": losses.image_loss(crop.image, rendered, crop.object_mask)}
    weights = {"image": config.w_image}
    if masks is not None:
        terms["silhouette"] = losses.silhouette_loss(masks, alpha)
        weights["silhouette"] = config.w_silhouette
    else:
        terms["difference"] = losses.difference_loss(crop.object_mask, alpha)
        weights["difference"] = config.w_difference * max(0.0, 1 - progress / config.difference_fade)
    return terms, weights


class FrameObjective:
    """L = w_I L_I + w_T L_T + w_L L_L + (w_S L_S or w_D L_D) of one candidate on one crop; a
    step keeps its blurred render for the snapshot."""

    def __init__(
        self,
        crop: Crop,
        shape: ShapeParams,
        motion: MotionParams,
        masks: torch.Tensor | None,
        config: FitConfig,
        render_config: RenderConfig,
    ) -> None:
        self.crop, self.shape, self.motion, self.masks, self.config = crop, shape, motion, masks, config
        self.modules = (shape, motion)
        self.renderer = MeshRenderer(crop.camera, render_config)
        self.taus = exposure_times(render_config.time_steps, crop.image.device)

    def __call__(self, progress: float) -> Step:
        shape, config = self.shape, self.config
        rotations, positions = self.motion(self.taus)
        vertices, texture = shape.vertices(), shape.texture()
        posed = pose_vertices(vertices, rotations, positions)
        rendered, alpha = self.renderer.blurred(posed, shape.topology, texture, self.crop.background)
        data, data_weights = frame_terms(self.crop, self.masks, rendered, alpha, config, progress)
        terms = {
            "image": data.pop("image"),
            "texture": losses.texture_tv(texture),
            "laplacian": losses.laplacian(vertices, shape.topology.edges),
            **data,
        }
        weights = data_weights | {"texture": config.w_texture, "laplacian": config.w_laplacian}
        total = weighted_sum(terms, weights)
        record = read_terms(terms | {"total": total})
        return Step(total, record, rendered.detach())


def frame_optimisation(objective: FrameObjective, iterations: int, early_stop: bool) -> Optimisation:
    """Adam on the candidate's learnt parameters, rotations at their own step size (fused: one
    kernel per step instead of a dozen small operations per parameter)."""
    config, motion = objective.config, objective.motion
    rotation = (motion.quat0, motion.omega_raw)
    trained = [p for p in (*objective.shape.parameters(), *motion.parameters()) if p.requires_grad]
    groups = [
        {"params": [p for p in trained if all(p is not r for r in rotation)]},
        {"params": [p for p in trained if any(p is r for r in rotation)], "lr": config.lr_rotation},
    ]
    optimiser = torch.optim.Adam([g for g in groups if g["params"]], lr=config.lr, fused=True)
    patience = config.plateau_patience if early_stop else None
    return Optimisation(objective, optimiser, iterations, patience, config.plateau_tolerance)


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


def _check_crop(crop: Crop) -> None:
    if not bool(torch.isfinite(crop.image).all() and torch.isfinite(crop.background).all()):
        raise SfbError("image or background contains NaN or infinite values")
    if float(crop.object_mask.sum()) == 0:
        raise NoObjectError("no object: the image does not differ from the background in the object box")
    if int((crop.object_mask > 0.5).sum()) < MIN_STREAK_PIXELS:
        raise NoObjectError(
            f"no object: fewer than {MIN_STREAK_PIXELS} pixels differ from the background in the object box"
        )


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
    device = crop.image.device
    start = time.perf_counter()
    names = (warm.prototype,) if warm is not None else config.prototypes
    iterations = config.warm_iterations if warm is not None else config.iterations
    trial = max(1, round(config.prototype_trial * iterations)) if config.prototype_trial < 1 else None
    with seeded(config.seed):
        candidates = {name: _candidate(name, crop, warm, masks, config, render_config, iterations) for name in names}
        with deterministic(device):
            name, _ = race(candidates, trial if len(candidates) > 1 else None, on_step)
    fit = candidates[name]
    best = fit.restore()
    shape, motion = fit.objective.modules
    with torch.no_grad():
        state = ObjectState(shape.vertices(), shape.topology, shape.texture(), motion.motion())
    curves = {n: f.curve for n, f in candidates.items()}
    return FitResult(
        prototype=name,
        state=state,
        reconstruction=best.kept,
        losses=best.record,
        curves=curves,
        iterations=len(curves[name]),
        seconds=time.perf_counter() - start,
    )


def _candidate(
    name: str,
    crop: Crop,
    warm: WarmStart | None,
    masks: torch.Tensor | None,
    config: FitConfig,
    render_config: RenderConfig,
    iterations: int,
) -> Optimisation:
    """Prototype ``name``'s optimisation: from the warm start's shape, texture and motion, or
    cold from the prototype, grey, on the crop's streak."""
    device = crop.image.device
    learnt = (config.deform, config.learn_texture)
    proto, topology = load_prototype(name)
    topology = topology.to(device)
    if warm is not None:
        shape = ShapeParams(warm.vertices.to(device), topology, warm.texture.shape[-1], *learnt).to(device)
        seed_texture(shape, warm.texture)
    else:
        shape = ShapeParams(proto.to(device), topology, config.texture_size, *learnt).to(device)
    motion = MotionParams(
        crop.camera, config.size_range, config.max_size_ratio, config.max_rotation_deg, config.init_size
    ).to(device)
    if warm is None:
        motion.start_at_streak(streak_from_mask(crop.object_mask))
    else:
        motion.load_motion(warm.motion)
    if not config.learn_motion:
        motion.requires_grad_(False)
    if warm is not None and warm.at_streak:
        # The streak locates this frame far better than a prediction carried over from the
        # last one, whose errors would add up along a track: the prediction only says which
        # end came first, and the rotation.
        motion.start_at_streak(_oriented(streak_from_mask(crop.object_mask), warm.motion, crop))
    objective = FrameObjective(crop, shape, motion, masks, config, render_config)
    return frame_optimisation(objective, iterations, early_stop=warm is not None)
