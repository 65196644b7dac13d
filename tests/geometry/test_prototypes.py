import math

import pytest
import torch

from sfb_video.errors import MeshError
from sfb_video.geometry.mesh import MeshTopology, normalize_vertices, signed_volume
from sfb_video.geometry.prototypes import PROTOTYPE_NAMES, load_prototype

COUNTS = {
    "sphere": (1212, 2420),
    "sphere_large": (1538, 3072),
    "torus": (1536, 3072),
    "capsule": (1212, 2420),
    "box": (1212, 2420),
    "disc": (1212, 2420),
}
EULER = {"sphere": 2, "sphere_large": 2, "torus": 0, "capsule": 2, "box": 2, "disc": 2}


@pytest.mark.parametrize("name", PROTOTYPE_NAMES)
def test_prototype_is_a_closed_consistently_oriented_mesh(name: str) -> None:
    verts, topo = load_prototype(name)
    assert (verts.shape[0], topo.num_faces) == COUNTS[name]
    assert topo.is_closed()
    assert verts.shape[0] - topo.edges.shape[0] + topo.num_faces == EULER[name]
    # Each interior edge runs one way in one face and the other way in its neighbour.
    slots = topo.edge_slots
    forward = (slots[:, :, 1] - slots[:, :, 0]) % 3 == 1
    assert bool((forward[:, 0] != forward[:, 1]).all())
    assert float(signed_volume(verts, topo.faces)) > 0


@pytest.mark.parametrize("name", PROTOTYPE_NAMES)
def test_prototype_is_at_unit_scale_with_seam_free_uvs(name: str) -> None:
    verts, topo = load_prototype(name)
    assert torch.allclose(verts.mean(0), torch.zeros(3), atol=1e-6)
    assert verts.square().sum(-1).mean().sqrt().item() == pytest.approx(0.5, rel=1e-5)
    uv = topo.face_uv_coords()
    assert uv.min() >= 0 and uv.max() <= 1
    # No face's UVs wrap around the texture: every face spans a small part of it.
    span = uv.amax(1) - uv.amin(1)
    assert float(span.max()) < 0.1


def test_sphere_volume_matches_the_unit_diameter_ball() -> None:
    verts, topo = load_prototype("sphere")
    assert float(signed_volume(verts, topo.faces)) == pytest.approx(math.pi / 6, rel=0.03)


def test_normalize_vertices_is_invariant_to_translation_and_scale() -> None:
    verts, _ = load_prototype("torus")
    moved = verts * 3.7 + torch.tensor([1.0, -2.0, 5.0])
    assert torch.allclose(normalize_vertices(moved), verts, atol=1e-5)


def test_non_manifold_edge_is_rejected() -> None:
    faces = torch.tensor([[0, 1, 2], [0, 1, 3], [0, 1, 4]])
    uvs = torch.rand(5, 2)
    with pytest.raises(MeshError, match="manifold"):
        MeshTopology.build(faces, uvs, faces)


def test_unknown_prototype_names_the_choices() -> None:
    with pytest.raises(ValueError, match="sphere_large"):
        load_prototype("cube")
