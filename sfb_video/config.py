"""Typed configuration: one dataclass per part; YAML presets fill them in.

A preset is a YAML file whose top-level keys name the sections below; anything left out keeps
its default. The presets ``default`` and ``fast`` ship inside the package (the repository's
``configs/`` folder is that package, ``sfb_video.configs``); any other YAML file can be given by
its path. Overrides use dotted keys (``render.sigma_inv=3000``). The resolved config is written
into every output folder so that a run can be replayed.

Every number has its valid range next to its default (:func:`bounded`), checked whenever a
config is built, so a bad value is refused with the field's name before any work starts. Why
each default has the value it has, measured, is in ``benchmarks/RESULTS.md``.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import yaml

from sfb_video.atomic import atomic_write_bytes
from sfb_video.errors import ConfigError
from sfb_video.geometry.prototypes import PROTOTYPE_NAMES

PRESETS = "sfb_video.configs"
"""The package that holds the named presets (``<name>.yaml``)."""


def bounded(default: Any, *, ge: float | None = None, gt: float | None = None, le: float | None = None) -> Any:
    """A numeric field (or tuple of numbers) whose every value must be >= ``ge``, > ``gt``, <= ``le``."""
    return field(default=default, metadata={"ge": ge, "gt": gt, "le": le})


def one_of(default: Any, choices: tuple[str, ...], may_be_empty: bool = False) -> Any:
    """A text field (or tuple of texts, non-empty unless ``may_be_empty``) whose every value must
    be one of ``choices``."""
    return field(default=default, metadata={"choices": choices, "may_be_empty": may_be_empty})


class _Checked:
    """Checks every field's range or choices when the section is built (also by ``replace``)."""

    SECTION: ClassVar[str] = ""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            values = value if isinstance(value, tuple) else (value,)
            where = f"{self.SECTION}.{f.name}"
            if "choices" in f.metadata:
                if value == () and not f.metadata["may_be_empty"]:
                    raise ConfigError(f"{where} must be a non-empty list, got []")
                bad = [v for v in values if v not in f.metadata["choices"]]
                if bad:
                    raise ConfigError(f"{where} must be one of {', '.join(f.metadata['choices'])}; got {bad[0]!r}")
            for v in values if {"ge", "gt", "le"} & set(f.metadata) else ():
                ge, gt, le = f.metadata["ge"], f.metadata["gt"], f.metadata["le"]
                if not math.isfinite(v):
                    raise ConfigError(f"{where} must be a finite number, got {v}")
                if (ge is not None and v < ge) or (gt is not None and v <= gt) or (le is not None and v > le):
                    rules = [f"{op} {b:g}" for op, b in ((">=", ge), (">", gt), ("<=", le)) if b is not None]
                    raise ConfigError(f"{where} must be {' and '.join(rules)}, got {value}")


@dataclass(frozen=True)
class CameraConfig(_Checked):
    """The one pinhole camera of a clip."""

    SECTION: ClassVar[str] = "camera"

    fov_y_deg: float = bounded(45.0, gt=0, le=179)
    """Vertical field of view in degrees, when the focal length is not given. 45 as in the SfB
    reference; only depth and speed in object sizes depend on it."""
    motion: str = one_of("auto", ("auto", "on", "off"))
    """Whether the camera may move (:mod:`sfb_video.registration`): ``on`` registers every frame
    to a reference frame before the background, detection and fit; ``auto`` does so only when
    some frame moved more than ``still_px``; ``off`` takes the camera as still."""
    still_px: float = bounded(1.0, ge=0)
    """A clip whose registered frames all move their corners less than this is still (``auto``)."""
    min_overlap: float = bounded(0.6, gt=0, le=1)
    """A frame that covers less than this share of its reference frame starts a new reference
    (a pan longer than the frame); tracks end there."""
    max_margin: float = bounded(0.5, ge=0, le=1)
    """Registered frames are drawn on the reference's view grown by how far the frames reach
    past it (:class:`sfb_video.registration.Canvas`), by at most this share of the frame's side
    on each side."""
    min_inliers: int = bounded(15, ge=4)
    """A frame registers when at least this many matched features agree on its motion."""
    features: int = bounded(1500, ge=50)
    """ORB features found per frame for its registration."""
    stabilised: bool = False
    """Write ``tsr.mp4`` in the reference frame's coordinates (the camera held still) instead of
    each frame's own."""


