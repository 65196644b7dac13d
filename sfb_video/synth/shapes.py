"""Textured ground-truth objects: ball, box, pen, ring and key.

Every shape is a closed mesh with faces counter-clockwise seen from outside, normalised to
unit scale (centred on the vertex mean, RMS radius 1/2; see ``geometry/mesh.py``), with
per-corner texture coordinates and a procedural texture drawn from a random generator.
Vertices and topology are torch tensors, as in ``sfb_video.geometry``; the texture is an
(S, S, 3) uint8 numpy image.

The ball and the ring reuse the fitter's prototype generators (a ground truth of exactly the
prototype's shape is a fair first test); the box, pen and key are built here and are not
reachable by deforming a sphere without large offsets, which is the point of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from sfb_video.errors import SfbError
from sfb_video.geometry.mesh import MeshTopology, normalize_vertices, signed_volume
from sfb_video.geometry.prototypes import torus, uv_sphere
from sfb_video.synth.textures import procedural_texture

SHAPE_NAMES = ("ball", "box", "pen", "ring", "key", "disc")

# The shapes' proportions (before normalisation to unit scale) and mesh resolutions.
BALL_RINGS, BALL_SEGMENTS = 22, 55  # the fitter's "sphere" prototype
BOX_SIDES, BOX_CELLS = (1.0, 0.62, 0.4), 6
PEN_LENGTH, PEN_RADIUS, PEN_RINGS, PEN_SEGMENTS = 5.0, 0.5, 30, 24  # length : diameter = 5 : 1
RING_MAJOR, RING_MINOR, RING_TUBE_RATIO = 48, 24, 0.35
KEY_CELL, KEY_THICKNESS = 0.08, 0.16  # outline grid spacing; the head has radius 1
DISC_THICKNESS, DISC_RINGS, DISC_SEGMENTS = 0.24, 8, 64  # a flying disc: diameter : thickness = 2 : 0.24


@dataclass(frozen=True)
class TexturedMesh:
    """A closed textured mesh at unit scale.

    Attributes:
        name: the shape's name (one of ``SHAPE_NAMES`` or a loaded mesh's label).
        vertices: (V, 3) float32 tensor, centred on the vertex mean, RMS radius 1/2.
        topology: faces, UVs and per-corner UV indices.
        texture: (S, S, 3) uint8 RGB image; UV (0, 0) is its top-left corner.
    """

    name: str
    vertices: torch.Tensor
    topology: MeshTopology
    texture: np.ndarray

    @property
    def bounding_radius(self) -> float:
        """Largest distance of a vertex from the centre, in object sizes."""
        return float(self.vertices.norm(dim=-1).max())


def _weld(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge coincident points (from separately built patches) so the mesh is closed.

    Args:
        points: (P, 3) float64 positions; faces: (F, 3) indices into them.

    Returns:
        unique points (V, 3) and faces (F, 3) re-indexed into them.
    """
    # Positions are built from the same few coordinates, so rounding far below the patch
    # spacing identifies exactly the copies of one corner.
    keys = np.round(points * 1e6).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return points[first], inverse.reshape(-1)[faces]


