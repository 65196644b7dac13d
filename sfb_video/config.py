"""Typed configuration: one dataclass per part, YAML presets in ``configs/`` fill them in.

A preset is a YAML file whose top-level keys name the sections below; anything left out keeps
its default. Overrides use dotted keys (``render.sigma_inv=3000``). The resolved config is
written into every run folder so that a run can be replayed.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sfb_video.checks import ConfigError
from sfb_video.imageio import atomic_write_bytes

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"


@dataclass(frozen=True)
class CameraConfig:
    """The one pinhole camera of a clip."""

    fov_y_deg: float = 45.0
    """Vertical field of view in degrees (the SfB reference uses 45)."""


@dataclass(frozen=True)
class RenderConfig:
    """The differentiable rasteriser and its soft silhouette."""

    sigma_inv: float = 7000.0
    """Sharpness of the soft silhouette: coverage outside is exp(-sigma_inv * d^2) at distance d
    in normalised image units (half the longer side is 1). The paper uses 7000 (DIB-R)."""
    band_eps: float = 1e-4
    """Coverage below this is treated as zero; it sets the width of the band where it is computed."""
    near: float = 1e-2
    """Near plane in object sizes: geometry closer to the camera is an error."""
    time_steps: int = 8
    """T, the number of poses that discretise one exposure (paper: 8)."""


@dataclass(frozen=True)
class CropConfig:
    """How a detection box becomes the crop a fit renders in."""

    margin: float = 0.5
    """Growth on each side, as a fraction of the box's shorter side (about one object radius)."""
    aspect: float = 4 / 3
    """Width / height of the crop (the paper's 320x240)."""
    max_width: int = 200
    """Crops wider than this are downsampled to it; smaller ones keep their native resolution."""
    detect_threshold: float = 0.05
    """sum_rgb |I - B| above this, largest blob, is the object region (as the SfB reference
    detects it). It finds the box, starts the motion, normalises L_I and is the mask D of L_D:
    the paper's D, ||I - B||_2 > 0.1, misses faint parts of a streak and so rewards shrinking
    (on 6 generated frames: TIoU 0.57 with it, 0.73 with this one)."""
    defmo_margin: float = 1.0
    """Growth on each side of the window DeFMO sees, as a fraction of the box's shorter side: two
    object radii, as the SfB reference crops for DeFMO (twice the fit's own margin)."""


@dataclass(frozen=True)
class FitConfig:
    """Test-time optimisation of one blurred frame (paper, Sec. 3.2)."""

    prototypes: tuple[str, ...] = ("sphere",)
    """Tried in turn from a cold start; the lowest image loss wins."""
    deform: bool = True
    """Optimise per-vertex offsets (off: the prototype keeps its shape)."""
    learn_texture: bool = True
    """Optimise the texture (off: it keeps its start, grey or a warm start's). With ``deform`` off
    and a warm start from a known object's mesh and texture, only the motion is fitted: then its
    rotation is recovered, which one frame cannot tell apart from a texture that is free."""
    iterations: int = 500
    """Adam steps of a cold start."""
    warm_iterations: int = 150
    """At most this many steps when starting from a previous frame's result."""
    lr: float = 0.1
    """Adam's step size for the shape, texture and translation (paper: 0.1)."""
    lr_rotation: float = 0.02
    """Adam's step size for the rotations R0 and omega. At 0.1 they wander on a loss that hardly
    tells rotations apart, and the texture and silhouette chase them: on ten generated frames TIoU
    was 0.49 with 0.1, 0.56 with 0.02 and 0.54 with 0.01 (benchmarks.fit frames, seeds 1-2)."""
    plateau_patience: int = 40
    """Stop when the best image loss has not improved for this many steps ..."""
    plateau_tolerance: float = 1e-3
    """... by more than this fraction."""
    texture_size: int = 100
    size_range: tuple[float, float] = (0.05, 1.0)
    """Apparent diameter bounds at the start, as fractions of the crop height (paper: 5% to 100%)."""
    max_size_ratio: float = 1.5
    """Bound on how much the apparent size may change within one exposure (end / start)."""
    init_size: float = 0.4
    """Initial apparent diameter, as a fraction of the crop height."""
    max_rotation_deg: float = 120.0
    """Cap on the rotation during one exposure (paper: 120 degrees); 0 fits no rotation."""
    w_image: float = 1.0
    """Weight of L_I, the L1 reconstruction loss."""
    w_silhouette: float = 1.0
    """Weight of L_S, the IoU with given sub-frame masks (used only when masks are given)."""
    w_difference: float = 0.3
    """Weight of L_D, the IoU of the swept silhouette with the object mask (used without masks).
    Below the paper's 1: with the streak start it pulls shapes a prototype cannot take (pens,
    keys) towards the mask at the expense of L_I; on 5 generated shapes weight 1 gave TIoU 0.57,
    0.3 gave 0.61 and 0 gave 0.69 but let depth drift (translation error 0.71, 0.66, 2.55)."""
    difference_fade: float = 0.8
    """L_D's weight falls linearly from ``w_difference`` at the first step to 0 at this fraction
    of the iterations, and stays 0 after. D thresholds |I - B|, so it places the streak well but
    misses its faint parts, which a thin, turning object (a pen) leaves everywhere: held to the
    end it fattens the object. Fading it lets L_I shape the object once it is in place (15
    generated frames: TIoU 0.60 -> 0.63; the seed-0 pen 0.55 -> 0.96). A large value keeps it."""
    w_texture: float = 1.0
    """Weight of L_T, the texture's total variation."""
    w_laplacian: float = 1000.0
    """Weight of L_L, the Laplacian smoothness of the vertices (paper: 1000)."""
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.difference_fade > 0:
            raise ConfigError(f"fit.difference_fade must be positive, got {self.difference_fade}")