@dataclass(frozen=True)
class RenderConfig(_Checked):
    """The differentiable rasteriser, its soft silhouette and the exposure's discretisation."""

    SECTION: ClassVar[str] = "render"

    sigma_inv: float = bounded(7000.0, gt=0)
    """Sharpness of the soft silhouette: coverage outside is exp(-sigma_inv * d^2) at distance d
    in normalised image units (half the longer side is 1). 7000 as in the paper (DIB-R)."""
    band_eps: float = bounded(1e-4, gt=0, le=0.5)
    """Coverage below this counts as zero; it sets the width of the band where coverage is computed."""
    near: float = bounded(1e-2, gt=0)
    """Near plane in object sizes: geometry closer to the camera is an error."""
    time_steps: int = bounded(8, ge=1)
    """T, the poses that discretise one exposure in a fit (paper: 8)."""
    steps_per_subframe: int = bounded(4, ge=1)
    """Poses averaged into each rendered TSR sub-frame: enough for the blur within 1/N of an exposure."""
    max_batch_pixels: int = bounded(2_000_000, ge=1)
    """Outside the fit (exports, TSR), poses are rendered in batches of at most this many pixels
    in all (H x W x poses): the renderer's buffers grow with them."""
    export_max_width: int = bounded(400, ge=16)
    """Exports render a crop box at most this wide and scale it up to the frame. The fit saw the
    crop at most ``crop.max_width`` wide and the soft silhouette's width scales with the image,
    so rendering wider adds no detail, only time and memory (a 4K frame's crop is ~1000 px)."""


@dataclass(frozen=True)
class CropConfig(_Checked):
    """How a detection box becomes the crop a fit renders in."""

    SECTION: ClassVar[str] = "crop"

    margin: float = bounded(0.5, ge=0)
    """Growth on each side, as a fraction of the box's shorter side: about one object radius."""
    aspect: float = bounded(4 / 3, gt=0)
    """Width / height of the crop (the paper's 320x240)."""
    max_width: int = bounded(200, ge=16)
    """Crops wider than this are downsampled to it; smaller ones keep their native resolution:
    rendering cost grows with pixels, and upsampling adds none."""
    max_object_px: float = bounded(48.0, ge=0)
    """Crops are downsampled so that the object's streak is at most this many pixels across
    (:func:`sfb_video.crop.streak_width`): a 1080p phone clip's object, three times a 640x480
    clip's in pixels, is fitted in fewer pixels. Not lower: at 32 a textured ball's rotation
    and a short-exposure pen's length were lost (tests/fitting). 0: no bound but ``max_width``."""
    region_threshold: float = bounded(0.05, gt=0, le=3)
    """The object region of a crop is the largest blob of sum over RGB of |I - B| above this (the
    SfB reference's test). It finds the box of ``sfb-video fit``, starts the motion, normalises
    L_I and is the mask D of L_D. Not the detector's test (``detect.threshold``, on the L2 norm):
    this one is looser, because a mask that misses a streak's faint parts rewards shrinking."""
    region_noise: float = bounded(6.0, ge=0)
    """The object's footprint is read off the region grown into the streak's faint parts: pixels
    whose smoothed difference stands this many noise spreads above the crop's median, touching
    it (:func:`sfb_video.crop.object_region`). 0 keeps the threshold alone."""
    defmo_margin: float = bounded(1.0, ge=0)
    """Growth on each side of the window DeFMO sees, as a fraction of the box's shorter side: two
    object radii, as the SfB reference crops for DeFMO."""


