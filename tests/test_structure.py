"""The package's layering: no import circle between the detector's command line and its real-frame
evaluation, and the drawing helpers below the packages that draw (detect/ and track/ never reach
up into report/)."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "pedcal"


def _imports(path: Path) -> set[str]:
    """Every pedcal module ``path`` imports, at its top or inside a function."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {m for m in out if m.startswith("pedcal")}


def _module(path: Path) -> str:
    return ".".join(path.relative_to(PKG.parent).with_suffix("").parts)


def _graph() -> dict[str, set[str]]:
    modules = {_module(p): p for p in PKG.rglob("*.py")}
    return {name: {m for m in _imports(p) if m in modules and m != name} for name, p in modules.items()}


def _reaches(graph: dict[str, set[str]], start: str, goal: str) -> bool:
    seen, todo = set(), [start]
    while todo:
        m = todo.pop()
        if m == goal:
            return True
        if m not in seen:
            seen.add(m)
            todo.extend(graph.get(m, ()))
    return False


def test_detector_cli_and_real_evaluation_import_no_circle():
    g = _graph()
    assert _reaches(g, "pedcal.detect.detect_cli", "pedcal.detect.files")
    assert _reaches(g, "pedcal.detect.real_eval", "pedcal.detect.files")
    assert not _reaches(g, "pedcal.detect.real_eval", "pedcal.detect.detect_cli")
    assert not _reaches(g, "pedcal.detect.files", "pedcal.detect.detect_cli")


def test_detect_and_track_do_not_reach_up_into_report():
    g = _graph()
    upward = {m: sorted(d for d in deps if d.startswith("pedcal.report"))
              for m, deps in g.items() if m.startswith(("pedcal.detect", "pedcal.track", "pedcal.plotting"))}
    assert not {m: d for m, d in upward.items() if d}
    assert "pedcal.plotting" in g["pedcal.report.figures"]


def test_the_graph_finds_an_import_inside_a_function(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from pedcal.report.figures import save_png\n")
    assert "pedcal.report.figures" in _imports(probe)
