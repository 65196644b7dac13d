"""The joint fit of a window of frames of one track: one mesh, one texture, one trajectory.

One frame cannot tell a long object moving a little from a short one moving far, nor the
rotation from a free texture (README, "Fit accuracy"). Several frames can: the distance between
consecutive streaks fixes the speed, the exposure fraction turns speed into travel within an
exposure, and one texture that must explain every frame fixes the rotation. So the frames of a
window share the mesh (prototype + offsets) and the texture, and their poses are samples of one
continuous trajectory (:mod:`sfb_video.model.trajectory`) at each frame's exposure times, the
exposure fraction shared and learnt. Adam minimises the mean of the frames' own losses (L_I and
L_D or L_S, each in its crop, as the single-frame fit weighs them) plus L_T and L_L once.

The fit starts from single-frame fits of the same frames (the seeds): the trajectory is fitted
to their streak ends in the image, and the mesh and texture are those of the seed that explains
its frame best, its rotation carried to the window's start. Two choices are made on the window,
not on one frame: the motion model (a bounce where one smooth path leaves the seeds' streak ends
far apart, :func:`choose_motion`), and the start: fresh prototypes (a capsule for pens and
keys) and, on a track's first window, the seed's prototype with the spin and texture that a
search over spins finds (:mod:`sfb_video.fitting.spin`) compete with the seeded mesh for the first part
of the fit, and the lowest joint L_I goes on.
"""

from __future__ import annotations

import copy
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from sfb_video.config import FitConfig, JointConfig, RenderConfig
from sfb_video.crop import Crop
from sfb_video.fitting.frame import deterministic
from sfb_video.fitting.spin import SpinScore, score_spin, search_spin, spin_grid, upsample_texture
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.geometry.rotation import axis_angle_to_matrix
from sfb_video.model import losses
from sfb_video.model.formation import exposure_times
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.model.shape import ShapeParams
from sfb_video.model.trajectory import MOTION_MODELS, Trajectory, TrajectoryParams, interpolate
from sfb_video.render import MeshRenderer

StepCallback = Callable[[int, dict[str, float]], None]


@dataclass(frozen=True)
class WindowFrame:
    """One frame of a window.

    Attributes:
        index: the frame's index in the clip.
        crop: its working crop (image, background, crop camera, object region).
        masks: (N, h, w) sub-frame masks in the track's time order, or None (L_D is used).
    """

    index: int
    crop: Crop
    masks: torch.Tensor | None = None


@dataclass(frozen=True)
class Seed:
    """A single-frame fit of one frame of the window, where the joint fit starts.

    Attributes:
        index: the frame's index; state: its mesh, texture and motion (camera coordinates, in
        the track's time direction); prototype: the prototype it deformed; image_loss: its L_I.
    """

    index: int
    state: ObjectState
    prototype: str
    image_loss: float


@dataclass(frozen=True)
class JointResult:
    """The outcome of a joint fit.

    Attributes:
        prototype: the prototype the shared mesh deformed.
        vertices: (V, 3) the shared mesh at unit scale; topology: its faces and UVs.
        texture: (3, Ht, Wt) the shared texture.
        trajectory: the window's trajectory (camera coordinates, object sizes).
        losses: per frame index, its loss terms at the kept parameters.
        loss: the joint loss at the kept parameters (the mean over frames of their weighted
            terms, plus the shared L_T and L_L).
        curve: the joint loss terms at every step.
        seconds: wall time.
        bounce: the window time of the bounce model's break, else None.
        trials: per candidate tried (``seed:<prototype>``, ``spin:<prototype>`` for the
            searched spin, or a fresh prototype's name), its mean L_I after the trial steps.
    """

    prototype: str
    vertices: torch.Tensor
    topology: MeshTopology
    texture: torch.Tensor
    trajectory: Trajectory
    losses: dict[int, dict[str, float]]
    loss: float
    curve: list[dict[str, float]]
    seconds: float
    bounce: float | None = None
    trials: dict[str, float] = field(default_factory=dict)

    def state(self, index: int) -> ObjectState:
        """Frame ``index``'s object: the shared mesh and texture, its exposure's motion."""
        return ObjectState(self.vertices, self.topology, self.texture, self.trajectory.frame_motion(index))


def _apparent_px(motion: Motion, camera: PinholeCamera) -> float:
    return float(camera.fy / motion.x0[2].clamp_min(1e-6))