@dataclass(frozen=True)
class FitConfig(_Checked):
    """Test-time optimisation of one blurred frame (paper, Sec. 3.2)."""

    SECTION: ClassVar[str] = "fit"

    prototypes: tuple[str, ...] = one_of(("sphere",), PROTOTYPE_NAMES)
    """Tried in turn from a cold start; the lowest image loss wins. One: more did not pay on
    single frames (lowest L_I does not pick the best prototype) and cost their number in time."""
    prototype_trial: float = bounded(0.2, gt=0, le=1)
    """With several prototypes, all run for this fraction of the steps, then only the one with
    the lowest image loss goes on (1: each runs to the end)."""
    deform: bool = True
    """Optimise per-vertex offsets (off: the prototype keeps its shape)."""
    learn_texture: bool = True
    """Optimise the texture (off: it keeps its start). With ``deform`` off and a warm start from
    a known object's mesh and texture, only the motion is fitted, and then its rotation is
    recovered, which one frame cannot tell apart from a free texture."""
    learn_motion: bool = True
    """Optimise the motion (off: it keeps its start, as a window's refined frames may)."""
    iterations: int = bounded(500, ge=1)
    """Adam steps of a cold start (paper: 500)."""
    warm_iterations: int = bounded(150, ge=1)
    """At most this many steps when starting from a previous frame's result."""
    lr: float = bounded(0.1, gt=0)
    """Adam's step size for the shape, texture and translation (paper: 0.1)."""
    lr_rotation: float = bounded(0.02, ge=0)
    """Adam's step size for the rotations R0 and omega. Smaller than ``lr``: the image loss
    hardly tells rotations apart, and at 0.1 they wander and the texture chases them."""
    plateau_patience: int = bounded(40, ge=1)
    """Stop when the best image loss has not improved for this many steps ..."""
    plateau_tolerance: float = bounded(1e-3, ge=0)
    """... by more than this fraction."""
    texture_size: int = bounded(100, ge=2)
    """Side of the square texture map in texels (paper: 100)."""
    size_range: tuple[float, float] = bounded((0.05, 1.0), gt=0, le=1)
    """Apparent diameter bounds at the start, as fractions of the crop height (paper: 5% to 100%)."""
    max_size_ratio: float = bounded(1.5, ge=1)
    """Bound on how much the apparent size may change within one exposure (end / start): without
    it a fit can fade an unexplained streak out by sending one end far away."""
    init_size: float = bounded(0.4, gt=0, le=1)
    """Initial apparent diameter, as a fraction of the crop height."""
    max_rotation_deg: float = bounded(120.0, ge=0, le=180)
    """Cap on the rotation during one exposure (paper: 120 degrees); 0 fits no rotation."""
    w_image: float = bounded(1.0, ge=0)
    """Weight of L_I, the L1 reconstruction loss."""
    w_silhouette: float = bounded(1.0, ge=0)
    """Weight of L_S, the IoU with given sub-frame masks (used only when masks are given)."""
    w_difference: float = bounded(0.3, ge=0)
    """Weight of L_D, the IoU of the swept silhouette with the object mask (used without masks).
    Below the paper's 1: with the streak's start it pulls shapes a prototype cannot take (pens,
    keys) towards the mask at the expense of L_I; at 0 depth drifts."""
    difference_fade: float = bounded(0.8, gt=0)
    """L_D's weight falls linearly from ``w_difference`` to 0 at this fraction of the steps. D
    thresholds |I - B|: it places the streak well but misses the faint parts a thin, turning
    object leaves, and held to the end it fattens the object. Above 1 it never reaches 0."""
    w_texture: float = bounded(1.0, ge=0)
    """Weight of L_T, the texture's total variation."""
    w_laplacian: float = bounded(1000.0, ge=0)
    """Weight of L_L, the Laplacian smoothness of the vertices (paper: 1000): it also keeps
    depth stable and the mesh cheap to render."""
    seed: int = bounded(0, ge=0)
    """Seed of the fit's random initialisation."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.size_range[0] >= self.size_range[1]:
            raise ConfigError(f"fit.size_range must be (low, high) with low < high, got {self.size_range}")
        weights = ("w_image", "w_silhouette", "w_difference", "w_texture", "w_laplacian")
        if not any(getattr(self, w) for w in weights):
            raise ConfigError(f"fit: every loss weight ({', '.join(weights)}) is 0, so there is nothing to fit")


@dataclass(frozen=True)
class JointConfig(_Checked):
    """The joint fit of a window of frames of one track (:mod:`sfb_video.fitting.window`)."""

    SECTION: ClassVar[str] = "joint"

    enabled: bool = True
    """Refit each window of a track jointly after its single-frame fits (off: the single-frame
    results are the output, as before the joint fit existed)."""
    window: int = bounded(6, ge=2)
    """Frames per window; a track's windows slide by ``window - overlap``."""
    overlap: int = bounded(2, ge=0)
    """Frames a window shares with the previous one of its track."""
    iterations: int = bounded(200, ge=1)
    """Adam steps of a window's joint fit."""
    frames_per_step: int = bounded(3, ge=0)
    """Frames of the window each step renders, in turn (every frame seen every few steps); 0: all."""
    path_steps: int = bounded(300, ge=0)
    """Steps fitting the trajectory to the seeds' streak ends before the joint fit (no rendering)."""
    motion: str = one_of("auto", ("auto", "constant_velocity", "constant_acceleration", "bounce"))
    """The trajectory's model; ``auto`` takes constant acceleration, or a bounce where one
    smooth path misses a seed's streak end by more than ``bounce_residual`` and a path broken in
    one gap between exposures brings every end within it (:func:`sfb_video.fitting.path.choose_motion`)."""
    bounce_residual: float = bounded(0.15, gt=0)
    """``auto`` motion: a bounce is tried when one smooth path passes farther than this from a
    seed's streak end, in apparent object diameters."""
    prototypes: tuple[str, ...] = one_of(
        ("sphere", "capsule", "box", "disc", "torus"), PROTOTYPE_NAMES, may_be_empty=True
    )
    """The shapes a track's first window chooses among, each stretched, turned and sized to the
    footprint its streaks show (:mod:`sfb_video.fitting.shapes`) and scored by its best coarse
    texture; the chosen one starts the window's fit alone. Empty: keep the seeds' mesh."""
    shape_spin_axes: int = bounded(8, ge=1)
    """Axes of the coarse spin grid (at ``spin_magnitudes``) that each shape of the trial is
    scored at; the chosen shape's spin is then refined by ``spin_refine``."""
    shape_texture: int = bounded(16, ge=2)
    """Texels a side of the shape trial's texture: coarse, so that the outline decides."""
    shape_margin: float = bounded(0.05, ge=0, le=0.5)
    """A prototype other than the sphere is chosen only where its residual is this fraction
    below the sphere's."""
    shape_race: float = bounded(0.0, ge=0, le=1)
    """The trial's prototypes within this fraction of the best one's residual (after
    ``shape_margin``) start a fit each, raced for ``trial_fraction`` of the steps on their L_I;
    0: the best alone."""
    refine: str = one_of("pose", ("off", "texture", "pose"))
    """After a window's joint fit, refine each of its frames from it, the shared mesh held:
    ``texture`` fits the frame's own texture on the window's trajectory, ``pose`` its texture
    and pose (stopping on a plateau; a frame whose streak touched another object's, which holds
    both objects' pixels shared out by nearness, its texture only); ``off`` keeps the window's."""
    refine_iterations: int = bounded(75, ge=1)
    """At most this many steps for each refined frame, and no more than ``fit.warm_iterations``
    (each is a warm start from the window's fit)."""
    laplacian_end: float = bounded(0.1, gt=0, le=1)
    """The Laplacian's weight falls geometrically over the joint fit from ``fit.w_laplacian`` to
    this fraction of it (1: constant)."""
    trial_fraction: float = bounded(0.2, gt=0, le=1)
    """The share of ``iterations`` every competing shape is fitted before the choice."""
    max_explained_drop: float = bounded(0.15, ge=0)
    """A window's joint fit stands for its frames when it explains their difference from the
    background (``explained`` in summary.json, the mean over the window) at most this much less
    than their single-frame fits do; otherwise they keep the single-frame fits (a path that the
    trajectory's model cannot follow, such as a circular swing over the window). A frame that an
    accepted window explains more than this much worse than its single-frame fit keeps that fit
    (a frame whose pose the window held: only where it explains less than half as much too)."""
    learn_exposure: bool = True
    """Learn the exposure fraction (shared by the window) from ``video.exposure_fraction``;
    off keeps that value."""
    spin_magnitudes: tuple[float, ...] = bounded((30.0, 60.0, 90.0), ge=0, le=180)
    """A track's first window searches the spin (per frame interval, degrees) over these
    magnitudes about ``spin_axes`` axes, and the seeds' spins and none, by the residual of the
    best coarse texture (:mod:`sfb_video.fitting.spin`); empty: start from the best seed's spin."""
    spin_axes: int = bounded(20, ge=1)
    """Axes of the spin search's grid, spread evenly over the sphere."""
    spin_refine: tuple[float, ...] = bounded((15.0, 7.5), gt=0)
    """The pattern search's steps after the grid (degrees per frame interval), largest first."""
    spin_texture: int = bounded(32, ge=2)
    """Texels a side of the spin search's texture: a finer one explains the frames with a
    wrong spin too."""
    spin_smoothness: float = bounded(1e-3, ge=0)
    """Weight of the squared texel differences in the spin search's texture solve."""
    lr_path: float = bounded(0.02, gt=0)
    """Adam's step size for the trajectory's anchors (in reference diameters and log size)."""
    lr_exposure: float = bounded(0.05, gt=0)
    """Adam's step size for the exposure fraction's logit."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.overlap >= self.window:
            raise ConfigError(f"joint.overlap must be less than joint.window, got {self.overlap} >= {self.window}")


@dataclass(frozen=True)
class VideoConfig(_Checked):
    """Reading a clip, its background and the timing of its exposures."""

    SECTION: ClassVar[str] = "video"

    background: str = one_of("running", ("running", "global"))
    """``running``: median of the previous ``background_window`` frames (the next ones at the
    start of the clip); ``global``: median of ``global_samples`` frames spread over the clip."""
    background_window: int = bounded(5, ge=1)
    """K, the frames in the running median (paper: 5)."""
    global_samples: int = bounded(25, ge=1)
    """Frames in the global median."""
    exposure_fraction: float = bounded(1.0, gt=0, le=1)
    """Share of the frame interval the shutter is open. The motion is continued across the gap
    (1 / fraction - 1 exposures long) to predict the next frame's start."""
    tsr: int = bounded(8, ge=1)
    """Sub-frames rendered per blurred frame in ``tsr.mp4``."""
    warm_start: bool = True
    """Start each frame of a track from the previous frame's result (off: every frame cold)."""
    max_objects: int = bounded(0, ge=0)
    """Objects tracked at once: every fast mover has its own track, up to this many (0: all);
    1 follows one object, the others left in a frame's note. Beside a tracked object, a blob
    starts a track only when it is an object of its own, not a shred of a slow mover or a
    shadow (:meth:`~sfb_video.stages.detect.FrameBlobs.own_object`)."""
    min_track_frames: int = bounded(3, ge=1)
    """A track fitted in fewer frames than this is not an object (a flicker, a shred of an arm)
    and is left out of the outputs, unless no track of the clip is longer."""
    track_prototypes: tuple[str, ...] = one_of(("sphere", "sphere_large", "torus"), PROTOTYPE_NAMES)
    """Prototypes tried on the first frame of a track (the paper's cold start tries them all);
    other cold starts use ``fit.prototypes``."""
    retry_ratio: float = bounded(2.0, gt=0)
    """A warm fit whose image loss exceeds the previous frame's by this factor is redone cold,
    and the better of the two kept."""
    min_explained: float = bounded(0.5, le=1)
    """A fitted frame whose fit explains less than this share of the frame's difference from
    its background around the object (``explained`` in summary.json) is listed as unexplained
    and warned about: a fragment of the streak fitted, or something else fitted."""
    max_side: int = bounded(4096, ge=16)
    """Frames larger than this on a side are refused."""


