"""The walkthrough notebook runs top to bottom on the fast preset and shows what it promises.

It is executed in a fresh kernel, as a reader would run it, so that API changes in the pipeline
break this test instead of silently rotting the notebook.
"""

from __future__ import annotations

import re
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient
from nbformat import NotebookNode

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "walkthrough.ipynb"
MIN_MEAN_TIOU = 0.75
"""Measured 0.853 and 0.861 in two runs on the fast preset (CPU, torch 2.13): runs differ a little."""


def _tagged(notebook: NotebookNode, tag: str) -> NotebookNode:
    """The one cell carrying ``tag``: tags, not positions, so cells can be added around it."""
    (cell,) = [c for c in notebook.cells if tag in c.metadata.get("tags", [])]
    return cell


def _data(cell: NotebookNode, mime: str) -> list[str]:
    return [o["data"][mime] for o in cell.outputs if mime in o.get("data", {})]


def test_saved_without_outputs() -> None:
    # Outputs hold base64 PNGs: committed, they bloat the repository and every diff.
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    for cell in notebook.cells:
        if cell.cell_type == "code":
            assert not cell.outputs and cell.execution_count is None, cell.source[:60]


def test_walkthrough_runs(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    # The kernel is a child process: it inherits these variables.
    monkeypatch.setenv("SFB_VIDEO_PRESET", "fast")
    # matplotlib's inline backend draws with Agg into PNG outputs and never opens a window;
    # set explicitly so a GUI backend in the caller's environment cannot leak in.
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    # The notebook's temporary folder goes here, so the test can see that it is removed.
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setenv("TMPDIR", str(scratch))
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    # cwd outside the repository: the notebook must not depend on it (``stages`` and the
    # presets come from the editable install) nor write next to itself.
    client = NotebookClient(
        notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()  # raises CellExecutionError, with the cell's traceback, if any cell fails

    assert _data(_tagged(notebook, "reconstruction"), "image/png"), "the reconstruction cell showed no figure"
    tables = _data(_tagged(notebook, "scores"), "text/markdown")
    assert tables, "the scores cell showed no table"
    mean = re.search(r"^\| mean \| ([0-9.]+) \|", tables[0], re.MULTILINE)
    assert mean is not None, tables[0]
    assert float(mean.group(1)) > MIN_MEAN_TIOU, tables[0]
    assert not list(scratch.glob("sfb-walkthrough-*")), "the notebook left its temporary folder behind"
