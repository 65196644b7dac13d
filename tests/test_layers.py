"""The package's layers, read from its source: no import cycle anywhere, the core (geometry,
render, model, fitting) imports no pipeline stage and no command line, and the stages import no
command line. What the command line and the library both need lives below both."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CORE = ("sfb_video.geometry", "sfb_video.render", "sfb_video.model", "sfb_video.fitting")
STAGES = "sfb_video.stages"
COMMAND_LINE = (
    "sfb_video.cli",
    "sfb_video.entry",
    "sfb_video.batch",
    "sfb_video.demo",
    "sfb_video.evaluation.runner",
    "sfb_video.evaluation.montage",
    "sfb_video.evaluation.jobs",
    "sfb_video.evaluation.tables",
)


def _modules() -> dict[str, Path]:
    """Module name -> source file, with the repository's stages/ as sfb_video.stages."""
    found = {}
    for top, package in ((ROOT / "sfb_video", ("sfb_video",)), (ROOT / "stages", ("sfb_video", "stages"))):
        for path in top.rglob("*.py"):
            parts = (*package, *path.relative_to(top).with_suffix("").parts)
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The project modules ``name`` imports anywhere in its file (in functions too: a cycle of
    local imports is a cycle all the same)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names]
        else:
            continue
        for target in targets:
            if target.split(".")[0] == "stages":
                out.add(target)  # the generic top-level name the wheel no longer has
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name:
                out.add(target)
    return out


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def test_the_package_has_no_import_cycle() -> None:
    assert _cycles(_graph()) == []


def test_the_core_imports_no_stage_and_no_command_line() -> None:
    bad = [
        (name, target)
        for name, targets in _graph().items()
        if _within(name, CORE)
        for target in targets
        if _within(target, (STAGES, "stages", *COMMAND_LINE))
    ]
    assert bad == []


def test_only_the_command_line_imports_the_command_line() -> None:
    bad = [
        (name, target)
        for name, targets in _graph().items()
        if not _within(name, COMMAND_LINE)
        for target in targets
        if _within(target, COMMAND_LINE)
    ]
    assert bad == []


def test_nothing_imports_a_top_level_stages_package() -> None:
    assert [(n, t) for n, ts in _graph().items() for t in ts if t.split(".")[0] == "stages"] == []


def test_the_checks_see_a_cycle_and_a_layer_break() -> None:
    # The rules above must be able to fail: a made-up graph with both faults.
    graph = {"sfb_video.model.a": {"sfb_video.stages.b"}, "sfb_video.stages.b": {"sfb_video.model.a"}}
    assert _cycles(graph) == [["sfb_video.model.a", "sfb_video.stages.b"]]
    assert _within("sfb_video.stages.b", (STAGES,)) and _within("sfb_video.model.a", CORE)
    assert len(_graph()) > 80  # every module was read