@dataclass(frozen=True)
class DetectConfig(_Checked):
    """Finding the fast moving object among the blobs of the difference image."""

    SECTION: ClassVar[str] = "detect"

    threshold: float = bounded(0.1, gt=0, le=math.sqrt(3))
    """||I - B||_2 over RGB (in [0, 1]) above this marks a pixel as differing from the
    background (the paper's D). Not the fit's object region (``crop.region_threshold``)."""
    weak_threshold: float = bounded(0.04, gt=0, le=math.sqrt(3))
    """Hysteresis: pixels differing by more than this (or ``weak_noise`` times the frame's
    median difference, whichever is larger, up to ``threshold``) are kept where they connect to
    pixels above ``threshold``, so the faint half of a streak stays with its strong half."""
    weak_noise: float = bounded(4.0, ge=0)
    """See ``weak_threshold``: the multiple of the frame's median difference (its noise level)
    below which no pixel is kept."""
    open_px: int = bounded(3, ge=1)
    """Side of the square that opens the difference mask, removing specks of noise (1: none)."""
    merge_px: int = bounded(3, ge=0)
    """Fragments of the moving mask less than twice this apart count as one blob (a streak cut
    by a fence's bars or by a background of its own colour)."""
    min_area_px: int = bounded(20, ge=1)
    """Blobs smaller than this are noise."""
    min_fill: float = bounded(0.3, ge=0, le=1)
    """A tracked object's blob must cover at least this fraction of the disc it is predicted to
    be; smaller blobs are noise or the remains of a slow mover."""
    motion_px: int = bounded(6, ge=0)
    """Neighbouring masks are grown by this much before their pixels are dropped, so that an
    object creeping a few pixels per frame is dropped too."""
    gate: float = bounded(4.0, gt=0)
    """A tracked object is looked for within this many object diameters of where its motion
    predicts it; a blob further away starts a new track."""
    colour_scale: float = bounded(0.05, gt=0)
    """A tracked object's blob is preferred by its colour too: a blob whose chromaticity
    (r, g, b summing to 1) lies this far from the track's counts half as much (0.05 separates
    a yellow ball from skin, about 0.2 away, and from a grey wall's shadow, about 0.08)."""
    merge_overlap: float = bounded(0.2, gt=0, le=1)
    """Fragments whose boxes share at least this share of the smaller box are one blob (the two
    sides of a ring's streak); a shred of an arm beside a ball overlaps it little if at all."""
    shred_ratio: float = bounded(1.25, ge=1)
    """A blob whose changed regions (slow movers' pixels kept) hold more than this times its own
    area is a shred of a larger mover (an arm's fast fringe), not an object of its own."""
    shade_chroma: float = bounded(0.06, ge=0)
    """A shade (a shadow, a flicker of the light): a blob whose strongest quarter's chromaticity
    differs from the background's by at most this (L1)..."""
    shade_contrast: float = bounded(0.14, gt=0)
    """... and whose mean difference there (||I - B|| over RGB in [0, 1]) is under this."""
    shade_penalty: float = bounded(4.0, ge=1)
    """A shade weighs this many times less as a tracked object than another blob: a grey
    object's faint streaks are shades too, and still taken where nothing else is."""
    parallel_deg: float = bounded(30.0, ge=0, le=90)
    """Two streaks (or paths) whose directions differ by at most this many degrees are parallel."""
    aligned: float = bounded(0.5, ge=0, le=1)
    """Parallel cores of a blob whose extents along their axis share at least this much of the
    shorter are one object (a ring's two sides); less, they are objects side by side."""
    core_close_px: int = bounded(3, ge=1)
    """Side of the square that closes a blob's strong pixels before its cores are found (a
    textured object's strong pixels are patchy)."""
    core_share: float = bounded(0.25, gt=0, le=1)
    """A blob's strong core counts from this share of its largest core's area."""


