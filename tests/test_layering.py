"""The layering rule (README "What a run does"): data flow one way, so no import cycle inside ``sweep``; only
``tracking.py`` and ``report/`` import MLflow, and only ``tracking.py`` writes to it."""
from __future__ import annotations

import ast
import re
from pathlib import Path

from conftest import ROOT

SRC = ROOT / "src"
WRITES = re.compile(r"\.(log_metric|log_batch|log_param|log_artifact|set_tag|set_experiment_tag|create_run|"
                    r"create_experiment|set_terminated|delete_run|update_run)\(")


def modules() -> dict[str, Path]:
    return {".".join(p.relative_to(SRC).with_suffix("").parts).removesuffix(".__init__"): p
            for p in (SRC / "sweep").rglob("*.py")}


def imports(path: Path, known: dict[str, Path]) -> set[str]:
    """The ``sweep`` modules a file imports, at module level or inside functions (not those under
    ``if TYPE_CHECKING:``, which are for annotations and never run)."""
    out = set()
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):   # drop the TYPE_CHECKING blocks
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            node.body = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name in known}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("sweep"):
            for a in node.names:   # "from sweep.agents import rollout" imports a submodule
                sub = f"{node.module}.{a.name}"
                out.add(sub if sub in known else node.module)
    return out


def test_no_import_cycle_inside_sweep():
    known = modules()
    graph = {m: imports(p, known) - {m} for m, p in known.items()}
    state: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for n in graph.get(m, ()):
            assert state.get(n) != 1, "import cycle: " + " -> ".join([*path, m, n])
            if n not in state:
                visit(n, [*path, m])
        state[m] = 2

    for m in graph:
        if m not in state:
            visit(m, [])


def test_only_tracking_and_report_touch_mlflow_and_only_tracking_writes():
    for name, path in modules().items():
        text = path.read_text()
        uses_mlflow = re.search(r"^\s*(import mlflow|from mlflow)", text, re.M)
        if name == "sweep.tracking" or name.startswith("sweep.report"):
            if name.startswith("sweep.report"):
                assert not WRITES.search(text), f"{path}: report/ writes to MLflow"
            continue
        assert not uses_mlflow, f"{path}: MLflow is read only by report/ and tracking.py, written only by tracking.py"
