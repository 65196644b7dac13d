"""The specification of a synthetic clip: every number the generator uses, in one dataclass.

Units: pixels for image sizes, degrees for angles, frame intervals for time (frame k's
exposure covers clip time [k, k + exposure_fraction]) and object sizes for 3D lengths (the mesh
is at unit scale; its bounding-sphere diameter D is what "object diameters" refers to).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from sfb_video.errors import ConfigError
from sfb_video.synth.backgrounds import BACKGROUND_NAMES
from sfb_video.synth.shapes import SHAPE_NAMES
from sfb_video.synth.textures import OBJECT_STYLES, TEXTURE_STYLES


@dataclass(frozen=True)
class ClipSpec:
    """What to generate. The same spec (seed included) always gives bit-identical output.

    Attributes:
        width, height: frame size in pixels.
        fov_y_deg: vertical field of view of the centred pinhole camera.
        num_frames: frames in the clip (1 = a single blurred frame).
        exposure_fraction: the fraction of a frame interval the shutter is open, in (0, 1]; the
            rest is the gap between consecutive exposures.
        num_subframes: N, ground-truth sharp sub-frames per exposure (the TSR target).
        sub_exposures: the fewest hard renders averaged per exposure, a multiple of
            ``num_subframes`` (each sub-frame averages an equal share of them).
        max_step_px: the most any vertex may move in the image between consecutive renders;
            a fast exposure gets more renders (still a multiple of ``num_subframes``), so a
            streak is a continuous smear rather than a row of separate copies. 0 turns this
            off (exactly ``sub_exposures`` renders).
        max_sub_exposures: the most renders one exposure may get from ``max_step_px``.
        supersample: samples per pixel along each axis of every hard render.
        noise_sigma: standard deviation of the Gaussian noise added to blurred frames (the
            intensity scale is [0, 1]) before 8-bit quantisation.
        shape: one of ``SHAPE_NAMES``.
        texture_size: side of the square texture image in texels.
        texture_style: one of ``TEXTURE_STYLES`` or ``OBJECT_STYLES``, or "random" (drawn from
            the seed among ``TEXTURE_STYLES``).
        background: one of ``BACKGROUND_NAMES`` or "random" (drawn from the seed).
        background_crop_range: the photo crop as a fraction of the largest crop that fits.
        size_px_range: the projected bounding-sphere diameter of the object at the middle of
            the clip's visible span, in pixels, drawn uniformly from this range.
        speed_range: motion parallel to the image plane during one exposure, in object
            (bounding-sphere) diameters, drawn uniformly from this range.
        max_depth_change: the largest change of depth over the visible span, as a fraction of
            the mid-span depth (towards or away from the camera).
        rotation_deg_range: rotation angle during one exposure, in degrees, drawn uniformly;
            below 180 so that the per-exposure axis-angle is unambiguous (the paper caps its
            estimate at 120).
        gravity: acceleration along camera +y (image down) in object sizes per frame^2; the
            per-frame ground truth keeps the chord dx = x(end) - x(start), so with gravity
            the linear model is an approximation within one exposure.
        min_streak: the projected centre must move at least this many projected object
            diameters during each visible exposure (a real FMO streak).
        min_depth: the closest any vertex may come to the camera plane, in object sizes.
        margin_px: the object keeps at least this distance from the frame's border while it is
            visible.
        absent_frames: frames in which the object is not drawn (the frame is background plus
            noise); the trajectory still runs through them.
        bounce_time: clip time at which the object bounces off a floor (its velocity along
            image y reverses, keeping ``BOUNCE_RESTITUTION`` of it); None: no bounce. The object
            then moves down the image before it and up after.
        swing_period: a circular swing parallel to the image plane, one turn in this many
            frame intervals, instead of the straight (or falling, or bouncing) path; its radius
            follows from the speed drawn from ``speed_range``. None: no swing.
        contrast: the object's texture is pulled towards the background's mean colour by this
            factor (1: as drawn; 0.2: a faint, low-contrast object).
        split_background: darken the left half of the background and brighten the right half,
            so that an object crossing the middle passes from dark to bright.
        fence_period_px: draw a static mesh fence in front of everything, wires 2 px wide every
            this many pixels in both directions (0: none); the background includes it.
        max_tries: trajectory draws before the spec is declared infeasible.
        seed: the seed of every random choice.
    """

    width: int = 320
    height: int = 240
    fov_y_deg: float = 45.0
    num_frames: int = 1
    exposure_fraction: float = 0.8
    num_subframes: int = 8
    sub_exposures: int = 32
    max_step_px: float = 2.0
    max_sub_exposures: int = 256
    supersample: int = 2
    noise_sigma: float = 0.007
    shape: str = "ball"
    texture_size: int = 256
    texture_style: str = "random"
    background: str = "random"
    background_crop_range: tuple[float, float] = (0.5, 1.0)
    size_px_range: tuple[float, float] = (20.0, 72.0)
    speed_range: tuple[float, float] = (1.5, 3.5)
    max_depth_change: float = 0.25
    rotation_deg_range: tuple[float, float] = (15.0, 90.0)
    gravity: float = 0.0
    min_streak: float = 1.0
    min_depth: float = 0.5
    margin_px: float = 2.0
    absent_frames: tuple[int, ...] = ()
    bounce_time: float | None = None
    swing_period: float | None = None
    contrast: float = 1.0
    split_background: bool = False
    fence_period_px: int = 0
    max_tries: int = 2000
    seed: int = 0

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def present_frames(self) -> tuple[int, ...]:
        """Indices of the frames in which the object is drawn."""
        absent = set(self.absent_frames)
        return tuple(k for k in range(self.num_frames) if k not in absent)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of every field (tuples become lists)."""
        return {f.name: _jsonable(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @staticmethod
    def from_dict(data: dict[str, Any]) -> ClipSpec:
        """Inverse of :meth:`to_dict`; unknown keys are an error, missing ones take defaults."""
        names = {f.name for f in dataclasses.fields(ClipSpec)}
        unknown = set(data) - names
        if unknown:
            raise ConfigError(f"unknown ClipSpec fields: {', '.join(sorted(unknown))}")
        return ClipSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def _jsonable(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


def _check_range(name: str, value: tuple[float, float], low: float, high: float) -> None:
    if len(value) != 2 or not low <= value[0] <= value[1] <= high:
        raise ConfigError(f"{name} must be (lo, hi) with {low:g} <= lo <= hi <= {high:g}, got {value}")


def _validate(spec: ClipSpec) -> None:
    if spec.width < 8 or spec.height < 8:
        raise ConfigError(f"frame size must be at least 8 x 8 pixels, got {spec.width} x {spec.height}")
    if not 0 < spec.fov_y_deg < 180:
        raise ConfigError(f"fov_y_deg must be in (0, 180), got {spec.fov_y_deg}")
    if spec.num_frames < 1:
        raise ConfigError(f"num_frames must be >= 1, got {spec.num_frames}")
    if not 0 < spec.exposure_fraction <= 1:
        raise ConfigError(f"exposure_fraction must be in (0, 1], got {spec.exposure_fraction}")
    if spec.num_subframes < 1:
        raise ConfigError(f"num_subframes must be >= 1, got {spec.num_subframes}")
    if spec.sub_exposures < spec.num_subframes or spec.sub_exposures % spec.num_subframes:
        raise ConfigError(
            f"sub_exposures ({spec.sub_exposures}) must be a positive multiple of num_subframes "
            f"({spec.num_subframes}) so that every sub-frame averages the same number of renders"
        )
    if spec.max_step_px < 0 or spec.max_sub_exposures < spec.sub_exposures:
        raise ConfigError("max_step_px must be >= 0 and max_sub_exposures >= sub_exposures")
    if spec.supersample < 1:
        raise ConfigError(f"supersample must be >= 1, got {spec.supersample}")
    if spec.noise_sigma < 0:
        raise ConfigError(f"noise_sigma must be >= 0, got {spec.noise_sigma}")
    if spec.shape not in SHAPE_NAMES:
        raise ConfigError(f"unknown shape {spec.shape!r}; choose one of {', '.join(SHAPE_NAMES)}")
    styles = TEXTURE_STYLES + OBJECT_STYLES
    if spec.texture_style != "random" and spec.texture_style not in styles:
        raise ConfigError(f"unknown texture_style {spec.texture_style!r}; choose one of {styles}")
    if spec.texture_size < 4:
        raise ConfigError(f"texture_size must be >= 4, got {spec.texture_size}")
    if spec.background != "random" and spec.background not in BACKGROUND_NAMES:
        raise ConfigError(f"unknown background {spec.background!r}; choose one of {BACKGROUND_NAMES}")
    _check_range("background_crop_range", spec.background_crop_range, 1e-3, 1.0)
    _check_range("size_px_range", spec.size_px_range, 1.0, float(max(spec.width, spec.height)))
    _check_range("speed_range", spec.speed_range, 0.0, float("inf"))
    _check_range("rotation_deg_range", spec.rotation_deg_range, 0.0, 179.0)
    if not 0 <= spec.max_depth_change < 1:
        raise ConfigError(f"max_depth_change must be in [0, 1), got {spec.max_depth_change}")
    if spec.min_streak < 0 or spec.min_depth <= 0 or spec.margin_px < 0:
        raise ConfigError("min_streak and margin_px must be >= 0 and min_depth > 0")
    if spec.bounce_time is not None and not 0 < spec.bounce_time < spec.num_frames:
        raise ConfigError(f"bounce_time must lie in (0, {spec.num_frames}), got {spec.bounce_time}")
    if spec.swing_period is not None and (spec.swing_period < 2 or spec.bounce_time is not None or spec.gravity):
        raise ConfigError("swing_period must be at least 2 frames, and a swing has no bounce and no gravity")
    if not 0 <= spec.contrast <= 1:
        raise ConfigError(f"contrast must be in [0, 1], got {spec.contrast}")
    if spec.fence_period_px < 0 or 0 < spec.fence_period_px < 4:
        raise ConfigError(f"fence_period_px must be 0 (no fence) or at least 4, got {spec.fence_period_px}")
    if any(not 0 <= k < spec.num_frames for k in spec.absent_frames):
        raise ConfigError(f"absent_frames must lie in [0, {spec.num_frames}), got {spec.absent_frames}")
    if not spec.present_frames:
        raise ConfigError("absent_frames covers every frame: the object would never be seen")
    if spec.max_tries < 1:
        raise ConfigError(f"max_tries must be >= 1, got {spec.max_tries}")