@dataclass(frozen=True)
class TrackConfig(_Checked):
    """Following each object from frame to frame (the detection section's ``gate`` and
    ``colour_scale`` choose among the blobs)."""

    SECTION: ClassVar[str] = "track"

    lag_diameters: float = bounded(2.0, ge=0)
    """A track's 3D guess that lags this many object diameters behind its image pace, along the
    pace's line, is followed only where no other guess finds a blob."""
    max_coast: int = bounded(5, ge=0)
    """Frames a track goes on through while its streak is merged into, or shared with, another's."""
    colour_memory: float = bounded(0.7, ge=0, le=1)
    """A track's colour is this share its own and the rest its latest blob's."""
    other_share: float = bounded(0.1, gt=0, le=1)
    """A blob no track takes starts a track only from this share of the frame's largest blob."""
    share_cost: float = bounded(0.7, ge=0)
    """What a track pays on top of a blob's cost to share it with another track that takes it: as
    much as a miss of one object diameter (``log 2``). A track goes to a blob left in its gate
    rather than share where that costs less; a track does not leave its own blob for a far one
    so that another need not share it."""
    fallback_cost: float = bounded(50.0, ge=0)
    """What a track pays on top of a blob's cost where only a fallback guess reaches it: above
    sharing a blob, so that it follows a fallback guess only where nothing else is left."""
    young_coast_cost: float = bounded(0.7, ge=0)
    """What a track of one frame (its direction a guess) pays to take no blob in the contest for
    the blobs, where a track of two frames or more pays a miss at the gate's edge: as much as a
    miss of one object diameter (``log 2``). It gives its blob up to a longer track with no other."""
    look_back: int = bounded(2, ge=0)
    """Frames a newly proven track looks back for its object inside other tracks' blobs."""
    look_back_share: float = bounded(0.5, gt=0, le=1)
    """Looking back, a blob is shared out where the track's share of it and the blob's growth
    over the other track's own are each at least this share of the track's first blob."""


