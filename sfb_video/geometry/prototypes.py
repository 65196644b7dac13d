"""Mesh prototypes generated in code: the shapes a fit starts from.

Each prototype is a closed mesh at unit scale with outward faces and a seam-correct texture
mapping: vertices on a seam get one UV per side, so no face's UVs wrap across the texture.
The counts follow the paper: a sphere of 1212 vertices / 2420 faces, a larger sphere of
1538 / 3072 and a torus of 1536 / 3072. The capsule (the sphere's mesh with its hemispheres
pulled apart along y) is ours: a start for pens and keys, whose streaks a sphere explains with
an object stretched along them. So are the box and the disc: the sphere's mesh pushed out along
each vertex's ray onto a cube's faces, or onto a flat cylinder's (its faces normal to z), so that
they share the sphere's texture map and count; boxes and frisbees are what people throw.
"""

from __future__ import annotations

import math

import torch

from sfb_video.geometry.mesh import MeshTopology, normalize_vertices, signed_volume

PROTOTYPE_NAMES = ("sphere", "sphere_large", "torus", "capsule", "box", "disc")


def _grid_faces(rows: int, cols: int, wrap_cols: bool, wrap_rows: bool) -> torch.Tensor:
    """Two triangles per cell of a rows x cols vertex grid (indices row * cols + col)."""
    r = torch.arange(rows if wrap_rows else rows - 1)
    c = torch.arange(cols if wrap_cols else cols - 1)
    rr, cc = torch.meshgrid(r, c, indexing="ij")
    r1, c1 = (rr + 1) % rows, (cc + 1) % cols
    a, b, d, e = rr * cols + cc, rr * cols + c1, r1 * cols + cc, r1 * cols + c1
    return torch.cat((torch.stack((a, d, b), -1), torch.stack((b, d, e), -1))).reshape(-1, 3)


def _orient_outward(vertices: torch.Tensor, faces: torch.Tensor, face_uvs: torch.Tensor):
    if float(signed_volume(vertices, faces)) < 0:
        return faces.flip(-1), face_uvs.flip(-1)
    return faces, face_uvs


def uv_sphere(rings: int = 22, segments: int = 55) -> tuple[torch.Tensor, MeshTopology]:
    """A UV sphere with ``rings`` latitude rings of ``segments`` vertices and two poles.

    Poles lie on the y axis (y down in camera space, so the north pole is up in the image).
    The spherical texture map has u = longitude / 2 pi and v = colatitude / pi; the seam
    column is duplicated at u = 1 and each pole face gets its own pole UV at its segment's
    middle, which avoids the pinched triangle fan of a single pole UV.

    Returns:
        vertices (V, 3) at unit scale with V = rings * segments + 2, and the topology.
    """
    theta = torch.arange(1, rings + 1, dtype=torch.float64) * math.pi / (rings + 1)
    phi = torch.arange(segments, dtype=torch.float64) * 2 * math.pi / segments
    th, ph = torch.meshgrid(theta, phi, indexing="ij")
    ring_xyz = torch.stack((th.sin() * ph.cos(), -th.cos(), th.sin() * ph.sin()), -1).reshape(-1, 3)
    top, bottom = torch.tensor([[0.0, -1.0, 0.0]]), torch.tensor([[0.0, 1.0, 0.0]])
    vertices = torch.cat((top.double(), ring_xyz, bottom.double())).float()
    n_ring = rings * segments
    bottom_id = n_ring + 1

    # Ring vertex (i, j) is 1 + i * segments + j; its UV is i * (segments + 1) + j.
    body = _grid_faces(rings, segments, wrap_cols=True, wrap_rows=False) + 1
    body_uv = _grid_faces(rings, segments + 1, wrap_cols=False, wrap_rows=False)
    j = torch.arange(segments)
    top_faces = torch.stack((torch.zeros_like(j), 1 + j, 1 + (j + 1) % segments), -1)
    last = 1 + (rings - 1) * segments
    bottom_faces = torch.stack((torch.full_like(j, bottom_id), last + (j + 1) % segments, last + j), -1)

    u = torch.arange(segments + 1, dtype=torch.float32) / segments
    v = theta.float() / math.pi
    grid_uv = torch.stack(torch.meshgrid(v, u, indexing="ij")[::-1], -1).reshape(-1, 2)
    pole_u = (torch.arange(segments, dtype=torch.float32) + 0.5) / segments
    top_uv = torch.stack((pole_u, torch.zeros(segments)), -1)
    bottom_uv = torch.stack((pole_u, torch.ones(segments)), -1)
    uvs = torch.cat((grid_uv, top_uv, bottom_uv))
    n_grid = grid_uv.shape[0]
    top_fuv = torch.stack((n_grid + j, j, j + 1), -1)
    lrow = (rings - 1) * (segments + 1)
    bottom_fuv = torch.stack((n_grid + segments + j, lrow + j + 1, lrow + j), -1)

    faces = torch.cat((top_faces, body, bottom_faces))
    face_uvs = torch.cat((top_fuv, body_uv, bottom_fuv))
    faces, face_uvs = _orient_outward(vertices, faces, face_uvs)
    return normalize_vertices(vertices), MeshTopology.build(faces, uvs, face_uvs)