def _orient(
    points: np.ndarray, faces: np.ndarray, face_uvs: np.ndarray, outward: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Flip faces whose normal points against ``outward`` (F, 3); returns (faces, face_uvs)."""
    a, b, c = (points[faces[:, k]] for k in range(3))
    flip = (np.cross(b - a, c - a) * outward).sum(-1) < 0
    faces, face_uvs = faces.copy(), face_uvs.copy()
    faces[flip] = faces[flip][:, [0, 2, 1]]
    face_uvs[flip] = face_uvs[flip][:, [0, 2, 1]]
    return faces, face_uvs


def _finish(
    points: np.ndarray, faces: np.ndarray, uvs: np.ndarray, face_uvs: np.ndarray
) -> tuple[torch.Tensor, MeshTopology]:
    """Normalise to unit scale and bundle as (vertices, topology); checks closed + outward."""
    vertices = torch.from_numpy(points).float()
    faces_t = torch.from_numpy(faces).long()
    if float(signed_volume(vertices.double(), faces_t)) <= 0:
        raise SfbError("internal error: a synthetic shape came out inside-out")
    topology = MeshTopology.build(faces_t, torch.from_numpy(uvs).float(), torch.from_numpy(face_uvs))
    if not topology.is_closed():
        raise SfbError("internal error: a synthetic shape is not closed")
    return normalize_vertices(vertices), topology


def _cell_faces(rows: int, cols: int) -> np.ndarray:
    """Two triangles per cell of a rows x cols grid of points (index r * cols + c)."""
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a, b = r * cols + c, r * cols + c + 1
    d, e = a + cols, b + cols
    return np.concatenate((np.stack((a, d, b), -1), np.stack((b, d, e), -1))).reshape(-1, 3)


def box_mesh(sides: tuple[float, float, float], cells: int) -> tuple[torch.Tensor, MeshTopology]:
    """A cuboid of side lengths ``sides`` (x, y, z), each face split into cells x cells squares.

    The texture atlas is 3 x 2 tiles, one per face, inset by 1/32 of a tile so that bilinear
    lookups never bleed a neighbouring tile's colours across an edge.
    """
    half = np.asarray(sides, dtype=np.float64) / 2
    s = np.linspace(-1.0, 1.0, cells + 1)
    g1, g2 = np.meshgrid(s, s, indexing="ij")
    t = np.linspace(1 / 32, 1 - 1 / 32, cells + 1)
    t1, t2 = np.meshgrid(t, t, indexing="ij")
    grid = _cell_faces(cells + 1, cells + 1)
    points, faces, uvs, outward = [], [], [], []
    sides_of_box = [(axis, sign) for axis in range(3) for sign in (-1.0, 1.0)]
    for tile, (axis, sign) in enumerate(sides_of_box):
        other = [k for k in range(3) if k != axis]
        p = np.zeros((cells + 1, cells + 1, 3))
        p[..., axis] = sign
        p[..., other[0]], p[..., other[1]] = g1, g2
        col, row = tile % 3, tile // 3
        uv = np.stack(((col + t2) / 3, (row + t1) / 2), -1)
        base = sum(len(q) for q in points)
        points.append((p * half).reshape(-1, 3))
        uvs.append(uv.reshape(-1, 2))
        faces.append(grid + base)
        n = np.zeros(3)
        n[axis] = sign
        outward.append(np.broadcast_to(n, (len(grid), 3)))
    all_points, corner_faces = np.concatenate(points), np.concatenate(faces)
    face_uvs = corner_faces.copy()  # UVs are per built point, before welding
    welded, faces_w = _weld(all_points, corner_faces)
    faces_w, face_uvs = _orient(welded, faces_w, face_uvs, np.concatenate(outward))
    return _finish(welded, faces_w, np.concatenate(uvs), face_uvs)


def capsule_mesh(length: float, radius: float, rings: int, segments: int) -> tuple[torch.Tensor, MeshTopology]:
    """A capsule (cylinder with hemispherical caps) along x, of total ``length``.

    Rings are spaced evenly in arc length along the profile and v is that arc length, so the
    texture is not squeezed onto the caps the way a stretched sphere's spherical map would be.

    Returns:
        vertices (rings * segments + 2, 3) at unit scale and the topology.
    """
    if length <= 2 * radius:
        raise SfbError(f"a capsule needs length > 2 * radius, got {length} and {radius}")
    cap, body = math.pi * radius / 2, length - 2 * radius
    total = 2 * cap + body
    s = np.arange(1, rings + 1) / (rings + 1) * total
    # Profile: axial position and radius at arc length s, from the -x pole to the +x pole.
    ang_a = np.clip(s / radius, 0, math.pi / 2)
    ang_b = np.clip((s - cap - body) / radius, 0, math.pi / 2)
    axial = np.where(
        s < cap,
        -body / 2 - radius * np.cos(ang_a),
        np.where(s <= cap + body, s - cap - body / 2, body / 2 + radius * np.sin(ang_b)),
    )
    rad = np.where(s < cap, radius * np.sin(ang_a), np.where(s <= cap + body, radius, radius * np.cos(ang_b)))
    phi = np.arange(segments) * 2 * math.pi / segments
    ring_pts = np.stack(
        (np.repeat(axial, segments), np.outer(rad, np.cos(phi)).ravel(), np.outer(rad, np.sin(phi)).ravel()), -1
    )
    poles = np.array([[-length / 2, 0, 0], [length / 2, 0, 0]])
    points = np.concatenate((poles[:1], ring_pts, poles[1:]))
    last_id = rings * segments + 1

    # Ring vertex (i, j) is 1 + i * segments + j; its UV is i * (segments + 1) + j (seam copy).
    j = np.arange(segments)
    i = np.arange(rings - 1)[:, None]
    a, b = 1 + i * segments + j, 1 + i * segments + (j + 1) % segments
    ua, ub = i * (segments + 1) + j, i * (segments + 1) + j + 1
    body_f = np.concatenate((np.stack((a, a + segments, b), -1), np.stack((b, a + segments, b + segments), -1)))
    body_uv = np.concatenate(
        (np.stack((ua, ua + segments + 1, ub), -1), np.stack((ub, ua + segments + 1, ub + segments + 1), -1))
    )
    first_f = np.stack((np.zeros_like(j), 1 + j, 1 + (j + 1) % segments), -1)
    lr = 1 + (rings - 1) * segments
    last_f = np.stack((np.full_like(j, last_id), lr + (j + 1) % segments, lr + j), -1)

    u = np.arange(segments + 1) / segments
    v = s / total
    grid_uv = np.stack(np.meshgrid(u, v, indexing="xy"), -1).reshape(-1, 2)
    pole_u = (np.arange(segments) + 0.5) / segments
    n_grid = len(grid_uv)
    uvs = np.concatenate(
        (grid_uv, np.stack((pole_u, np.zeros(segments)), -1), np.stack((pole_u, np.ones(segments)), -1))
    )
    lrow = (rings - 1) * (segments + 1)
    first_uv = np.stack((n_grid + j, j, j + 1), -1)
    last_uv = np.stack((n_grid + segments + j, lrow + j + 1, lrow + j), -1)

    faces = np.concatenate((first_f, body_f.reshape(-1, 3), last_f))
    face_uvs = np.concatenate((first_uv, body_uv.reshape(-1, 3), last_uv))
    centroid = (points[faces[:, 0]] + points[faces[:, 1]] + points[faces[:, 2]]) / 3
    # The outward direction of a surface of revolution is away from the axis (and, on the
    # caps, away from the centre), which the vector from the nearest axis point gives.
    nearest = np.clip(centroid[:, 0], -body / 2, body / 2)
    outward = centroid - np.stack((nearest, np.zeros_like(nearest), np.zeros_like(nearest)), -1)
    faces, face_uvs = _orient(points, faces, face_uvs, outward)
    return _finish(points, faces, uvs, face_uvs)


def key_outline(cell: float) -> np.ndarray:
    """Boolean occupancy grid (rows along z, columns along x) of a flat key's outline.

    A round head of radius 1 with a hole of radius 0.4 at the origin, a shaft to x = 4 and
    two teeth; ``cell`` is the grid spacing in the same units.
    """
    xs = np.arange(-1.0, 4.0, cell) + cell / 2
    zs = np.arange(-1.0, 1.0, cell) + cell / 2
    x, z = np.meshgrid(xs, zs, indexing="xy")
    r2 = x**2 + z**2
    head = (r2 <= 1.0) & (r2 >= 0.4**2)
    shaft = (x >= 0.8) & (x <= 4.0) & (np.abs(z) <= 0.28)
    teeth = ((np.abs(x - 2.75) <= 0.18) | (np.abs(x - 3.45) <= 0.18)) & (z > 0.28) & (z <= 0.62)
    occupied = head | shaft | teeth
    # Two cells touching only at a corner would make an edge shared by four wall faces (not a
    # manifold); filling one of them is invisible at the cell size.
    while True:
        a, b, c, d = occupied[:-1, :-1], occupied[:-1, 1:], occupied[1:, :-1], occupied[1:, 1:]
        diag = (a & d & ~b & ~c) | (b & c & ~a & ~d)
        if not diag.any():
            return occupied
        rows, cols = np.nonzero(diag)
        occupied[rows, cols] = True
        occupied[rows, cols + 1] = True


def extruded_mesh(occupied: np.ndarray, cell: float, thickness: float) -> tuple[torch.Tensor, MeshTopology]:
    """A closed plate: the occupied cells of a grid extruded by ``thickness`` along y.

    Texture coordinates are the planar map of the grid's bounding box (the same on both
    sides); side walls take the colour of their rim.
    """
    rows, cols = occupied.shape

    def corner(r: np.ndarray, c: np.ndarray, layer: int) -> np.ndarray:
        """Index of grid corner (r, c) in the top (0) or bottom (1) layer."""
        return (layer * (rows + 1) + r) * (cols + 1) + c

    rr, cc = np.nonzero(occupied)
    faces, outward = [], []
    for layer, ny in ((0, -1.0), (1, 1.0)):
        a, b = corner(rr, cc, layer), corner(rr, cc + 1, layer)
        d, e = corner(rr + 1, cc, layer), corner(rr + 1, cc + 1, layer)
        faces += [np.stack((a, d, b), -1), np.stack((b, d, e), -1)]
        outward += [np.tile([0.0, ny, 0.0], (2 * len(rr), 1))]
    padded = np.pad(occupied, 1)
    # Each side of an occupied cell that faces an empty cell is a wall; (dr, dc) points out.
    for dr, dc, (r0, c0), (r1, c1) in (
        (-1, 0, (0, 0), (0, 1)),
        (1, 0, (1, 0), (1, 1)),
        (0, -1, (0, 0), (1, 0)),
        (0, 1, (0, 1), (1, 1)),
    ):
        wall = occupied & ~padded[1 + dr : rows + 1 + dr, 1 + dc : cols + 1 + dc]
        wr, wc = np.nonzero(wall)
        p, q = corner(wr + r0, wc + c0, 0), corner(wr + r1, wc + c1, 0)
        p1, q1 = corner(wr + r0, wc + c0, 1), corner(wr + r1, wc + c1, 1)
        faces += [np.stack((p, p1, q), -1), np.stack((q, p1, q1), -1)]
        outward += [np.tile([dc, 0.0, dr], (2 * len(wr), 1))]
    faces_all = np.concatenate(faces)
    gz, gx = np.meshgrid(np.arange(rows + 1) * cell, np.arange(cols + 1) * cell, indexing="ij")
    layer_pts = [np.stack((gx, np.full_like(gx, y), gz), -1).reshape(-1, 3) for y in (-thickness / 2, thickness / 2)]
    points = np.concatenate(layer_pts)
    uv_grid = np.stack((gx / gx.max(), gz / gz.max()), -1).reshape(-1, 2)
    face_uvs = faces_all % ((rows + 1) * (cols + 1))  # both layers share the planar map
    faces_all, face_uvs = _orient(points, faces_all, face_uvs, np.concatenate(outward))
    used, faces_c = np.unique(faces_all, return_inverse=True)
    return _finish(points[used], faces_c.reshape(-1, 3), uv_grid, face_uvs)


def disc_mesh(thickness: float, rings: int, segments: int) -> tuple[torch.Tensor, MeshTopology]:
    """A flat cylinder of radius 1 and ``thickness`` along y: two faces of ``rings`` concentric
    rings of ``segments`` vertices around a centre, joined by a wall at the rim.

    Texture coordinates are the planar map of the faces (centre at (0.5, 0.5), the rim touching
    the map's sides; the same on both faces); the wall takes the colour of the rim.
    """
    phi = np.arange(segments) * 2 * math.pi / segments
    radii = np.arange(1, rings + 1) / rings
    ring_xz = np.stack((np.outer(radii, np.cos(phi)), np.outer(radii, np.sin(phi))), -1).reshape(-1, 2)
    plane = np.concatenate((np.zeros((1, 2)), ring_xz))  # the centre, then ring by ring
    per_face = len(plane)
    points = np.concatenate(
        [np.stack((plane[:, 0], np.full(per_face, y), plane[:, 1]), -1) for y in (thickness / 2, -thickness / 2)]
    )
    uvs = np.concatenate([0.5 + plane / 2] * 2)
    j = np.arange(segments)
    nxt = (j + 1) % segments
    faces, outward = [], []
    for layer, ny in ((0, 1.0), (1, -1.0)):
        base = layer * per_face

        def ring(k: int, s: np.ndarray, base: int = base) -> np.ndarray:
            return base + 1 + k * segments + s

        layer_faces = [np.stack((np.full(segments, base), ring(0, j), ring(0, nxt)), -1)]
        for k in range(rings - 1):
            layer_faces += [
                np.stack((ring(k, j), ring(k + 1, j), ring(k, nxt)), -1),
                np.stack((ring(k, nxt), ring(k + 1, j), ring(k + 1, nxt)), -1),
            ]
        stacked = np.concatenate(layer_faces)
        faces.append(stacked)
        outward.append(np.tile([0.0, ny, 0.0], (len(stacked), 1)))
    top, bottom = 1 + (rings - 1) * segments + j, per_face + 1 + (rings - 1) * segments + j
    top_n, bottom_n = 1 + (rings - 1) * segments + nxt, per_face + 1 + (rings - 1) * segments + nxt
    wall = np.concatenate((np.stack((top, bottom, top_n), -1), np.stack((top_n, bottom, bottom_n), -1)))
    faces.append(wall)
    rim = np.stack((np.cos(phi), np.zeros(segments), np.sin(phi)), -1)
    outward.append(np.concatenate((rim, rim)))
    all_faces = np.concatenate(faces)
    oriented, face_uvs = _orient(points, all_faces, all_faces.copy(), np.concatenate(outward))
    return _finish(points, oriented, uvs, face_uvs)


def make_shape(name: str, rng: np.random.Generator, texture_size: int, texture_style: str) -> TexturedMesh:
    """The textured shape ``name`` (one of ``SHAPE_NAMES``), its texture drawn from ``rng``.

    Shapes: "ball" (UV sphere, 1212 vertices), "box" (sides 1 : 0.62 : 0.4), "pen" (capsule,
    length : diameter = 5 : 1), "ring" (torus, tube/ring radius 0.35), "key" (flat plate 5 x 2
    x 0.16 with a round head, a hole and two teeth), "disc" (a flying disc: a flat cylinder of
    diameter : thickness = 2 : 0.24).
    """
    if name == "ball":
        vertices, topology = uv_sphere(BALL_RINGS, BALL_SEGMENTS)
    elif name == "box":
        vertices, topology = box_mesh(BOX_SIDES, BOX_CELLS)
    elif name == "pen":
        vertices, topology = capsule_mesh(PEN_LENGTH, PEN_RADIUS, PEN_RINGS, PEN_SEGMENTS)
    elif name == "ring":
        vertices, topology = torus(RING_MAJOR, RING_MINOR, RING_TUBE_RATIO)
    elif name == "key":
        vertices, topology = extruded_mesh(key_outline(KEY_CELL), KEY_CELL, KEY_THICKNESS)
    elif name == "disc":
        vertices, topology = disc_mesh(DISC_THICKNESS, DISC_RINGS, DISC_SEGMENTS)
    else:
        raise SfbError(f"unknown shape {name!r}; choose one of {', '.join(SHAPE_NAMES)}")
    texture = procedural_texture(rng, texture_size, texture_style)
    return TexturedMesh(name, vertices.float().contiguous(), topology, texture)
