"""The mesh topology: what it finds once (its faces' vertex span, whether it is closed) carried to another device."""

from __future__ import annotations

import pytest

from sfb_video.errors import MeshError
from sfb_video.geometry.mesh import MeshTopology, check_vertices
from sfb_video.geometry.prototypes import load_prototype


def test_the_faces_vertex_span_is_read_once_and_goes_with_the_topology_to_another_device() -> None:
    vertices, topology = load_prototype("sphere")
    assert topology.vertex_span == (0, vertices.shape[0] - 1)
    # A meta tensor holds no values: were the span read again there (as it was every render, a
    # wait for the device on a GPU), this would raise.
    closed = topology.is_closed()
    moved = topology.to("meta")
    assert moved.faces.is_meta and moved.vertex_span == topology.vertex_span
    assert moved.is_closed() == closed  # carried: a meta tensor cannot be read
    assert topology.to("cpu") is topology  # every render moves its topology: no copy where it is
    check_vertices(vertices, topology)
    with pytest.raises(MeshError, match="out of range"):
        check_vertices(vertices[:-1], topology)
    bad = MeshTopology(
        topology.faces.float(),
        *(getattr(topology, f) for f in ("uvs", "face_uvs", "edges", "edge_faces", "edge_slots")),
    )
    with pytest.raises(MeshError, match="integer"):
        check_vertices(vertices, bad)
