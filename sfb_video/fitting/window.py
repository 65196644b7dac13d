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
far apart, :func:`~sfb_video.fitting.path.choose_motion`), and the start. On a track's first
window the footprint its streaks show once the travel is known chooses a shape
(:func:`trial_shapes`: round, elongated, boxy or flat prototypes, each stretched, turned and
sized to it, each at its own best spin, scored by the best coarse texture); that shape, its
spin refined (:mod:`sfb_video.fitting.spin`), starts the fit alone. Without a trial (a later
window, or ``joint.prototypes`` empty) the seeded mesh races the seed's prototype at a searched
spin for the first part of the fit, and the lowest joint L_I goes on
(:func:`sfb_video.fitting.engine.race`).
The Laplacian's weight falls over the fit (``joint.laplacian_end``); on the seed's prototype it
holds the deformation smooth, not the mesh. The trial's shape is fitted rigid: deformed, a box's
corners were rounded off.

After the fit each frame is refined from it (:func:`refine_frames`): the mesh held, the frame's
own texture and pose fitted, so that the window shows one object that explains each frame as
well as that frame alone can tell.

The fit in parts: :func:`start_window` (the path fitted to the seeds, the motion model, what
every candidate shares), :func:`trial_shapes`, :func:`window_candidate` (one candidate's
optimisation), :func:`searched_spin`, :func:`fit_window`, which races them, and
:func:`refine_frames`.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import statistics
import sys
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field

import torch

from sfb_video.config import FitConfig, JointConfig, RenderConfig
from sfb_video.crop import Crop
from sfb_video.errors import DivergenceError, PoseError, check_finite
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
from sfb_video.fitting.frame import WarmStart, fit_frame, frame_terms
from sfb_video.fitting.path import Seed, apparent_px, choose_motion, fit_path, measured_exposure, path_params
from sfb_video.fitting.shapes import NEEDS, Footprint, ShapedStart, footprint, shaped_start
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
from sfb_video.model.trajectory import Trajectory, TrajectoryParams
from sfb_video.render import MeshRenderer
from sfb_video.timing import stage, timed

