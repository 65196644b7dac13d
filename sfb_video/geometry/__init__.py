"""Camera, rotations and meshes: the geometry every stage shares."""