@dataclass(frozen=True)
class DemoConfig(_Checked):
    """The built-in demo: a short generated clip with ground truth, processed like a user's clip."""

    SECTION: ClassVar[str] = "demo"

    shape: str = one_of("ball", ("ball", "box", "pen", "ring", "key"))
    """One of the generator's shapes."""
    frames: int = bounded(8, ge=2)
    """Frames of the clip (the running median needs two)."""
    width: int = bounded(320, ge=16)
    height: int = bounded(240, ge=16)
    size_px: tuple[float, float] = bounded((24.0, 28.0), gt=0)
    """Range of the object's apparent diameter in pixels."""
    speed: tuple[float, float] = bounded((1.2, 1.5), gt=0)
    """Range of the travel per exposure, in object diameters."""
    exposure_fraction: float = bounded(0.8, gt=0, le=1)
    """The generated camera's shutter; the pipeline is told it (``video.exposure_fraction``)."""
    seed: int = bounded(0, ge=0)


@dataclass(frozen=True)
class Config:
    """Everything sfb-video can be tuned by."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    crop: CropConfig = field(default_factory=CropConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    video: VideoConfig = field(default_factory=VideoConfig)
    joint: JointConfig = field(default_factory=JointConfig)
    detect: DetectConfig = field(default_factory=DetectConfig)
    track: TrackConfig = field(default_factory=TrackConfig)
    demo: DemoConfig = field(default_factory=DemoConfig)


def _coerce(value: Any, typ: Any, where: str) -> Any:
    if dataclasses.is_dataclass(typ):
        if not isinstance(value, dict):
            raise ConfigError(f"{where} must be a mapping, got {value!r}")
        return _build(typ, value, where)
    origin = typing.get_origin(typ)
    if origin is tuple:
        args = typing.get_args(typ)
        if len(args) == 2 and args[1] is Ellipsis:
            if not isinstance(value, list | tuple):
                raise ConfigError(f"{where} must be a list, got {value!r}")
            return tuple(_coerce(v, args[0], where) for v in value)
        if not isinstance(value, list | tuple) or len(value) != len(args):
            raise ConfigError(f"{where} must be a list of {len(args)} values, got {value!r}")
        return tuple(_coerce(v, a, where) for v, a in zip(value, args, strict=True))
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in typing.get_args(typ):
            return None
        typ = next(a for a in typing.get_args(typ) if a is not type(None))
    if typ is float and isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if typ in (int, str, bool) and type(value) is typ:
        return value
    raise ConfigError(f"{where} must be {getattr(typ, '__name__', typ)}, got {value!r}")


def _build(cls: type, values: dict[str, Any], where: str) -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(values) - names
    if unknown:
        raise ConfigError(f"unknown config key {where + '.' if where else ''}{sorted(unknown)[0]}")
    kwargs = {k: _coerce(v, hints[k], f"{where}.{k}" if where else k) for k, v in values.items()}
    return cls(**kwargs)


def _set_dotted(tree: dict[str, Any], key: str, value: Any) -> None:
    *parents, leaf = key.split(".")
    for p in parents:
        tree = tree.setdefault(p, {})
        if not isinstance(tree, dict):
            raise ConfigError(f"override {key!r} goes through a non-section key")
    tree[leaf] = value


def preset_names() -> list[str]:
    """The names of the presets that ship with the package."""
    files = importlib.resources.files(PRESETS).iterdir()
    return sorted(p.name.removesuffix(".yaml") for p in files if p.name.endswith(".yaml"))


def _preset_text(preset: str | Path) -> tuple[str, str]:
    """The YAML text of a preset (a name or a file path) and how to name it in messages."""
    path = Path(preset)
    if path.suffix in (".yaml", ".yml") or path.parent != Path("."):
        if not path.is_file():
            raise ConfigError(f"config file not found: {path}")
        return path.read_text(), str(path)
    resource = importlib.resources.files(PRESETS) / f"{preset}.yaml"
    if not resource.is_file():
        names = ", ".join(preset_names())
        raise ConfigError(f"no config preset {str(preset)!r}; the presets are {names}, or give a YAML file")
    return resource.read_text(), f"preset {preset}"


def load_config(preset: str | Path = "default", overrides: list[str] | None = None) -> Config:
    """Load a preset (a name such as ``fast``, or a YAML path) and apply ``key=value`` overrides.

    Raises:
        ConfigError: a missing preset, bad YAML, an unknown key, a wrong type or a value out of
            its range, naming the field.
    """
    try:
        text, name = _preset_text(preset)
        tree = yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{preset} is not valid YAML: {str(exc).splitlines()[0]}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read the config {preset}: {exc}") from None
    if not isinstance(tree, dict):
        raise ConfigError(f"{name} must hold a mapping of config sections")
    for item in overrides or []:
        key, sep, raw = item.partition("=")
        if not sep:
            raise ConfigError(f"override {item!r} must look like section.key=value")
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(f"override {item!r}: the value is not valid YAML") from None
        _set_dotted(tree, key.strip(), value)
    return _build(Config, tree, "")


def config_to_dict(config: Config) -> dict[str, Any]:
    """The config as plain YAML-ready data (tuples become lists)."""
    return _plain(dataclasses.asdict(config))


def _plain(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, tuple | list):
        return [_plain(v) for v in x]
    return x


def save_config(path: Path, config: Config) -> None:
    """Save the resolved config beside a command's outputs (atomically), so it can be replayed."""
    atomic_write_bytes(path, yaml.safe_dump(config_to_dict(config), sort_keys=False).encode())