SHAPE_PRUNE = 1.5
"""A shape of the trial whose residual at the seeds' spins is this many times the best one's is
not searched at other spins."""


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
class Refined:
    """One frame of a window refined from the joint fit: the shared mesh held, its own texture
    and, where refined with its pose, its pose (:func:`refine_frames`).

    Attributes:
        texture: (3, Ht, Wt); motion: the frame's exposure; losses: its single-frame loss terms.
    """

    texture: torch.Tensor
    motion: Motion
    losses: dict[str, float]


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
        trials: per candidate raced (``seed:<prototype>``; ``spin:<prototype>``, the seed's
            prototype with a searched spin), its mean L_I after the trial steps; empty when one
            candidate ran (``shape:<prototype>``, the shape that the footprint's trial chose,
            raced against the shapes within ``joint.shape_race`` of it where there are any).
        shapes: per prototype of the footprint's trial, its coarse texture's residual over the
            sphere's (:func:`trial_shapes`).
        shape_margin: how clearly the trial's shape won (:func:`trial_margin`); None without a
            trial.
        refined: per frame refined after the fit, its own texture and motion (the window's
            trajectory's where its pose was held; :func:`refine_frames`).
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
    shapes: dict[str, float] = field(default_factory=dict)
    refined: dict[int, Refined] = field(default_factory=dict)
    shape_margin: float | None = None

    def state(self, index: int) -> ObjectState:
        """Frame ``index``'s object: the shared mesh, and its refined texture and pose where the
        frame was refined, else the shared texture and its exposure's motion on the trajectory."""
        if index in self.refined:
            r = self.refined[index]
            return ObjectState(self.vertices, self.topology, r.texture, r.motion)
        return ObjectState(self.vertices, self.topology, self.texture, self.trajectory.frame_motion(index))

    def frame_losses(self, index: int) -> dict[str, float]:
        """Frame ``index``'s loss terms as :meth:`state` shows it."""
        return self.refined[index].losses if index in self.refined else self.losses[index]


class WindowObjective:
    """The joint loss of one candidate: the mean over the window's frames of their weighted data
    terms (each in its crop, as the single-frame fit weighs them), plus L_T and L_L once; a step
    keeps each frame's terms for the snapshot.

    With ``joint.frames_per_step`` set, a step renders only that many of the frames, in turn, so
    that every frame is seen every few steps (the first step renders them all). The step's L_I,
    which the snapshot and the race compare, is then the mean of every frame's latest L_I: a
    subset's own mean would rank the steps by which frames they drew."""

    def __init__(
        self, window: WindowStart, shape: ShapeParams, path: TrajectoryParams, rest: torch.Tensor | None = None
    ) -> None:
        self.window, self.shape, self.path, self.rest = window, shape, path, rest
        self.modules = (shape, path)
        self.steps = 0
        self.latest: dict[int, dict[str, float]] = {}

    def drawn(self) -> list[int]:
        """The positions in the window of the frames this step renders."""
        count, each = len(self.window.frames), self.window.config.frames_per_step
        if self.steps == 0 or each == 0 or each >= count:
            return list(range(count))
        start = ((self.steps - 1) * each) % count
        return sorted((start + j) % count for j in range(each))

    def __call__(self, progress: float) -> Step:
        window, shape, config = self.window, self.shape, self.window.fit_config
        rotations, positions = self.path(window.frame_times, window.taus)
        vertices, texture = shape.vertices(), shape.texture()
        drawn = self.drawn()
        self.steps += 1
        terms_by_frame: dict[int, dict[str, torch.Tensor]] = {}
        frame_total = torch.zeros((), device=window.taus.device)
        for k in drawn:
            frame = window.frames[k]
            posed = pose_vertices(vertices, rotations[k], positions[k])
            rendered, alpha = window.renderers[k].blurred(posed, shape.topology, texture, frame.crop.background)
            terms, weights = frame_terms(frame.crop, frame.masks, rendered, alpha, config, progress)
            frame_total = frame_total + weighted_sum(terms, weights)
            terms_by_frame[k] = terms
        texture_tv = losses.texture_tv(texture)
        laplacian = losses.laplacian(vertices if self.rest is None else vertices - self.rest, shape.topology.edges)
        # The shape's freedom grows over the fit: held to its start while the path and texture
        # settle, free enough at the end for corners and thin parts to form.
        w_laplacian = config.w_laplacian * window.config.laplacian_end**progress
        total = frame_total / len(drawn) + config.w_texture * texture_tv + w_laplacian * laplacian
        shared = {"texture": texture_tv, "laplacian": laplacian, "exposure": self.path.exposure(), "total": total}
        # Every frame's terms and the window's read from the device at once: one host sync a step.
        each = {f"{k}/{name}": v for k, terms in terms_by_frame.items() for name, v in terms.items()}
        read = read_terms(each | shared)
        for k, terms in terms_by_frame.items():
            self.latest[window.frames[k].index] = {name: read[f"{k}/{name}"] for name in terms}
        per_frame = {f.index: self.latest[f.index] for f in window.frames}
        record = {"image": statistics.fmean(r["image"] for r in per_frame.values())} | {k: read[k] for k in shared}
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

    @property
    def seed_time(self) -> float:
        """The best seed's exposure start, in window time."""
        return float(self.best_seed.index - self.first)

    def oriented(
        self, spin: torch.Tensor, rotation: torch.Tensor | None = None, at: float | None = None
    ) -> TrajectoryParams:
        """The seeds' path turning at ``spin`` (3,) rad per frame interval and holding
        ``rotation`` (3, 3) at window time ``at`` whatever the spin (default: the best seed's
        orientation at its frame's start); the base path, changed in place."""
        rotation = self.best_seed.state.motion.rot0 if rotation is None else rotation
        at = self.seed_time if at is None else at
        self.path.load_rotation(axis_angle_to_matrix(-at * spin) @ rotation.to(spin), spin)
        return self.path

    def poses(self, spin: torch.Tensor, start: ShapedStart | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(F, T, 3, 3) rotations and (F, T, 3) positions of the frames on the seeds' path at
        ``spin``, oriented and sized as ``start`` says (default: as the best seed)."""
        with torch.no_grad():
            if start is None:
                return self.oriented(spin)(self.frame_times, self.taus)
            rotations, positions = self.oriented(spin, start.rotation, self.shape_time)(self.frame_times, self.taus)
            return rotations, positions / self.scale_for(start)

    @property
    def shape_time(self) -> float:
        """When a shaped start holds its orientation: the middle of the best seed's exposure."""
        return self.seed_time + 0.5 * float(self.path.exposure().detach())

    @property
    def seed_spins(self) -> torch.Tensor:
        """(S, 3) the seeds' spins per frame interval."""
        return torch.stack([s.state.motion.omega / self.exposure_fraction for s in self.seeds]).float()

    def px_per_unit(self) -> float:
        """The apparent size of one object unit on the seeds' path at :attr:`shape_time`, in pixels."""
        with torch.no_grad():
            t = torch.tensor([self.shape_time], device=self.device)
            _, position = self.path(t, torch.zeros(1, device=self.device))
        return self.path.camera.fy / float(position[0, 0, 2])

    def scale_for(self, start: ShapedStart) -> float:
        """How much nearer the seeds' path must bring an object for ``start.size_px`` pixels per
        unit at the best seed's frame (positions divide by it)."""
        return start.size_px / self.px_per_unit()

    def footprint(self) -> Footprint:
        """The object's outline that the window's streaks show on the seeds' path."""
        # Eight points over the exposure follow a curved path's arc, not only its chord.
        taus = torch.linspace(0.0, 1.0, 8, device=self.device)
        with torch.no_grad():
            _, positions = self.path(self.frame_times, taus)
        tracks = torch.stack([f.crop.camera.project(p)[0] for f, p in zip(self.frames, positions, strict=True)])
        reference = next(k for k, f in enumerate(self.frames) if f.index == self.best_seed.index)
        return footprint([f.crop for f in self.frames], tracks, reference, float(self.path.camera.fy))


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


def window_candidate(
    window: WindowStart, start: ShapedStart | None, spin: SpinScore | None = None, rigid: bool = False
) -> Optimisation:
    """One candidate's optimisation on a copy of the window's path.

    Args:
        start: None for the best seed's mesh, texture and orientation, else a prototype
            stretched, turned and sized to the window's footprint (or the seed's, undeformed).
        spin: a searched spin and its texture, else the best seed's spin (and, for a shaped
            start, a grey texture).
        rigid: the mesh held (its pose, path and texture learnt): the shape trial's start,
            whose deformation rounded a box's corners off within the fit (box_fill 0.99 ->
            0.39) and lowered the outlines' TIoU (benchmarks/RESULTS.md, issue 32).
    """
    fit_config, config, seed = window.fit_config, window.config, window.best_seed
    learnt = (fit_config.deform and not rigid, fit_config.learn_texture)
    turning = seed.state.motion.omega / window.exposure_fraction if spin is None else spin.spin
    rest = None
    if start is None:
        window.oriented(turning)
        _, topology = load_prototype(seed.prototype)
        shape = ShapeParams(seed.state.vertices, topology, seed.state.texture.shape[-1], *learnt)
        texture = seed.state.texture
    else:
        window.oriented(turning, start.rotation, window.shape_time)
        topology, rest = start.topology, start.vertices
        shape = ShapeParams(start.vertices, topology, fit_config.texture_size, *learnt)
        texture = None
    path = copy.deepcopy(window.path)
    if start is not None:
        with torch.no_grad():
            path.anchors_raw[:, 2] += math.log(window.scale_for(start))
    if spin is not None:
        texture = upsample_texture(spin.texture.cpu(), shape.texture_logits.shape[-1])
    if texture is not None:
        seed_texture(shape, texture)
    shape.topology = topology.to(window.device)
    shape, path = shape.to(window.device), path.to(window.device)
    rest = None if rest is None else rest.to(window.device)
    rotation = (path.quat0, path.spin_raw)
    groups = [
        {"params": [p for p in shape.parameters() if p.requires_grad]},
        {"params": [path.anchors_raw], "lr": config.lr_path},
        {"params": [p for p in rotation if p.requires_grad], "lr": fit_config.lr_rotation},
        {"params": [path.exposure_raw] if path.exposure_raw.requires_grad else [], "lr": config.lr_exposure},
    ]
    # A start sized or placed from a degenerate footprint or path (the log of a scale that is
    # not a number): Adam would only spread the NaN from the first step on.
    name = f"the {'seed' if start is None else start.name} start"
    for p in [*shape.parameters(), *path.parameters(), *([] if rest is None else [rest])]:
        check_finite(p, name, DivergenceError)
    optimiser = torch.optim.Adam([g for g in groups if g["params"]], lr=fit_config.lr, fused=True)
    return Optimisation(WindowObjective(window, shape, path, rest), optimiser, config.iterations)


def score_shape(
    window: WindowStart, start: ShapedStart, spin: torch.Tensor, render_config: RenderConfig, texels: int | None = None
) -> SpinScore:
    """How well ``start`` at ``spin`` (3,) explains the window: the residual of its best coarse
    texture (:func:`sfb_video.fitting.spin.score_spin`; ``texels`` a side, default
    ``joint.spin_texture``), the same measure for every prototype."""
    config = window.config
    vertices, topology = start.vertices.to(window.device), start.topology.to(window.device)
    crops = [f.crop for f in window.frames]
    size = config.spin_texture if texels is None else texels
    args = (crops, vertices, topology, size, config.spin_smoothness, render_config)
    try:
        return score_spin(spin.to(window.device), lambda s: window.poses(s, start), *args)
    except PoseError:
        # Sized to the footprint, the shape would reach behind the camera: it explains nothing.
        return SpinScore(spin, math.inf, torch.zeros(3, size, size, device=window.device))


def trial_shapes(
    window: WindowStart, names: tuple[str, ...], render_config: RenderConfig
) -> tuple[list[tuple[ShapedStart, SpinScore]], dict[str, float]]:
    """The prototypes whose starts at the window's footprint explain its frames best, each at
    the spin a coarse search finds for it with its score there, best first, and every
    prototype's residual relative to the sphere's.

    Each shape gets its own spin: a box, a pen or a ring explains the frames only once it turns
    as the object did, and at one spin for all (the seeds') the trial chose a box for a ball and
    a sphere for a box. The choice is kept honest twice over: a long or flat prototype enters
    only when the footprint shows the evidence for it (:data:`sfb_video.fitting.shapes.NEEDS`;
    a ball's streaks are explained about as well by a disc seen face on or a short capsule, and
    the trial chose them for balls), and a prototype other than the sphere must beat it by
    ``joint.shape_margin``. Prototypes left out have no residual.

    The best comes first; the others within ``joint.shape_race`` of it follow, for the window's
    fit to race: a box's capsule and a key's torus stood within 10% of the sphere, and the
    interpolation of a registered (shaken) clip's frames alone flipped the choice.
    """
    config = window.config
    outline = window.footprint()
    near = torch.cat((torch.zeros(1, 3), window.seed_spins)).to(window.device)
    shown = [n for n in names if n not in NEEDS or outline.shows(NEEDS[n])]
    starts = {name: shaped_start(name, outline) for name in dict.fromkeys(("sphere", *shown))}

    def search(
        start: ShapedStart, grid: torch.Tensor, refine: tuple[float, ...], known: tuple[SpinScore, ...] = ()
    ) -> SpinScore:
        def score(spin: torch.Tensor) -> SpinScore:
            return score_shape(window, start, spin, render_config, config.shape_texture)

        return search_spin(grid, score, refine, known)[0]

    scores = {name: search(start, near, ()) for name, start in starts.items()}
    if config.spin_magnitudes and window.fit_config.max_rotation_deg > 0:
        # Shapes far behind at the seeds' spins are not searched further: a capsule for a ball
        # stays 5 times the sphere's residual at any spin.
        best_near = min(s.residual for s in scores.values())
        coarse = spin_grid(config.spin_magnitudes, config.shape_spin_axes)[1:].to(near)
        for name, start in starts.items():
            if scores[name].residual < SHAPE_PRUNE * best_near or name == "sphere":
                # The seeds' spins were scored above: their best stands in for them.
                scores[name] = search(start, coarse, config.spin_refine[:1], (scores[name],))
    sphere = scores["sphere"].residual
    weighed = {n: s.residual / (1.0 if n == "sphere" else 1 - config.shape_margin) for n, s in scores.items()}
    ranked = sorted(weighed, key=weighed.__getitem__)
    near_best = [n for n in ranked if weighed[n] <= (1 + config.shape_race) * weighed[ranked[0]]]
    contenders = [(starts[n], scores[n]) for n in near_best or ranked[:1]]
    return contenders, {name: s.residual / max(sphere, 1e-12) for name, s in scores.items()}


def trial_margin(shapes: dict[str, float], chosen: str) -> float | None:
    """How clearly ``chosen`` won the trial whose residuals (relative to the sphere's) are
    ``shapes``: 1 - its residual over the best other's. Positive where it scored lowest; negative
    where it was kept though another scored lower (the sphere within ``joint.shape_margin`` of a
    complex shape, or a raced contender that won on its fit). None without a trial to judge by
    (no other shape tried, or the chosen one not among them)."""
    others = [v for n, v in shapes.items() if n != chosen]
    if chosen not in shapes or not others or min(others) <= 0:
        return None
    return 1 - shapes[chosen] / min(others)


def searched_spin(
    window: WindowStart, start: ShapedStart, render_config: RenderConfig, around: SpinScore | None = None
) -> SpinScore:
    """The spin (and texture) that best explains the window's frames on the seeds' path, searched
    on an undeformed prototype: searched on the single-frame fit's mesh, deformed to explain one
    frame's blur, the spin came out 40 degrees off, on the prototype 4 (tests/fitting/test_window.py's clip).

    The search scores the grid of ``joint.spin_magnitudes`` and the seeds' spins, or only
    ``around`` (the shape trial's spin), then refines the best by ``joint.spin_refine``; the
    texture is solved at ``joint.spin_texture``."""
    config = window.config
    if around is None:
        grid = torch.cat((spin_grid(config.spin_magnitudes, config.spin_axes), window.seed_spins))
    else:
        grid = around.spin[None]
    score = functools.partial(score_shape, window, start, render_config=render_config)
    return search_spin(grid.to(window.device), score, config.spin_refine)[0]


def seed_prototype(window: WindowStart) -> ShapedStart:
    """The best seed's prototype, undeformed, in its orientation and at its size."""
    vertices, topology = load_prototype(window.best_seed.prototype)
    motion = window.best_seed.state.motion
    rotation = axis_angle_to_matrix(0.5 * motion.omega) @ motion.rot0  # at the exposure's middle
    return ShapedStart(window.best_seed.prototype, vertices, topology, rotation, window.px_per_unit())


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
        prototypes: the prototypes the footprint's trial chooses among (:func:`trial_shapes`),
            without ``shape_from`` only; the chosen one, its spin refined (``config.spin_refine``)
            and with its texture, starts the fit (alone, or raced against the trial's near
            ties). Without a trial, the best seed's prototype at the spin searched on it
            (``config.spin_magnitudes``) competes with the best seed's mesh for the first
            ``config.trial_fraction`` of the steps, and the lowest mean L_I goes on.
        shape_from: the seed whose mesh, texture and rotation the fit starts from (default: the
            seed with the lowest L_I); the previous window of a track hands its shape on so.
        on_step: called with (step, joint loss terms) after every step of the kept candidate
            (and of every candidate during the trials).

    Raises:
        DivergenceError: when no finite path fits the seeds, no candidate starts from a finite
            state (one that does not is left out), or every candidate's loss is non-finite from
            its first step.
    """
    started = time.perf_counter()
    with stage("joint: path"):
        window = start_window(frames, seeds, camera, fit_config, config, render_config, exposure_fraction, shape_from)
    searching = shape_from is None and bool(config.spin_magnitudes) and fit_config.max_rotation_deg > 0
    shapes: dict[str, float] = {}
    with seeded(fit_config.seed), deterministic(window.device):
        # Spins are searched on the seeds' path, not on the one of a trial: a trial from a wrong
        # spin bends the path to fit it, and the search then finds a wrong spin that explains the
        # frames better than the true one on the seeds' path (40 degrees off against 4).
        if prototypes and shape_from is None:
            # The shapes the streaks choose start the fit without the seeds' mesh: against it,
            # fitted for hundreds of steps to each frame, no fresh start wins a short race
            # (measured on `synthetic`: the seeds won every one, a box staying a torus).
            with stage("joint: shape trial"):
                contenders, shapes = trial_shapes(window, prototypes, render_config)
            fits: dict[str, Optimisation] = {}
            for start, spin in contenders:
                if searching:
                    with stage("joint: spin search"):
                        spin = searched_spin(window, start, render_config, around=spin)
                _add(fits, f"shape:{start.name}", functools.partial(window_candidate, window, start, spin, rigid=True))
            if not fits:  # no shaped start was finite: the seeds' mesh goes on
                _add(fits, f"seed:{window.best_seed.prototype}", functools.partial(window_candidate, window, None))
        else:
            fits = {}
            _add(fits, f"seed:{window.best_seed.prototype}", functools.partial(window_candidate, window, None))
            if searching:
                start = seed_prototype(window)
                with stage("joint: spin search"):
                    spin = searched_spin(window, start, render_config)
                _add(fits, f"spin:{start.name}", functools.partial(window_candidate, window, start, spin))
        if not fits:
            raise DivergenceError("no candidate of the window starts from a finite state")
        trial = max(1, round(config.trial_fraction * config.iterations)) if len(fits) > 1 else None
        with stage("joint: steps"):
            key, trials = race(fits, trial, on_step)
    fit = fits[key]
    best = fit.restore()
    shape, path = fit.objective.modules
    with torch.no_grad():
        vertices, texture = shape.vertices().cpu(), shape.texture().cpu()
    prototype = key.split(":")[-1]
    return JointResult(
        prototype=prototype,
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
        shapes=shapes,
        shape_margin=trial_margin(shapes, prototype) if key.startswith("shape:") else None,
    )


def _add(fits: dict[str, Optimisation], key: str, make: Callable[[], Optimisation]) -> None:
    """``fits[key] = make()``, unless the candidate's start is not finite (left out, said on stderr)."""
    try:
        fits[key] = make()
    except DivergenceError as exc:
        print(f"joint fit: {exc}; left out of the window's candidates", file=sys.stderr)


@timed("joint: refine")
def refine_frames(
    result: JointResult,
    frames: list[WindowFrame],
    fit_config: FitConfig,
    render_config: RenderConfig,
    pose: bool = False,
    iterations: int | None = None,
    held: Collection[int] = (),
) -> JointResult:
    """Each frame refined from the joint fit: the shared mesh held (the window stays one
    object), the frame's own texture (and, with ``pose``, its pose) fitted from the joint fit's,
    as a warm start that stops on a plateau. One texture for six frames explains each of them
    less well than its own would; the refined frame keeps the joint fit's shape (and place) and
    takes back what the frame alone can tell (its shading; its exact pose).

    Args:
        iterations: at most this many steps a frame (None: ``fit_config.warm_iterations``).
        held: the frames whose pose stays the joint fit's even with ``pose``: their texture only.

    Returns:
        ``result`` with ``refined`` holding every frame's texture, motion and loss terms.
    """
    steps = fit_config.warm_iterations if iterations is None else iterations
    config = dataclasses.replace(fit_config, deform=False, learn_motion=pose, warm_iterations=steps)
    texture_only = dataclasses.replace(config, learn_motion=False)
    refined = {}
    for frame in frames:
        motion = result.trajectory.frame_motion(frame.index)
        warm = WarmStart(result.prototype, result.vertices, result.texture, motion, at_streak=False)
        fit = fit_frame(frame.crop, texture_only if frame.index in held else config, render_config, warm, frame.masks)
        state = fit.state
        refined[frame.index] = Refined(state.texture.cpu(), state.motion.to("cpu"), fit.losses)
    return dataclasses.replace(result, refined=refined)
