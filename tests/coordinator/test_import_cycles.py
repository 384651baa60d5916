"""No import cycle in the service's packages (issue 39): a module's imports, at module level
and inside functions alike (a function-level import that closes a loop is a cycle that runs
only by luck of order), read from the source with ``ast``. An import of a module's own
package (its ``__init__``) is not an edge: the package is being initialised already."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("api", "coordinator", "planner", "sim_workers")


def modules(root: Path) -> dict[str, Path]:
    out = {}
    for path in root.rglob("*.py"):
        rel = path.relative_to(root)
        if rel.parts[0] in PACKAGES:
            name = ".".join(rel.with_suffix("").parts)
            out[name.removesuffix(".__init__")] = path
    return out


def _targets(mods: dict[str, Path], module: str, node: ast.AST) -> list[str]:
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        base = node.module or ""
        if node.level:
            pkg = module.split(".") if mods[module].name == "__init__.py" else module.split(".")[:-1]
            base = ".".join(pkg[:len(pkg) - node.level + 1] + ([base] if base else []))
        names = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
    out = []
    for name in names:
        parts = name.split(".")
        # the module and every package above it run when it is imported
        for k in range(1, len(parts) + 1):
            target = ".".join(parts[:k])
            if target in mods and target != module and not module.startswith(target + "."):
                out.append(target)
    return out


def import_graph(root: Path) -> dict[str, set[str]]:
    mods = modules(root)
    graph = {m: set() for m in mods}
    for module, path in mods.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                graph[module].update(_targets(mods, module, node))
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_packages_have_no_import_cycle():
    graph = import_graph(REPO)
    assert len(graph) > 100 and sum(map(len, graph.values())) > 300
    assert cycles(graph) == []


def test_a_cycle_through_a_function_level_import_is_found(tmp_path):
    pkg = tmp_path / "coordinator"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from coordinator.b import g\n")
    (pkg / "b.py").write_text("def g():\n    from . import c\n")
    (pkg / "c.py").write_text("import coordinator.a\n")
    assert cycles(import_graph(tmp_path)) == [["coordinator.a", "coordinator.b", "coordinator.c"]]
    (pkg / "c.py").write_text("import coordinator\n")          # its own package: not a cycle
    assert cycles(import_graph(tmp_path)) == []


def test_the_planner_package_loads_no_domain():
    """``import planner.domain`` used to run planner/__init__, which imported the container's
    task half (and clingo): the "no domain in the core" rule could not see it."""
    graph = import_graph(REPO)
    assert not any(t.startswith(("planner.container", "planner.stack_and_push")) for t in graph["planner"])


OLD_PATHS = {"session": "loop", "episode": "loop", "runner": "loop", "real_pose": "loop", "transit": "loop",
             "reality": "loop", "step_record": "loop", "observations": "loop", "transition_model": "transition",
             "experience": "transition", "fanout": "distributed", "shard_pools": "distributed",
             "reaper": "distributed", "gym_env": "integrations", "tracker": "integrations",
             "export": "integrations", "frames": "integrations", "grounding_bandit": "baselines",
             "gym_baselines": "baselines"}


def test_coordinator_is_grouped_by_concept_and_the_old_names_still_work():
    """Issue 39: coordinator/ was 31 flat files. Each moved module is still importable by
    its old name as the very same module (pickles, checkpoints, `gymnasium.make` ids and
    scripts name them), and every folder says what it is."""
    import importlib

    from coordinator import MOVED

    assert MOVED == OLD_PATHS
    for old, package in OLD_PATHS.items():
        moved = importlib.import_module(f"coordinator.{package}.{old}")
        assert importlib.import_module(f"coordinator.{old}") is moved, old
        assert importlib.import_module(f"coordinator.{package}").__doc__
    flat = [p.stem for p in (REPO / "coordinator").glob("*.py") if p.stem != "__init__"]
    assert len(flat) <= 8 and not set(flat) & set(OLD_PATHS), flat      # no file per old name


def test_the_reaper_still_runs_by_its_old_module_name():
    """`python -m coordinator.reaper` (an old name) runs the moved module as __main__."""
    import subprocess

    proc = subprocess.run([sys.executable, "-c", "import runpy, sys; sys.argv = ['x', '0']; "
                           "runpy.run_module('coordinator.reaper', run_name='__main__')"],
                          input=b"clean", capture_output=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