def _streak_ends(seeds: list[Seed], first: int, exposure: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Window times (2S,) and camera-space points (2S, 3) of the seeds' streak ends, in time order."""
    times, points = [], []
    for seed in seeds:
        m = seed.state.motion
        times += [seed.index - first, seed.index - first + exposure]
        points += [m.x0, m.x0 + m.dx]
    t = torch.tensor(times, dtype=torch.float32)
    order = torch.argsort(t)
    return t[order], torch.stack(points).float()[order]


def _fit_path(params: TrajectoryParams, seeds: list[Seed], first: int, exposure: float, steps: int) -> torch.Tensor:
    """Fit the anchors to the seeds' streak ends in the image (no rendering): in pixels (in
    units of the reference diameter), and loosely in apparent size, which sets depth but which
    one frame measures poorly (a thin object's size barely shows).

    Returns:
        (2S,) each streak end's distance from the fitted path in the image, in reference diameters.
    """
    t, target = _streak_ends(seeds, first, exposure)
    uv, depth = params.camera.project(target)
    log_size = torch.log(params.camera.fy / depth)
    # Start from the seeds themselves, interpolated at the anchors' times in the image and in
    # log depth: extrapolated in camera space, a depth can end behind the camera (circle_fast).
    start_uv = torch.stack([_interp(params.times, t, uv[:, k]) for k in range(2)], -1)
    start_depth = torch.exp(_interp(params.times, t, torch.log(depth)))
    params.load_anchors(params.camera.unproject(start_uv, start_depth))
    optimiser = torch.optim.Adam([params.anchors_raw], lr=0.05)
    for _ in range(steps):
        optimiser.zero_grad(set_to_none=True)
        path = interpolate(params.anchors(), params.breaks, params.degree, t)
        p_uv, p_depth = params.camera.project(path)
        loss = ((p_uv - uv) / params.ref_px).square().sum(-1).mean()
        loss = loss + 0.25 * (torch.log(params.camera.fy / p_depth) - log_size).square().mean()
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        path = interpolate(params.anchors(), params.breaks, params.degree, t)
        return ((params.camera.project(path)[0] - uv) / params.ref_px).norm(dim=-1)


def _interp(x: torch.Tensor, xp: torch.Tensor, fp: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of (xp, fp) at x, extended linearly beyond the ends."""
    if xp.shape[0] == 1:
        return fp.expand_as(x).clone()
    i = torch.searchsorted(xp, x).clamp(1, xp.shape[0] - 1)
    x0, x1, f0, f1 = xp[i - 1], xp[i], fp[i - 1], fp[i]
    w = (x - x0) / (x1 - x0).clamp_min(1e-9)
    return f0 + w * (f1 - f0)


def measured_exposure(seeds: list[Seed], camera: PinholeCamera) -> float | None:
    """The exposure fraction the seeds show: the median over consecutive frames of a streak's
    length in the image over the distance from its start to the next frame's start (a shutter
    open for the fraction e of the interval draws e of the way). None without two consecutive
    seeds that move."""
    ratios = []
    by_index = {s.index: s.state.motion for s in seeds}
    for index, motion in by_index.items():
        following = by_index.get(index + 1)
        if following is None:
            continue
        uv = camera.project(torch.stack((motion.x0, motion.x0 + motion.dx, following.x0)))[0]
        step = float((uv[2] - uv[0]).norm())
        if step > 1.0:
            ratios.append(float((uv[1] - uv[0]).norm()) / step)
    return min(max(statistics.median(ratios), 0.05), 1.0) if ratios else None


def _path_params(
    model: str,
    bounce: float | None,
    end: float,
    camera: PinholeCamera,
    ref_px: float,
    exposure_fraction: float,
    config: JointConfig,
    max_rotation_deg: float,
) -> TrajectoryParams:
    degree, pieces = MOTION_MODELS[model]
    breaks = torch.tensor([0.0, end] if pieces == 1 else [0.0, float(bounce), end])
    return TrajectoryParams(camera, breaks, degree, ref_px, exposure_fraction, config.learn_exposure, max_rotation_deg)


def choose_motion(
    seeds: list[Seed],
    first: int,
    end: float,
    camera: PinholeCamera,
    exposure_fraction: float,
    config: JointConfig,
) -> tuple[str, float | None]:
    """The motion model of a window and, for a bounce, the time of its break.

    A configured model is used as is (a bounce's break then goes where it fits the seeds best).
    ``auto`` takes constant acceleration unless one smooth path leaves some seed's streak end
    more than ``config.bounce_residual`` reference diameters away, and a path that breaks in
    one of the gaps between exposures brings every end within that distance and halves the
    worst miss (seeds that are simply wrong, a fit of the wrong blob, are not taken for a
    bounce: breaking the path does not bring them near).

    Returns:
        the model's name and the bounce's window time (None without a bounce).
    """
    ref_px = statistics.median(_apparent_px(s.state.motion, camera) for s in seeds)

    def residual(model: str, bounce: float | None) -> float:
        params = _path_params(model, bounce, end, camera, ref_px, exposure_fraction, config, 0.0)
        return float(_fit_path(params, seeds, first, exposure_fraction, config.path_steps).max())

    if config.motion not in ("auto", "bounce"):
        return config.motion, None
    smooth = residual("constant_acceleration", None) if config.motion == "auto" else float("inf")
    if len(seeds) < 3 or smooth <= config.bounce_residual:
        return "constant_acceleration", None
    # The break in the middle of a gap: the bounce happened while the shutter was closed, or
    # near enough (a break during an exposure is seen as a bend of one streak).
    gaps = [k + (1 + exposure_fraction) / 2 for k in range(round(end) - 1)]
    broken = {
        g: residual("bounce", g)
        for g in gaps
        if min(s.index for s in seeds) - first < g < max(s.index for s in seeds) - first
    }
    best = min(broken, key=broken.__getitem__)
    if config.motion == "bounce" or broken[best] <= min(0.5 * smooth, config.bounce_residual):
        return "bounce", best
    return "constant_acceleration", None


def _frame_loss(
    frame: WindowFrame,
    rotations: torch.Tensor,
    positions: torch.Tensor,
    vertices: torch.Tensor,
    texture: torch.Tensor,
    shape: ShapeParams,
    renderer: MeshRenderer,
    config: FitConfig,
    progress: float,
) -> tuple[torch.Tensor, dict[str, float]]:
    crop = frame.crop
    posed = pose_vertices(vertices, rotations, positions)
    rendered, alpha = renderer.blurred(posed, shape.topology, texture, crop.background)
    terms = {"image": losses.image_loss(crop.image, rendered, crop.object_mask)}
    weights = {"image": config.w_image}
    if frame.masks is not None:
        terms["silhouette"] = losses.silhouette_loss(frame.masks, alpha)
        weights["silhouette"] = config.w_silhouette
    else:
        terms["difference"] = losses.difference_loss(crop.object_mask, alpha)
        weights["difference"] = config.w_difference * max(0.0, 1 - progress / config.difference_fade)
    total = sum(weights[k] * v for k, v in terms.items() if weights[k] != 0)
    return total, {k: float(v.detach()) for k, v in terms.items()}


class _WindowFit:
    """One candidate shape's joint fit of a window, which can be run in parts (a trial, then
    the rest) and keeps its parameters at the lowest mean L_I seen."""

    def __init__(
        self,
        frames: list[WindowFrame],
        renderers: list[MeshRenderer],
        shape: ShapeParams,
        params: TrajectoryParams,
        fit_config: FitConfig,
        config: JointConfig,
        taus: torch.Tensor,
    ) -> None:
        self.frames, self.renderers, self.shape, self.params = frames, renderers, shape, params
        self.fit_config, self.config, self.taus = fit_config, config, taus
        first = frames[0].index
        self.frame_times = torch.tensor([float(f.index - first) for f in frames], device=taus.device)
        rotation = (params.quat0, params.spin_raw)
        groups = [
            {"params": [p for p in shape.parameters() if p.requires_grad]},
            {"params": [params.anchors_raw], "lr": config.lr_path},
            {"params": [p for p in rotation if p.requires_grad], "lr": fit_config.lr_rotation},
            {"params": [params.exposure_raw] if params.exposure_raw.requires_grad else [], "lr": config.lr_exposure},
        ]
        self.optimiser = torch.optim.Adam([g for g in groups if g["params"]], lr=fit_config.lr, fused=True)
        self.step = 0
        self.curve: list[dict[str, float]] = []
        self.best: tuple[float, dict, dict, dict[int, dict[str, float]], float] | None = None

    @property
    def best_image_loss(self) -> float:
        return float("inf") if self.best is None else self.best[0]

    def run(self, steps: int, on_step: StepCallback | None) -> None:
        fit_config, shape, params = self.fit_config, self.shape, self.params
        device = self.taus.device
        for _ in range(steps):
            self.optimiser.zero_grad(set_to_none=True)
            rotations, positions = params(self.frame_times, self.taus)
            vertices, texture = shape.vertices(), shape.texture()
            per_frame: dict[int, dict[str, float]] = {}
            frame_total = torch.zeros((), device=device)
            progress = self.step / self.config.iterations
            for k, frame in enumerate(self.frames):
                total_k, record_k = _frame_loss(
                    frame, rotations[k], positions[k], vertices, texture, shape, self.renderers[k], fit_config, progress
                )
                frame_total = frame_total + total_k
                per_frame[frame.index] = record_k
            texture_tv = losses.texture_tv(texture)
            laplacian = losses.laplacian(vertices, shape.topology.edges)
            total = frame_total / len(self.frames)
            total = total + fit_config.w_texture * texture_tv + fit_config.w_laplacian * laplacian
            if not torch.isfinite(total):
                return
            image = statistics.fmean(r["image"] for r in per_frame.values())
            record = {
                "image": image,
                "texture": float(texture_tv.detach()),
                "laplacian": float(laplacian.detach()),
                "exposure": float(params.exposure().detach()),
                "total": float(total.detach()),
            }
            self.curve.append(record)
            if on_step is not None:
                on_step(self.step, record)
            if image < self.best_image_loss:
                state = tuple({k: v.detach().clone() for k, v in m.state_dict().items()} for m in (shape, params))
                self.best = (image, state[0], state[1], per_frame, record["total"])
            total.backward()
            self.optimiser.step()
            self.step += 1


def fit_window(
    frames: list[WindowFrame],
    seeds: list[Seed],
    camera: PinholeCamera,
    fit_config: FitConfig,
    config: JointConfig,
    render_config: RenderConfig,
    exposure_fraction: float,
    prototypes: tuple[str, ...] = (),
    shape_from: Seed | None = None,
    on_step: StepCallback | None = None,
) -> JointResult:
    """Fit one mesh, texture and trajectory to ``frames``, starting from their ``seeds``.

    Args:
        frames: the window's frames, in time order (consecutive frames of one track).
        seeds: single-frame fits of (some of) these frames, in the track's time direction.
        camera: the clip's full-frame camera.
        exposure_fraction: e, kept when ``config.learn_exposure`` is off; else learnt, starting
            from what the seeds measure (:func:`measured_exposure`) or, without, from this.
        prototypes: fresh prototypes (grey, undeformed) that compete with the best seed's mesh
            for the first ``config.trial_fraction`` of the steps; the lowest mean L_I goes on.
            Without ``shape_from``, the spin searched on the best seed's prototype
            (``config.spin_magnitudes``) starts one more competitor.
        shape_from: the seed whose mesh, texture and rotation the fit starts from (default: the
            seed with the lowest L_I); the previous window of a track hands its shape on so.
        on_step: called with (step, joint loss terms) after every step of the kept candidate
            (and of every candidate during the trials).

    Raises:
        RuntimeError: when no finite path fits the seeds, or every candidate's loss is
            non-finite from its first step.
    """
    device = frames[0].crop.image.device
    first = frames[0].index
    start = time.perf_counter()
    end = frames[-1].index - first + 1.0
    if config.learn_exposure:
        # The seeds' streaks and spacing measure e better than the configured start, which may be
        # far off (a short shutter taken for an open one puts each streak's end at the next
        # frame's start, and the path then has to jump).
        exposure_fraction = measured_exposure(seeds, camera) or exposure_fraction
    model, bounce = choose_motion(seeds, first, end, camera, exposure_fraction, config)
    ref_px = statistics.median(_apparent_px(s.state.motion, camera) for s in seeds)
    best_seed = shape_from or min(seeds, key=lambda s: s.image_loss)
    spin = best_seed.state.motion.omega / exposure_fraction
    renderers = [MeshRenderer(f.crop.camera, render_config) for f in frames]
    taus = exposure_times(render_config.time_steps, device)
    learnt = (fit_config.deform, fit_config.learn_texture)

    path = _path_params(model, bounce, end, camera, ref_px, exposure_fraction, config, fit_config.max_rotation_deg)
    _fit_path(path, seeds, first, exposure_fraction, config.path_steps)
    if not bool(torch.isfinite(path.anchors_raw).all()):
        raise RuntimeError("no finite path through the seeds' streaks")
    frame_times = torch.tensor([float(f.index - first) for f in frames], device=device)
    seed_index = float(best_seed.index - first)

    def orient(spin: torch.Tensor) -> None:
        # The best seed keeps its orientation at its frame's start whatever the spin.
        path.load_rotation(axis_angle_to_matrix(-seed_index * spin) @ best_seed.state.motion.rot0, spin)

    def poses(spin: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        orient(spin)
        with torch.no_grad():
            return path(frame_times, taus)

    def candidate(name: str | None, start: SpinScore | None = None) -> _WindowFit:
        # name None: the best seed's mesh, else a fresh prototype; start: a searched spin and
        # its texture, else the seed's spin (and texture, or grey for a fresh prototype).
        torch.manual_seed(fit_config.seed)
        orient(spin if start is None else start.spin)
        params = copy.deepcopy(path)
        if name is None:
            proto, topology = load_prototype(best_seed.prototype)
            shape = ShapeParams(best_seed.state.vertices, topology, best_seed.state.texture.shape[-1], *learnt)
            texture = best_seed.state.texture
        else:
            proto, topology = load_prototype(name)
            shape = ShapeParams(proto, topology, fit_config.texture_size, *learnt)
            texture = None
        if start is not None:
            texture = upsample_texture(start.texture.cpu(), shape.texture_logits.shape[-1])
        if texture is not None:
            with torch.no_grad():
                shape.texture_logits.copy_(torch.logit(texture.clamp(1e-4, 1 - 1e-4)))
        shape.topology = topology.to(device)
        return _WindowFit(frames, renderers, shape.to(device), params.to(device), fit_config, config, taus)

    def search() -> SpinScore:
        # On the seed's prototype as it was before its single-frame fit deformed it to explain
        # one frame's blur: searched on the deformed mesh the spin came out 40 degrees off, on
        # the prototype 4 (tests/test_joint.py's clip).
        vertices, topology = (x.to(device) for x in load_prototype(best_seed.prototype))
        crops = [f.crop for f in frames]
        args = (crops, vertices, topology, config.spin_texture, config.spin_smoothness, render_config)
        seed_spins = torch.stack([s.state.motion.omega / exposure_fraction for s in seeds]).float()
        grid = torch.cat((spin_grid(config.spin_magnitudes, config.spin_axes), seed_spins)).to(device)
        return search_spin(grid, lambda s: score_spin(s, poses, *args), config.spin_refine)[0]

    searching = shape_from is None and bool(config.spin_magnitudes) and fit_config.max_rotation_deg > 0
    with deterministic(device):
        seed_key = f"seed:{best_seed.prototype}"
        fits = {seed_key: candidate(None)} | {p: candidate(p) for p in prototypes}
        trials: dict[str, float] = {}
        trial_steps = max(1, round(config.trial_fraction * config.iterations))
        if len(fits) > 1 or searching:
            for key, fit in fits.items():
                fit.run(trial_steps, on_step)
                trials[key] = fit.best_image_loss
        if searching:
            # On the seeds' path, not on the one of the seed's trial: a trial from a wrong spin
            # bends the path to fit it, and the search then finds a wrong spin that explains
            # the frames better than the true one on the seeds' path (tests/test_joint.py's
            # clip: 40 degrees off against 4).
            key = f"spin:{best_seed.prototype}"
            fits[key] = candidate(best_seed.prototype, search())
            fits[key].run(trial_steps, on_step)
            trials[key] = fits[key].best_image_loss
        key = min(fits, key=lambda k: fits[k].best_image_loss)
        fit = fits[key]
        name = key.split(":")[-1]
        fit.run(config.iterations - fit.step, on_step)
    if fit.best is None:
        raise RuntimeError("the joint fit diverged from its first step (non-finite loss)")
    _, shape_state, path_state, per_frame, loss = fit.best
    fit.shape.load_state_dict(shape_state)
    fit.params.load_state_dict(path_state)
    with torch.no_grad():
        vertices, texture = fit.shape.vertices().cpu(), fit.shape.texture().cpu()
    return JointResult(
        prototype=name,
        vertices=vertices,
        topology=fit.shape.topology.to("cpu"),
        texture=texture,
        trajectory=fit.params.trajectory(first, model),
        losses=per_frame,
        loss=loss,
        curve=fit.curve,
        seconds=time.perf_counter() - start,
        bounce=bounce,
        trials=trials,
    )
