"""Writing synthetic clips to disk and reading them back.

Layout of a clip folder::

    frames/%04d.png              blurred, noisy frames (8-bit RGB)
    background.png               the noise-free background
    gt/subframes/%04d_%02d.png   sharp sub-frame j of frame k (8-bit RGB)
    gt/masks/%04d_%02d.png       mean coverage of sub-frame j (8-bit grey, level / 255)
    gt/mesh.obj, mesh.mtl        the object at unit scale in its own frame (OBJ texture
    gt/texture.png               coordinates have v up: v_obj = 1 - v)
    gt.json                      spec, camera, trajectory and per-frame motion, boxes,
                                 centres and radii; written last, so its presence means the
                                 folder is complete

Every file is written to a temporary name in its folder and moved into place with
``os.replace``, so a reader never sees a half-written file. Loading gives back a clip equal to
the saved one array for array.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from sfb_video.atomic import atomic_write_bytes
from sfb_video.errors import SfbError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.imageio import to_uint8
from sfb_video.synth.clip import (
    FrameTruth,
    SyntheticClip,
    SyntheticScene,
    make_scene,
    mask_from_levels,
    render_frame,
)
from sfb_video.synth.shapes import TexturedMesh
from sfb_video.synth.spec import ClipSpec
from sfb_video.synth.trajectory import FrameMotion, Trajectory

FORMAT = "sfb-video-synth/1"


def write_png(path: Path | str, image: np.ndarray) -> None:
    """Write an (H, W, 3) RGB or (H, W) grey uint8 image as PNG, atomically."""
    if image.dtype != np.uint8 or image.ndim not in (2, 3):
        raise SfbError(f"write_png needs an (H, W[, 3]) uint8 image, got {image.dtype} {image.shape}")
    bgr = image[..., ::-1] if image.ndim == 3 else image
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr))
    if not ok:
        raise SfbError(f"could not encode {path} as PNG")
    atomic_write_bytes(path, buf.tobytes())


def read_png(path: Path | str, grey: bool = False) -> np.ndarray:
    """Read a PNG as (H, W, 3) RGB uint8, or (H, W) with ``grey``."""
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR)
    if image is None:
        raise SfbError(f"could not read image {path}")
    return image if grey else np.ascontiguousarray(image[..., ::-1])


def write_obj(folder: Path | str, mesh: TexturedMesh) -> None:
    """Write ``mesh`` as folder/mesh.obj + mesh.mtl + texture.png."""
    folder = Path(folder)
    verts = mesh.vertices.float().numpy()
    # float64 arithmetic makes 1 - (1 - v) == v exactly for float32 v, so UVs round-trip.
    uvs = mesh.topology.uvs.float().numpy().astype(np.float64)
    faces = mesh.topology.faces.numpy() + 1
    fuv = mesh.topology.face_uvs.numpy() + 1
    lines = [f"# sfb-video synthetic {mesh.name}, unit scale", "mtllib mesh.mtl", "usemtl texture"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in verts]
    lines += [f"vt {float(u)!r} {float(1.0 - v)!r}" for u, v in uvs]
    lines += [f"f {a}/{ta} {b}/{tb} {c}/{tc}" for (a, b, c), (ta, tb, tc) in zip(faces, fuv, strict=True)]
    atomic_write_bytes(folder / "mesh.obj", ("\n".join(lines) + "\n").encode())
    mtl = "newmtl texture\nKa 1 1 1\nKd 1 1 1\nmap_Kd texture.png\n"
    atomic_write_bytes(folder / "mesh.mtl", mtl.encode())
    write_png(folder / "texture.png", mesh.texture)


def read_obj(folder: Path | str, name: str) -> TexturedMesh:
    """Read folder/mesh.obj and texture.png written by :func:`write_obj`."""
    folder = Path(folder)
    verts: list[list[float]] = []
    uvs: list[list[float]] = []
    faces: list[list[int]] = []
    fuvs: list[list[int]] = []
    for line in (folder / "mesh.obj").read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            verts.append([float(p) for p in parts[1:4]])
        elif parts[0] == "vt":
            uvs.append([float(parts[1]), 1.0 - float(parts[2])])
        elif parts[0] == "f":
            corners = [p.split("/") for p in parts[1:4]]
            faces.append([int(c[0]) - 1 for c in corners])
            fuvs.append([int(c[1]) - 1 for c in corners])
    topology = MeshTopology.build(
        torch.tensor(faces, dtype=torch.long), torch.tensor(uvs, dtype=torch.float64).float(), torch.tensor(fuvs)
    )
    vertices = torch.tensor(np.asarray(verts, dtype=np.float32))
    return TexturedMesh(name, vertices, topology, read_png(folder / "texture.png"))


def _subframe_name(index: int, j: int) -> str:
    return f"{index:04d}_{j:02d}.png"


def write_frame(root: Path | str, frame: np.ndarray, truth: FrameTruth) -> None:
    """Write one blurred frame and its sub-frames and masks into the clip folder ``root``."""
    root = Path(root)
    write_png(root / "frames" / f"{truth.index:04d}.png", frame)
    for j in range(truth.subframes.shape[0]):
        write_png(root / "gt" / "subframes" / _subframe_name(truth.index, j), truth.subframes[j])
        write_png(root / "gt" / "masks" / _subframe_name(truth.index, j), to_uint8(truth.masks[j]))


def _array(x: Any) -> Any:
    return None if x is None else np.asarray(x).tolist()


def frame_record(truth: FrameTruth) -> dict[str, Any]:
    """The JSON record of one frame's ground truth (everything but the images)."""
    m = truth.motion
    return {
        "index": truth.index,
        "present": truth.present,
        "frame": f"frames/{truth.index:04d}.png",
        "x0": _array(m.x0),
        "dx": _array(m.dx),
        "quaternion_wxyz": _array(m.quaternion),
        "rotation": _array(m.rotation),
        "omega": _array(m.omega),
        "bbox_xywh": None if truth.bbox is None else list(truth.bbox),
        "centres_uv": _array(truth.centres),
        "radius_px": truth.radius_px,
    }


