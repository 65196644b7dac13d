"""Synthetic motion-blurred clips with known ground truth, for measuring 3D accuracy.

The forward model here is deliberately not the fitter's: many hard, supersampled, z-buffered
renders per exposure (``raster``), composited over a real photo (``backgrounds``) and averaged,
with noise and 8-bit quantisation (``clip``). Nothing here imports ``sfb_video.render``.

Modules:
    textures     procedural texture images.
    shapes       ball, box, pen, ring and key meshes at unit scale, textured.
    raster       the hard rasteriser.
    backgrounds  photo backgrounds shipped with scikit-image.
    spec         ``ClipSpec``: every number the generator uses.
    trajectory   continuous motion over a clip and per-frame ground-truth motion.
    clip         blurred frames, sharp sub-frames, masks, boxes, centres, radii.
    io           clip folders on disk (atomic writes) and loading them back.

Array conventions: images are numpy uint8 RGB (H, W, 3), masks float32 coverage (H, W) in
[0, 1], motion float64 numpy, meshes torch (as in ``sfb_video.geometry``).
"""

from sfb_video.synth.backgrounds import BACKGROUND_NAMES, make_background
from sfb_video.synth.clip import (
    FrameTruth,
    SyntheticClip,
    SyntheticScene,
    exposure_renders,
    generate_clip,
    make_scene,
    render_exposure,
    render_frame,
)
from sfb_video.synth.io import load_clip, save_clip, write_clip
from sfb_video.synth.raster import RasterImages, pose_points, rasterize
from sfb_video.synth.shapes import SHAPE_NAMES, TexturedMesh, make_shape
from sfb_video.synth.spec import ClipSpec
from sfb_video.synth.textures import OBJECT_STYLES, TEXTURE_STYLES, procedural_texture
from sfb_video.synth.trajectory import FrameMotion, Trajectory, sample_trajectory

__all__ = [
    "BACKGROUND_NAMES",
    "OBJECT_STYLES",
    "SHAPE_NAMES",
    "TEXTURE_STYLES",
    "ClipSpec",
    "FrameMotion",
    "FrameTruth",
    "RasterImages",
    "SyntheticClip",
    "SyntheticScene",
    "TexturedMesh",
    "Trajectory",
    "exposure_renders",
    "generate_clip",
    "load_clip",
    "make_background",
    "make_scene",
    "make_shape",
    "pose_points",
    "procedural_texture",
    "rasterize",
    "render_exposure",
    "render_frame",
    "sample_trajectory",
    "save_clip",
    "write_clip",
]
