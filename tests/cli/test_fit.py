import io
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from sfb_video.cli import main

PAIRS = Path(__file__).resolve().parents[3] / "shared" / "data" / "pairs"
FAST = ["--config", "fast", "--device", "cpu", "--quiet", "--set", "fit.iterations=40"]


@pytest.mark.skipif(not PAIRS.is_dir(), reason="shared/data is not beside the checkout")
def test_fit_on_a_real_pair_writes_every_output(tmp_path: Path) -> None:
    out = tmp_path / "pen"
    args = ["fit", "--image", str(PAIRS / "pen_im.png"), "--background", str(PAIRS / "pen_bgr.png")]
    assert main([*args, "--out", str(out), "--tsr", "4", *FAST]) == 0
    expected = {"reconstruction.png", "tsr.png", "mesh.obj", "mesh.mtl", "mesh.png", "mesh.glb"}
    assert expected | {"fit.json", "loss_curve.csv", "config.yaml"} <= {p.name for p in out.iterdir()}
    record = json.loads((out / "fit.json").read_text())
    assert np.isfinite(record["motion"]["x0"]).all()
    crop_w, crop_h = record["crop_size"]
    assert cv2.imread(str(out / "tsr.png")).shape[:2] == (crop_h, 4 * crop_w)
    # The reconstruction explains the streak better than the background alone would.
    losses = np.loadtxt(out / "loss_curve.csv", delimiter=",", skiprows=1, usecols=2)
    assert record["losses"]["image"] < losses[0]
    mesh = trimesh.load(io.BytesIO((out / "mesh.glb").read_bytes()), file_type="glb", force="mesh")
    assert len(mesh.faces) == 2420
    assert mesh.visual.material.baseColorTexture.size == (32, 32)
    assert len(trimesh.load(out / "mesh.obj", force="mesh").faces) == 2420


def _write(path: Path, image: np.ndarray) -> str:
    cv2.imwrite(str(path), image)
    return str(path)


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("same", "no object"),
        ("missing", "image not found"),
        ("corrupt", "not a readable image"),
        ("sizes", "differ in size"),
        ("box", "--box must be"),
    ],
)
def test_bad_fit_inputs_give_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, message: str
) -> None:
    background = np.random.default_rng(0).integers(0, 255, (60, 80, 3), dtype=np.uint8)
    bgr = _write(tmp_path / "bgr.png", background)
    image = str(tmp_path / "im.png")
    if case in ("same", "box"):
        _write(tmp_path / "im.png", background)
    elif case == "sizes":
        _write(tmp_path / "im.png", background[:50])
    elif case == "corrupt":
        (tmp_path / "im.png").write_bytes(b"\x89PNG garbage")
    extra = ["--box", "1,2,3"] if case == "box" else []
    assert main(["fit", "--image", image, "--background", bgr, "--out", str(tmp_path / "o"), *FAST, *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err
    leftovers = [p.name for p in tmp_path.iterdir() if p.name == "o" or p.name.startswith(".o.")]
    assert not leftovers, "no output, partial or not, may be left behind"


def test_interrupted_fit_exits_130_and_leaves_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import sfb_video.fitting.frame

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(sfb_video.fitting.frame, "fit_frame", interrupted)
    background = np.zeros((60, 80, 3), np.uint8)
    image = background.copy()
    image[20:30, 20:50] = 255
    args = [
        "fit",
        "--image",
        _write(tmp_path / "im.png", image),
        "--background",
        _write(tmp_path / "b.png", background),
    ]
    assert main([*args, "--out", str(tmp_path / "o"), *FAST]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not [p.name for p in tmp_path.iterdir() if p.name == "o" or p.name.startswith(".o.")]