def write_scene_json(root: Path | str, scene: SyntheticScene, records: list[dict[str, Any]]) -> None:
    """Write gt.json (last, so that it marks a complete folder)."""
    cam, traj = scene.camera, scene.trajectory
    data = {
        "format": FORMAT,
        "spec": scene.spec.to_dict(),
        "camera": {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width, "height": cam.height},
        "shape": scene.mesh.name,
        "background_name": scene.background_name,
        "conventions": {
            "time": "frame k's exposure covers clip time [k, k + exposure_fraction]; tau in [0, 1]",
            "pose": "p(tau) = R(tau) v + x0 + tau dx, R(tau) = exp(tau omega) R0; camera x right, y down, z fwd",
            "quaternion": "WXYZ",
            "bbox_xywh": "columns x..x+w-1, rows y..y+h-1",
            "centres_uv": "pixel centres at integers; projection of x at tau = (j + 1/2) / N",
            "radius_px": "radius of the disc with the mean silhouette area over the exposure",
        },
        "trajectory": {
            "position0": _array(traj.position0),
            "velocity": _array(traj.velocity),
            "acceleration": _array(traj.acceleration),
            "quaternion0_wxyz": _array(traj.quaternion0),
            "angular_velocity": _array(traj.angular_velocity),
            "exposure_fraction": traj.exposure_fraction,
            "bounce_time": traj.bounce_time,
            "swing": None if traj.swing is None else _array(traj.swing),
        },
        "frames": records,
    }
    atomic_write_bytes(Path(root) / "gt.json", json.dumps(data, indent=1).encode())


def _write_static(root: Path, scene: SyntheticScene) -> None:
    for folder in ("frames", "gt/subframes", "gt/masks"):
        (root / folder).mkdir(parents=True, exist_ok=True)
    write_png(root / "background.png", scene.background)
    write_obj(root / "gt", scene.mesh)


def save_clip(clip: SyntheticClip, root: Path | str) -> Path:
    """Write a generated clip into the folder ``root`` (created if needed); returns it."""
    root = Path(root)
    _write_static(root, clip.scene)
    for frame, truth in zip(clip.frames, clip.truth, strict=True):
        write_frame(root, frame, truth)
    write_scene_json(root, clip.scene, [frame_record(t) for t in clip.truth])
    return root


def write_clip(spec: ClipSpec, root: Path | str) -> Path:
    """Generate ``spec`` straight to disk one frame at a time (memory does not grow with length)."""
    root = Path(root)
    scene = make_scene(spec)
    _write_static(root, scene)
    records = []
    for k in range(spec.num_frames):
        frame, truth = render_frame(scene, k)
        write_frame(root, frame, truth)
        records.append(frame_record(truth))
    write_scene_json(root, scene, records)
    return root


def _vec(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def load_clip(root: Path | str) -> SyntheticClip:
    """Read a clip folder written by :func:`save_clip` or :func:`write_clip`."""
    root = Path(root)
    meta_path = root / "gt.json"
    if not meta_path.is_file():
        raise SfbError(f"{root} is not a complete synthetic clip: gt.json is missing")
    data = json.loads(meta_path.read_text())
    if data.get("format") != FORMAT:
        raise SfbError(f"{meta_path} has format {data.get('format')!r}, expected {FORMAT!r}")
    spec = ClipSpec.from_dict(data["spec"])
    cam = data["camera"]
    camera = PinholeCamera(cam["fx"], cam["fy"], cam["cx"], cam["cy"], cam["width"], cam["height"])
    tr = data["trajectory"]
    trajectory = Trajectory(
        _vec(tr["position0"]),
        _vec(tr["velocity"]),
        _vec(tr["acceleration"]),
        _vec(tr["quaternion0_wxyz"]),
        _vec(tr["angular_velocity"]),
        float(tr["exposure_fraction"]),
        tr.get("bounce_time"),
        None if tr.get("swing") is None else _vec(tr["swing"]),
    )
    mesh = read_obj(root / "gt", data["shape"])
    scene = SyntheticScene(spec, camera, mesh, read_png(root / "background.png"), data["background_name"], trajectory)
    frames, truths = [], []
    for rec in data["frames"]:
        k = rec["index"]
        frames.append(read_png(root / rec["frame"]))
        n = spec.num_subframes
        subframes = np.stack([read_png(root / "gt" / "subframes" / _subframe_name(k, j)) for j in range(n)])
        levels = np.stack([read_png(root / "gt" / "masks" / _subframe_name(k, j), grey=True) for j in range(n)])
        motion = FrameMotion(
            _vec(rec["x0"]), _vec(rec["dx"]), _vec(rec["quaternion_wxyz"]), _vec(rec["rotation"]), _vec(rec["omega"])
        )
        bbox = None if rec["bbox_xywh"] is None else tuple(int(v) for v in rec["bbox_xywh"])
        centres = None if rec["centres_uv"] is None else _vec(rec["centres_uv"])
        truths.append(
            FrameTruth(
                k, bool(rec["present"]), motion, subframes, mask_from_levels(levels), bbox, centres, rec["radius_px"]
            )
        )
    return SyntheticClip(scene, np.stack(frames), tuple(truths))
