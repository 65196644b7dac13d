"""Mesh files: the textured trimesh every GLB and OBJ is written from."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sfb_video.geometry.prototypes import load_prototype
from sfb_video.mesh_files import to_trimesh
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState


@pytest.mark.parametrize("prototype", ["sphere", "torus", "box"])
def test_the_trimesh_has_one_vertex_per_vertex_and_uv_pair_and_the_same_corners(prototype: str) -> None:
    vertices, topology = load_prototype(prototype)
    still = Motion(x0=torch.tensor([0.0, 0.0, 5.0]), dx=torch.zeros(3), rot0=torch.eye(3), omega=torch.zeros(3))
    mesh = to_trimesh(ObjectState(vertices, topology, torch.rand(3, 8, 8), still))
    pairs = {(int(f), int(u)) for f, u in zip(topology.faces.reshape(-1), topology.face_uvs.reshape(-1), strict=True)}
    assert len(mesh.vertices) == len(pairs)
    # Every face corner keeps its position and its texture coordinate (v flipped, glTF's way).
    assert np.allclose(mesh.vertices[mesh.faces], vertices[topology.faces].numpy(), atol=1e-6)
    uv = topology.uvs[topology.face_uvs].numpy()
    assert np.allclose(mesh.visual.uv[mesh.faces], np.stack((uv[..., 0], 1 - uv[..., 1]), -1), atol=1e-6)