def torus(major: int = 48, minor: int = 32, ratio: float = 0.4) -> tuple[torch.Tensor, MeshTopology]:
    """A torus in the x-z plane with ``major`` x ``minor`` vertices and tube/ring radius ``ratio``.

    Its texture map is the (major angle, minor angle) rectangle, duplicated along both seams.

    Returns:
        vertices (major * minor, 3) at unit scale and the topology.
    """
    a = torch.arange(major, dtype=torch.float64) * 2 * math.pi / major
    b = torch.arange(minor, dtype=torch.float64) * 2 * math.pi / minor
    aa, bb = torch.meshgrid(a, b, indexing="ij")
    radius = 1 + ratio * bb.cos()
    vertices = torch.stack((radius * aa.cos(), ratio * bb.sin(), radius * aa.sin()), -1)
    vertices = vertices.reshape(-1, 3).float()
    faces = _grid_faces(major, minor, wrap_cols=True, wrap_rows=True)
    face_uvs = _grid_faces(major + 1, minor + 1, wrap_cols=False, wrap_rows=False)
    uu = torch.arange(major + 1, dtype=torch.float32) / major
    vv = torch.arange(minor + 1, dtype=torch.float32) / minor
    g_u, g_v = torch.meshgrid(uu, vv, indexing="ij")
    uvs = torch.stack((g_u, g_v), -1).reshape(-1, 2)
    faces, face_uvs = _orient_outward(vertices, faces, face_uvs)
    return normalize_vertices(vertices), MeshTopology.build(faces, uvs, face_uvs)


def capsule(rings: int = 22, segments: int = 55, half_length: float = 1.5) -> tuple[torch.Tensor, MeshTopology]:
    """A capsule along y: a unit sphere's hemispheres moved ``half_length`` radii apart.

    The cylinder between them is the sphere's equatorial band of faces (``rings`` even), so the
    vertex count, faces and texture map are the sphere's: 1212 / 2420 by default.

    Returns:
        vertices (V, 3) at unit scale and the topology.
    """
    vertices, topology = uv_sphere(rings, segments)
    vertices = vertices.clone()
    vertices[:, 1] += torch.sign(vertices[:, 1]) * half_length * vertices[:, [0, 2]].norm(dim=-1).max()
    return normalize_vertices(vertices), topology


def box(rings: int = 22, segments: int = 55) -> tuple[torch.Tensor, MeshTopology]:
    """A cube: each sphere vertex moved along its ray onto the cube's surface (flat faces,
    sharp edges, the sphere's topology and texture map).

    Returns:
        vertices (V, 3) at unit scale and the topology.
    """
    vertices, topology = uv_sphere(rings, segments)
    cube = vertices / vertices.abs().amax(-1, keepdim=True)
    return normalize_vertices(cube), topology


def disc(rings: int = 22, segments: int = 55, thickness: float = 0.25) -> tuple[torch.Tensor, MeshTopology]:
    """A flat cylinder in the x-y plane (its faces normal to z), ``thickness`` of its diameter:
    each sphere vertex moved along its ray onto the cylinder's surface.

    Returns:
        vertices (V, 3) at unit scale and the topology.
    """
    vertices, topology = uv_sphere(rings, segments)
    radial = vertices[:, :2].norm(dim=-1) / 0.5
    height = vertices[:, 2].abs() / (0.5 * thickness)
    flat = vertices / torch.maximum(radial, height)[:, None]
    return normalize_vertices(flat), topology


def load_prototype(name: str) -> tuple[torch.Tensor, MeshTopology]:
    """Vertices (V, 3) at unit scale and topology of the prototype ``name``."""
    if name == "sphere":
        return uv_sphere(22, 55)
    if name == "sphere_large":
        return uv_sphere(24, 64)
    if name == "torus":
        return torus(48, 32)
    if name == "capsule":
        return capsule()
    if name == "box":
        return box()
    if name == "disc":
        return disc()
    raise ValueError(f"unknown prototype {name!r}; choose one of {', '.join(PROTOTYPE_NAMES)}")
