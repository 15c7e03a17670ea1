"""The package's modules import each other one way only (no circle, not even inside a function)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "sim2real"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def import_graph() -> dict[str, set[str]]:
    """Module -> the package modules it imports anywhere in its body (function bodies included)."""
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
                targets = [f"{base}.{alias.name}" for alias in node.names] + [base]
            for target in targets:
                # the deepest package module the import names (``from sim2real.identification import sysid`` -> sim2real.identification.sysid)
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target != name and target != "sim2real":
                    graph[name].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_import_graph_has_no_cycle():
    graph = import_graph()
    assert "sim2real.identification.fitting" in graph["sim2real.identification.diagnosis.candidates"], "the parser sees the package's imports"
    cycle = find_cycle(graph)
    assert cycle is None, " -> ".join(cycle or [])


def test_the_fitting_core_depends_on_nothing_above_it():
    graph = import_graph()

    def reach(start: str) -> set[str]:
        seen, todo = set(), [start]
        while todo:
            for nxt in graph[todo.pop()]:
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return seen

    for module in ("sim2real.identification.sysid", "sim2real.identification.fitting", "sim2real.identification.diagnosis"):
        assert not any(m.startswith("sim2real.report") for m in reach(module)), module
    loaded = subprocess.run(
        [sys.executable, "-c", "import sys, sim2real.identification.sysid; print(' '.join(sorted(sys.modules)))"],
        check=True, capture_output=True, text=True,
    ).stdout.split()
    assert not any(m.startswith("sim2real.report") for m in loaded)


def test_the_packages_export_public_names_only():
    """A package's ``__init__`` re-exports public names; a private one is imported from the module that defines it."""
    private = []
    for path in sorted(PACKAGE.rglob("__init__.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = [alias.asname or alias.name for node in tree.body if isinstance(node, ast.ImportFrom)
                 for alias in node.names]
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
                names += [e.value for e in getattr(node.value, "elts", []) if isinstance(e, ast.Constant)]
        private += [f"{module_name(path)}: {name}" for name in names if name.startswith("_") and not name.startswith("__")]
    assert not private, "private names exported:\n" + "\n".join(private)


# The stages of rules/ as packages, and which may import which (issue 31): a stage imports only the stages
# below it, never one above; the shared modules import no stage.
SHARED = {"errors", "files", "cli", "cache", "blas", "forked", "stats", "filters"}
MAY_IMPORT = {
    "shared": set(),
    "assets": {"shared"},
    "measurements": {"shared", "assets"},
    "lab": {"shared", "assets", "measurements"},
    "identification": {"shared", "assets", "measurements"},
    "excitation": {"shared", "assets", "measurements", "identification"},
    "dr": {"shared", "assets", "measurements", "identification"},
    # the report words the diagnosis, naming the runs the excitation designs (sim2real.excitation.names)
    "report": {"shared", "assets", "measurements", "identification", "excitation"},
    # what rules/common.smk reads: every stage's config files and built files, above them all (no stage imports it)
    "workflow": {"shared", "assets", "measurements", "lab", "identification", "excitation"},
}


def stage(module: str) -> str:
    part = module.split(".")[1] if "." in module else module
    if part in SHARED:
        return "shared"
    return part


def test_each_stage_imports_only_the_stages_below_it():
    graph = import_graph()
    stages = {stage(m) for m in graph if m != "sim2real"}
    assert stages == set(MAY_IMPORT), f"a package that is no stage, or a stage without a rule: {stages ^ set(MAY_IMPORT)}"
    upward = [f"{a} -> {b}" for a, targets in sorted(graph.items()) for b in sorted(targets)
              if stage(a) != stage(b) and stage(b) not in MAY_IMPORT[stage(a)]]
    assert not upward, "imports running back up the stages:\n" + "\n".join(upward)


def test_the_report_imports_no_module_of_the_lab():
    """The gap report replays the measured commands on the torque-driven arm the lab drives too; it takes that arm
    from the stage below both (``sim2real.assets.arm``), never from the virtual lab it is judged against."""
    graph = import_graph()
    assert "sim2real.assets.arm" in graph["sim2real.report.replay"], "the replay's arm is seen"
    into_lab = [f"{a} -> {b}" for a, targets in sorted(graph.items()) if stage(a) == "report"
                for b in sorted(targets) if stage(b) == "lab"]
    assert not into_lab, "the report imports the lab:\n" + "\n".join(into_lab)


def test_the_layering_check_sees_an_import_running_back_up():
    graph = {"sim2real.measurements.runs": {"sim2real.identification.fitting"}}
    upward = [(a, b) for a, targets in graph.items() for b in targets if stage(b) not in MAY_IMPORT[stage(a)]]
    assert upward == [("sim2real.measurements.runs", "sim2real.identification.fitting")]
