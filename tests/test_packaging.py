"""What a wheel carries: every package of the tree, and the presets inside the package, read
with importlib.resources (``.ci/check-wheel`` installs a real wheel outside the checkout)."""

from __future__ import annotations

import importlib.resources
import tomllib
from pathlib import Path

from sfb_video.config import PRESETS, preset_names

ROOT = Path(__file__).resolve().parent.parent


def test_every_package_of_the_tree_is_in_the_wheel() -> None:
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "sfb_video").rglob("__init__.py")}
    stages = {
        ".".join(("sfb_video", *p.parent.relative_to(ROOT).parts)) for p in (ROOT / "stages").rglob("__init__.py")
    }
    assert found | stages | {PRESETS} == listed


def test_presets_ship_in_the_package() -> None:
    assert {"default", "fast"} <= set(preset_names())
    folder = importlib.resources.files(PRESETS)
    assert (folder / "default.yaml").is_file()
    # The repository's configs/ folder is that package: one copy, not two.
    assert {p.name for p in (ROOT / "configs").glob("*.yaml")} == {f"{n}.yaml" for n in preset_names()}
