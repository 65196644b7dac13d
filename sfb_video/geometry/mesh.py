"""Triangle-mesh topology with texture coordinates, and vertex normalisation.

Convention:
    Faces are counter-clockwise seen from outside (outward normals by the right-hand rule).
    Texture coordinates (u, v) lie in [0, 1]^2 with (0, 0) the top-left corner of the texture
    image, u along its width and v along its height. They are indexed per face corner
    (``face_uvs``), apart from the vertices, so that a seam can have two UVs at one vertex.
    Unit scale: vertices centred on their mean with root-mean-square radius 1/2, so a sphere has
    diameter 1; one object size is the unit of length everywhere in sfb-video.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import torch

from sfb_video.errors import MeshError, check_face_span, check_faces, check_finite, check_shape


@dataclass(frozen=True)
class MeshTopology:
    """What stays fixed while a mesh deforms: faces, texture mapping and edge adjacency.

    Attributes:
        faces: (F, 3) vertex indices per face.
        uvs: (U, 2) texture coordinates in [0, 1].
        face_uvs: (F, 3) indices into ``uvs`` per face corner.
        edges: (E, 2) unique undirected vertex edges, smaller index first.
        edge_faces: (E, 2) the faces on either side of each edge; -1 where an edge has only one
            (a boundary of an open mesh).
        edge_slots: (E, 2, 2) for each edge and side, the corners (0..2) of that face holding the
            edge's first and second vertex; -1 where there is no face.
    """

    faces: torch.Tensor
    uvs: torch.Tensor
    face_uvs: torch.Tensor
    edges: torch.Tensor
    edge_faces: torch.Tensor
    edge_slots: torch.Tensor

    @staticmethod
    def build(faces: torch.Tensor, uvs: torch.Tensor, face_uvs: torch.Tensor) -> MeshTopology:
        """Derive the edge adjacency of ``faces`` (F, 3) and bundle it with the UV mapping."""
        faces = faces.long()
        check_shape(uvs, (None, 2), "uvs")
        check_shape(face_uvs, (faces.shape[0], 3), "face_uvs")
        check_faces(face_uvs.long(), uvs.shape[0])
        num_faces = faces.shape[0]
        corner_a = torch.tensor([0, 1, 2])
        corner_b = torch.tensor([1, 2, 0])
        va, vb = faces[:, corner_a].reshape(-1), faces[:, corner_b].reshape(-1)
        face_id = torch.arange(num_faces).repeat_interleave(3)
        slot_a, slot_b = corner_a.repeat(num_faces), corner_b.repeat(num_faces)
        lo, hi = torch.minimum(va, vb), torch.maximum(va, vb)
        swapped = va > vb
        slot_lo = torch.where(swapped, slot_b, slot_a)
        slot_hi = torch.where(swapped, slot_a, slot_b)
        key = lo * (int(faces.max()) + 1 if faces.numel() else 1) + hi
        uniq, inverse, counts = torch.unique(key, return_inverse=True, return_counts=True)
        if counts.numel() and int(counts.max()) > 2:
            raise MeshError("mesh is not a manifold: an edge is shared by more than two faces")
        num_edges = uniq.shape[0]
        # Place each half-edge in column 0 or 1 of its edge: the first occurrence goes to 0.
        order = torch.argsort(inverse, stable=True)
        first = torch.ones_like(order, dtype=torch.bool)
        first[1:] = inverse[order][1:] != inverse[order][:-1]
        column = torch.empty_like(inverse)
        column[order] = (~first).long()
        edges = torch.zeros(num_edges, 2, dtype=torch.long)
        edges[inverse, 0], edges[inverse, 1] = lo, hi
        edge_faces = torch.full((num_edges, 2), -1, dtype=torch.long)
        edge_faces[inverse, column] = face_id
        edge_slots = torch.full((num_edges, 2, 2), -1, dtype=torch.long)
        edge_slots[inverse, column, 0] = slot_lo
        edge_slots[inverse, column, 1] = slot_hi
        return MeshTopology(faces, uvs.float(), face_uvs.long(), edges, edge_faces, edge_slots)

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])

    def is_closed(self) -> bool:
        """True when every edge has a face on both sides (a watertight mesh); found once."""
        if "_closed" not in self.__dict__:
            self.__dict__["_closed"] = bool((self.edge_faces[:, 1] >= 0).all())
        return self.__dict__["_closed"]

    def face_uv_coords(self) -> torch.Tensor:
        """(F, 3, 2) texture coordinates of each face corner, gathered once (every render
        reads them, and a topology never changes): read-only, shared by every caller."""
        if "_face_uv_coords" not in self.__dict__:
            self.__dict__["_face_uv_coords"] = self.uvs[self.face_uvs]
        return self.__dict__["_face_uv_coords"]

    @functools.cached_property
    def vertex_span(self) -> tuple[int, int]:
        """The lowest and highest vertex index of ``faces`` ((0, -1) without faces), checked once:
        the faces never change, and reading them off a GPU each render would wait for it.

        Raises:
            MeshError: faces not an (F, 3) integer tensor.
        """
        return check_faces(self.faces, None)

    def to(self, device: torch.device | str) -> MeshTopology:
        """This topology on ``device``: itself where it is there already (every render moves its
        topology), else a copy that keeps what was found once (span, closedness, face UVs)."""
        device = torch.device(device)
        if all(getattr(self, f).device == device for f in self.__dataclass_fields__):
            return self
        moved = MeshTopology(*(getattr(self, f).to(device) for f in self.__dataclass_fields__))
        for key in ("vertex_span", "_closed"):
            if key in self.__dict__:
                moved.__dict__[key] = self.__dict__[key]
        if "_face_uv_coords" in self.__dict__:
            moved.__dict__["_face_uv_coords"] = self.__dict__["_face_uv_coords"].to(device)
        return moved


def check_vertices(vertices: torch.Tensor, topology: MeshTopology) -> None:
    """Check that ``vertices`` (*, V, 3) are finite and that the faces index them."""
    if vertices.dim() < 2 or vertices.shape[-1] != 3:
        raise MeshError(f"vertices must have shape (*, V, 3), got {tuple(vertices.shape)}")
    check_finite(vertices, "mesh vertices", MeshError)
    check_face_span(topology.vertex_span, vertices.shape[-2])


def normalize_vertices(vertices: torch.Tensor) -> torch.Tensor:
    """Centre (*, V, 3) vertices on their mean and scale them to RMS radius 1/2 (unit scale)."""
    centred = vertices - vertices.mean(dim=-2, keepdim=True)
    rms = centred.square().sum(-1).mean(-1).sqrt()[..., None, None]
    return 0.5 * centred / rms.clamp_min(1e-12)


def signed_volume(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Signed volume of a closed mesh, positive when faces are oriented outward."""
    a, b, c = (vertices[..., faces[:, k], :] for k in range(3))
    return (a * torch.linalg.cross(b, c, dim=-1)).sum((-1, -2)) / 6


def box_fill(vertices: torch.Tensor, faces: torch.Tensor) -> float:
    """How boxy a closed mesh is: its volume over that of its bounding box along its principal
    axes. 1 for a box (of any proportions), pi / 6 = 0.52 for a sphere or an ellipsoid, pi / 4
    = 0.79 for a cylinder.

    Args:
        vertices: (V, 3); faces: (F, 3), oriented outward.
    """
    centred = vertices.double() - vertices.double().mean(0)
    # Principal axes of the surface's vertices; a box's are its edges' directions.
    _, axes = torch.linalg.eigh(centred.T @ centred)
    local = centred @ axes
    extent = (local.amax(0) - local.amin(0)).prod()
    return float(signed_volume(vertices.double(), faces) / extent)
