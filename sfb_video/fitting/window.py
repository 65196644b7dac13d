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
far apart, :func:`~sfb_video.fitting.path.choose_motion`), and the start: fresh prototypes (a
capsule for pens and keys) and, on a track's first window, the seed's prototype with the spin
and texture that a search over spins finds (:mod:`sfb_video.fitting.spin`) compete with the
seeded mesh for the first part of the fit, and the lowest joint L_I goes on
(:func:`sfb_video.fitting.engine.race`).

The fit in parts: :func:`start_window` (the path fitted to the seeds, the motion model, what
every candidate shares), :func:`window_candidate` (one candidate's optimisation),
:func:`searched_spin`, and :func:`fit_window`, which races them.
"""

from __future__ import annotations

import copy
import statistics
import time
from dataclasses import dataclass, field

import torch

from sfb_video.config import FitConfig, JointConfig, RenderConfig
from sfb_video.crop import Crop
from sfb_video.errors import DivergenceError
from sfb_video.fitting.engine import (
    Optimisation,
    Step,
    StepCallback,
    deterministic,
    race,
    seed_texture,
    seeded,
    weighted_sum,
)
from sfb_video.fitting.frame import frame_terms
from sfb_video.fitting.path import Seed, apparent_px, choose_motion, fit_path, measured_exposure, path_params
from sfb_video.fitting.spin import SpinScore, score_spin, search_spin, spin_grid, upsample_texture
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.geometry.rotation import axis_angle_to_matrix
from sfb_video.model import losses
from sfb_video.model.formation import exposure_times
from sfb_video.model.scene import ObjectState
from sfb_video.model.shape import ShapeParams
from sfb_video.model.trajectory import Trajectory, TrajectoryParams
from sfb_video.render import MeshRenderer


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


class WindowObjective:
    """The joint loss of one candidate: the mean over the window's frames of their weighted data
    terms (each in its crop, as the single-frame fit weighs them), plus L_T and L_L once; a step
    keeps each frame's terms for the snapshot."""

    def __init__(self, window: WindowStart, shape: ShapeParams, path: TrajectoryParams) -> None:
        self.window, self.shape, self.path = window, shape, path
        self.modules = (shape, path)

    def __call__(self, progress: float) -> Step:
        window, shape, config = self.window, self.shape, self.window.fit_config
        rotations, positions = self.path(window.frame_times, window.taus)
        vertices, texture = shape.vertices(), shape.texture()
        per_frame: dict[int, dict[str, float]] = {}
        frame_total = torch.zeros((), device=window.taus.device)
        for k, frame in enumerate(window.frames):
            posed = pose_vertices(vertices, rotations[k], positions[k])
            rendered, alpha = window.renderers[k].blurred(posed, shape.topology, texture, frame.crop.background)
            terms, weights = frame_terms(frame.crop, frame.masks, rendered, alpha, config, progress)
            frame_total = frame_total + weighted_sum(terms, weights)
            per_frame[frame.index] = {name: float(v.detach()) for name, v in terms.items()}
        texture_tv = losses.texture_tv(texture)
        laplacian = losses.laplacian(vertices, shape.topology.edges)
        total = frame_total / len(window.frames) + config.w_texture * texture_tv + config.w_laplacian * laplacian
        record = {
            "image": statistics.fmean(r["image"] for r in per_frame.values()),
            "texture": float(texture_tv.detach()),
            "laplacian": float(laplacian.detach()),
            "exposure": float(self.path.exposure().detach()),
            "total": float(total.detach()),
        }
        return Step(total, record, per_frame)


@dataclass(frozen=True)
class WindowStart:
    """What every candidate of a window starts from.

    Attributes:
        frames: the window's frames, in time order; first: the first one's index.
        seeds: their single-frame fits; best_seed: the one whose mesh, texture and rotation the
            seeded candidate takes.
        path: the trajectory fitted to the seeds' streak ends (each candidate gets a copy).
        model, bounce: the motion model chosen on the seeds and, for a bounce, its break's time.
        exposure_fraction: where e starts (what the seeds measure when e is learnt).
        frame_times: (F,) each frame's time in the window; taus: (T,) the exposure's times.
        renderers: one per frame, in its crop's camera.
        fit_config, config: the loss weights and learning rates; the joint fit's settings.
    """

    frames: list[WindowFrame]
    first: int
    seeds: list[Seed]
    best_seed: Seed
    path: TrajectoryParams
    model: str
    bounce: float | None
    exposure_fraction: float
    frame_times: torch.Tensor
    taus: torch.Tensor
    renderers: list[MeshRenderer]
    fit_config: FitConfig
    config: JointConfig

    @property
    def device(self) -> torch.device:
        return self.taus.device

    def oriented(self, spin: torch.Tensor) -> TrajectoryParams:
        """The seeds' path turning at ``spin`` (3,) rad per frame interval, the best seed keeping
        its orientation at its frame's start whatever the spin (the base path, changed in place)."""
        at = float(self.best_seed.index - self.first)
        self.path.load_rotation(axis_angle_to_matrix(-at * spin) @ self.best_seed.state.motion.rot0, spin)
        return self.path

    def poses(self, spin: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(F, T, 3, 3) rotations and (F, T, 3) positions of the frames on the seeds' path at ``spin``."""
        with torch.no_grad():
            return self.oriented(spin)(self.frame_times, self.taus)


def start_window(
    frames: list[WindowFrame],
    seeds: list[Seed],
    camera: PinholeCamera,
    fit_config: FitConfig,
    config: JointConfig,
    render_config: RenderConfig,
    exposure_fraction: float,
    shape_from: Seed | None = None,
) -> WindowStart:
    """The window's path, fitted to its seeds' streak ends, and what its candidates share.

    Raises:
        DivergenceError: when no finite path fits the seeds.
    """
    device = frames[0].crop.image.device
    first = frames[0].index
    end = frames[-1].index - first + 1.0
    if config.learn_exposure:
        # The seeds' streaks and spacing measure e better than the configured start, which may be
        # far off (a short shutter taken for an open one puts each streak's end at the next
        # frame's start, and the path then has to jump).
        exposure_fraction = measured_exposure(seeds, camera) or exposure_fraction
    model, bounce = choose_motion(seeds, first, end, camera, exposure_fraction, config)
    ref_px = statistics.median(apparent_px(s.state.motion, camera) for s in seeds)
    path = path_params(model, bounce, end, camera, ref_px, exposure_fraction, config, fit_config.max_rotation_deg)
    fit_path(path, seeds, first, exposure_fraction, config.path_steps)
    if not bool(torch.isfinite(path.anchors_raw).all()):
        raise DivergenceError("no finite path through the seeds' streaks")
    return WindowStart(
        frames=frames,
        first=first,
        seeds=seeds,
        best_seed=shape_from or min(seeds, key=lambda s: s.image_loss),
        path=path,
        model=model,
        bounce=bounce,
        exposure_fraction=exposure_fraction,
        frame_times=torch.tensor([float(f.index - first) for f in frames], device=device),
        taus=exposure_times(render_config.time_steps, device),
        renderers=[MeshRenderer(f.crop.camera, render_config) for f in frames],
        fit_config=fit_config,
        config=config,
    )


def window_candidate(window: WindowStart, prototype: str | None, spin: SpinScore | None = None) -> Optimisation:
    """One candidate's optimisation on a copy of the window's path.

    Args:
        prototype: None for the best seed's mesh and texture, else a fresh (grey) prototype.
        spin: a searched spin and its texture, else the best seed's spin.
    """
    fit_config, config, seed = window.fit_config, window.config, window.best_seed
    learnt = (fit_config.deform, fit_config.learn_texture)
    window.oriented(seed.state.motion.omega / window.exposure_fraction if spin is None else spin.spin)
    path = copy.deepcopy(window.path)
    if prototype is None:
        _, topology = load_prototype(seed.prototype)
        shape = ShapeParams(seed.state.vertices, topology, seed.state.texture.shape[-1], *learnt)
        texture = seed.state.texture
    else:
        proto, topology = load_prototype(prototype)
        shape = ShapeParams(proto, topology, fit_config.texture_size, *learnt)
        texture = None
    if spin is not None:
        texture = upsample_texture(spin.texture.cpu(), shape.texture_logits.shape[-1])
    if texture is not None:
        seed_texture(shape, texture)
    shape.topology = topology.to(window.device)
    shape, path = shape.to(window.device), path.to(window.device)
    rotation = (path.quat0, path.spin_raw)
    groups = [
        {"params": [p for p in shape.parameters() if p.requires_grad]},
        {"params": [path.anchors_raw], "lr": config.lr_path},
        {"params": [p for p in rotation if p.requires_grad], "lr": fit_config.lr_rotation},
        {"params": [path.exposure_raw] if path.exposure_raw.requires_grad else [], "lr": config.lr_exposure},
    ]
    optimiser = torch.optim.Adam([g for g in groups if g["params"]], lr=fit_config.lr, fused=True)
    return Optimisation(WindowObjective(window, shape, path), optimiser, config.iterations)


def searched_spin(window: WindowStart, render_config: RenderConfig) -> SpinScore:
    """The spin (and texture) that best explains the window's frames on the seeds' path, searched
    on the best seed's prototype as it was before its single-frame fit deformed it to explain one
    frame's blur: searched on the deformed mesh the spin came out 40 degrees off, on the
    prototype 4 (tests/fitting/test_window.py's clip)."""
    config = window.config
    vertices, topology = (x.to(window.device) for x in load_prototype(window.best_seed.prototype))
    crops = [f.crop for f in window.frames]
    args = (crops, vertices, topology, config.spin_texture, config.spin_smoothness, render_config)
    seed_spins = torch.stack([s.state.motion.omega / window.exposure_fraction for s in window.seeds]).float()
    grid = torch.cat((spin_grid(config.spin_magnitudes, config.spin_axes), seed_spins)).to(window.device)
    return search_spin(grid, lambda s: score_spin(s, window.poses, *args), config.spin_refine)[0]


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
        DivergenceError: when no finite path fits the seeds, or every candidate's loss is
            non-finite from its first step.
    """
    started = time.perf_counter()
    window = start_window(frames, seeds, camera, fit_config, config, render_config, exposure_fraction, shape_from)
    searching = shape_from is None and bool(config.spin_magnitudes) and fit_config.max_rotation_deg > 0
    seed_key = f"seed:{window.best_seed.prototype}"
    with seeded(fit_config.seed), deterministic(window.device):
        fits = {seed_key: window_candidate(window, None)} | {p: window_candidate(window, p) for p in prototypes}
        if searching:
            # On the seeds' path, not on the one of a trial: a trial from a wrong spin bends the
            # path to fit it, and the search then finds a wrong spin that explains the frames
            # better than the true one on the seeds' path (40 degrees off against 4).
            spin = searched_spin(window, render_config)
            fits[f"spin:{window.best_seed.prototype}"] = window_candidate(window, window.best_seed.prototype, spin)
        trial = max(1, round(config.trial_fraction * config.iterations)) if len(fits) > 1 else None
        key, trials = race(fits, trial, on_step)
    fit = fits[key]
    best = fit.restore()
    shape, path = fit.objective.modules
    with torch.no_grad():
        vertices, texture = shape.vertices().cpu(), shape.texture().cpu()
    return JointResult(
        prototype=key.split(":")[-1],
        vertices=vertices,
        topology=shape.topology.to("cpu"),
        texture=texture,
        trajectory=path.trajectory(window.first, window.model),
        losses=best.kept,
        loss=best.record["total"],
        curve=fit.curve,
        seconds=time.perf_counter() - started,
        bounce=window.bounce,
        trials=trials,
    )