@dataclass(frozen=True)
class VideoConfig:
    """Reading a clip, its background and the timing of its exposures."""

    background: str = "running"
    """``running``: median of the previous ``background_window`` frames (the next ones at the
    start of the clip); ``global``: median of ``global_samples`` frames spread over the clip."""
    background_window: int = 5
    """K, the frames in the running median (paper: 5)."""
    global_samples: int = 25
    exposure_fraction: float = 1.0
    """Share of the frame interval the shutter is open. The motion is continued across the gap
    (1 / fraction - 1 exposures long) to predict the next frame's start."""
    tsr: int = 8
    """Sub-frames rendered per blurred frame in ``tsr.mp4``."""
    warm_start: bool = True
    """Start each frame of a track from the previous frame's result (off: every frame cold)."""
    track_prototypes: tuple[str, ...] = ("sphere", "sphere_large", "torus")
    """Prototypes tried on the first frame of a track (the paper's cold start tries them all);
    other cold starts use ``fit.prototypes``."""
    retry_ratio: float = 2.0
    """A warm fit whose image loss exceeds the previous frame's by this factor is redone cold,
    and the better of the two kept."""
    max_side: int = 4096
    """Frames larger than this on a side are refused (the running median holds K + 1 of them)."""


@dataclass(frozen=True)
class DetectConfig:
    """Finding the fast moving object among the blobs of the difference image."""

    threshold: float = 0.1
    """||I - B||_2 above this (RGB in [0, 1]) marks a pixel as differing from the background."""
    open_px: int = 3
    """Side of the square that opens the difference mask, removing specks of noise."""
    min_area_px: int = 20
    """Blobs smaller than this are noise."""
    min_fill: float = 0.3
    """A tracked object's blob must cover at least this fraction of the disc it is predicted to
    be; smaller blobs are noise or the remains of a slow mover."""
    motion_px: int = 6
    """Neighbouring masks are grown by this much before their pixels are dropped, so that an
    object creeping a few pixels per frame is dropped too."""
    gate: float = 4.0
    """A tracked object is looked for within this many object diameters of where its motion
    predicts it; a blob further away starts a new track."""


@dataclass(frozen=True)
class DemoConfig:
    """The built-in demo: a short generated clip with ground truth, processed like a user's clip."""

    shape: str = "ball"
    """One of the generator's shapes: ball, box, pen, ring, key."""
    frames: int = 8
    width: int = 320
    height: int = 240
    size_px: tuple[float, float] = (24.0, 28.0)
    """Range of the object's apparent diameter in pixels."""
    speed: tuple[float, float] = (1.2, 1.5)
    """Range of the travel per exposure, in object diameters."""
    exposure_fraction: float = 0.8
    """The generated camera's shutter; the pipeline is told it (``video.exposure_fraction``)."""
    seed: int = 0


@dataclass(frozen=True)
class Config:
    """Everything sfb-video can be tuned by."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    crop: CropConfig = field(default_factory=CropConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    video: VideoConfig = field(default_factory=VideoConfig)
    detect: DetectConfig = field(default_factory=DetectConfig)
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
            if not isinstance(value, list | tuple) or not value:
                raise ConfigError(f"{where} must be a non-empty list, got {value!r}")
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


def load_config(preset: str | Path = "default", overrides: list[str] | None = None) -> Config:
    """Load a preset (a name in ``configs/`` or a YAML path) and apply ``key=value`` overrides."""
    path = Path(preset)
    if not path.suffix:
        path = CONFIG_DIR / f"{preset}.yaml"
    if not path.is_file():
        raise ConfigError(f"config preset not found: {path}")
    try:
        tree = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path} is not valid YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(tree, dict):
        raise ConfigError(f"{path} must hold a mapping of config sections")
    for item in overrides or []:
        key, sep, raw = item.partition("=")
        if not sep:
            raise ConfigError(f"override {item!r} must look like section.key=value")
        _set_dotted(tree, key.strip(), yaml.safe_load(raw))
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
    """Save the resolved config beside a run's outputs (atomically), so the run can be replayed."""
    atomic_write_bytes(path, yaml.safe_dump(config_to_dict(config), sort_keys=False).encode())
