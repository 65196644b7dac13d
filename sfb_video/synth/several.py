"""Several objects in one clip: generated objects taken out of their clips as layers, placed,
and composited over one background by depth, each object's own truth kept.

A layer is one object's share of a clip: per frame and sub-frame, its light (the sub-frame less
its background where the object does not cover it: premultiplied colour) and its coverage. A
layer can be mirrored, shifted in the image and cut in time, so that two objects cross, follow
each other along one path, or one enters as the other leaves. A clip of several layers
composites each sub-frame from every layer over the shared background, farthest first by the
layer's depth in that frame; its blurred frame is the mean of its sub-frames, with noise added
and 8-bit quantisation, as the generator makes one object's (:mod:`sfb_video.synth.clip`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sfb_video.geometry.camera import PinholeCamera
from sfb_video.imageio import to_uint8
from sfb_video.synth.clip import SyntheticClip, stream_rng

Box = tuple[int, int, int, int]


@dataclass(frozen=True)
class Layer:
    """One generated object's share of a clip of F frames of N sub-frames, H x W pixels.

    Attributes:
        light: (F, N, H, W, 3) float32 premultiplied colour of the object in each sub-frame.
        cover: (F, N, H, W) float32 coverage of each sub-frame, in [0, 1].
        depth: (F,) float64 the object's depth at the middle of each exposure (nearer: in front).
        boxes: per frame the tight (x, y, w, h) box of every pixel the object touches during the
            exposure; None where it is not drawn.
        centres: per frame its (N, 2) (u, v) centre at the sub-frames' mid-times; None where absent.
        radii: per frame the radius of the disc of its mean silhouette area; None where absent.
    """

    light: np.ndarray
    cover: np.ndarray
    depth: np.ndarray
    boxes: tuple[Box | None, ...]
    centres: tuple[np.ndarray | None, ...]
    radii: tuple[float | None, ...]

    @property
    def frames(self) -> int:
        return len(self.boxes)

    def present(self, index: int) -> bool:
        return self.boxes[index] is not None


def take_layer(clip: SyntheticClip) -> Layer:
    """The object of a generated ``clip`` as a :class:`Layer`."""
    background = clip.scene.background.astype(np.float32) / 255
    light, cover = [], []
    for truth in clip.truth:
        masks = truth.masks
        sub = truth.subframes.astype(np.float32) / 255
        # Uncovered pixels are the background exactly: zero there, not 8-bit rounding noise.
        light.append(np.clip(sub - (1 - masks[..., None]) * background, 0, None) * (masks[..., None] > 0))
        cover.append(masks)
    depth = np.array([float(t.motion.x0[2] + t.motion.dx[2] / 2) for t in clip.truth])
    return Layer(
        np.stack(light),
        np.stack(cover),
        depth,
        tuple(t.bbox if t.present else None for t in clip.truth),
        tuple(t.centres for t in clip.truth),
        tuple(t.radius_px for t in clip.truth),
    )


def mirrored(layer: Layer) -> Layer:
    """``layer`` mirrored left to right (pixel centres at integers: column u goes to W - 1 - u)."""
    width = layer.cover.shape[-1]
    boxes = tuple(None if b is None else (width - b[0] - b[2], b[1], b[2], b[3]) for b in layer.boxes)
    centres = tuple(None if c is None else np.stack((width - 1 - c[:, 0], c[:, 1]), 1) for c in layer.centres)
    light, cover = layer.light[:, :, :, ::-1].copy(), layer.cover[..., ::-1].copy()
    return dataclasses.replace(layer, light=light, cover=cover, boxes=boxes, centres=centres)


def shifted(layer: Layer, dx: int, dy: int) -> Layer:
    """``layer`` moved ``dx`` pixels right and ``dy`` down.

    Raises:
        ValueError: the object would leave the frame.
    """
    height, width = layer.cover.shape[-2:]
    for box in layer.boxes:
        if box is not None and not (box[0] + dx >= 0 and box[0] + box[2] + dx <= width):
            raise ValueError(f"a shift of ({dx}, {dy}) takes the object out of the frame")
        if box is not None and not (box[1] + dy >= 0 and box[1] + box[3] + dy <= height):
            raise ValueError(f"a shift of ({dx}, {dy}) takes the object out of the frame")
    # Nothing is covered outside the boxes, so rolling loses nothing and brings in zeros.
    light = np.roll(layer.light, (dy, dx), axis=(2, 3))
    cover = np.roll(layer.cover, (dy, dx), axis=(2, 3))
    boxes = tuple(None if b is None else (b[0] + dx, b[1] + dy, b[2], b[3]) for b in layer.boxes)
    centres = tuple(None if c is None else c + np.array([dx, dy], dtype=np.float64) for c in layer.centres)
    return dataclasses.replace(layer, light=light, cover=cover, boxes=boxes, centres=centres)


def cut(layer: Layer, first: int, count: int) -> Layer:
    """Frames ``first`` .. ``first + count - 1`` of ``layer``: its object later (or earlier) in a clip."""
    pick = slice(first, first + count)
    return Layer(
        layer.light[pick],
        layer.cover[pick],
        layer.depth[pick],
        layer.boxes[pick],
        layer.centres[pick],
        layer.radii[pick],
    )


@dataclass(frozen=True)
class SeveralClip:
    """Layers composited over one background.

    Attributes:
        background: (H, W, 3) uint8 noise-free background of every frame.
        camera: the full-frame camera.
        layers: the objects, in the order they were given.
        frames: (F, H, W, 3) uint8 blurred, noisy frames.
        subframes: (F, N, H, W, 3) uint8 sharp, noise-free sub-frames of every object (the TSR target).
    """

    background: np.ndarray
    camera: PinholeCamera
    layers: tuple[Layer, ...]
    frames: np.ndarray
    subframes: np.ndarray

    def others(self, index: int, layer: int) -> np.ndarray:
        """(N, H, W, 3) float64 in [0, 1]: frame ``index``'s sub-frames with every object but
        ``layer``, the background a fit of that object is rendered over when it is scored."""
        kept = [k for k in range(len(self.layers)) if k != layer]
        n = self.subframes.shape[1]
        return _composite(self.background, [self.layers[k] for k in kept], index, n).astype(np.float64)


def _composite(background: np.ndarray, layers: list[Layer], index: int, n: int) -> np.ndarray:
    """(n, H, W, 3) float32: frame ``index``'s sub-frames of ``layers`` over ``background``."""
    out = np.broadcast_to(background.astype(np.float32) / 255, (n, *background.shape)).copy()
    for layer in sorted(layers, key=lambda a: -a.depth[index]):  # farthest first
        out = out * (1 - layer.cover[index][..., None]) + layer.light[index]
    return out


def several(
    background: np.ndarray, camera: PinholeCamera, layers: list[Layer], noise_sigma: float, seed: int
) -> SeveralClip:
    """The clip of ``layers`` over ``background``; frame k's noise from stream (3, k) of ``seed``
    (the same noise for the same seed, whichever objects the clip holds)."""
    if not layers:
        raise ValueError("a clip of several objects needs at least one")
    counts = {a.frames for a in layers}
    if len(counts) != 1:
        raise ValueError(f"the layers hold different numbers of frames: {sorted(counts)}")
    frames, subframes = [], []
    for k in range(counts.pop()):
        sub = _composite(background, layers, k, layers[0].cover.shape[1])
        noise = stream_rng(seed, 3, k).normal(0.0, noise_sigma, background.shape)
        frames.append(to_uint8(sub.mean(0) + noise))
        subframes.append(to_uint8(sub))
    return SeveralClip(background, camera, tuple(layers), np.stack(frames), np.stack(subframes))
