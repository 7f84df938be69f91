"""The layers of the package, as the folders show them, and no two modules that import each
other. Imports inside functions count too: a lazy import still ties the layers together."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Where each installed package's files live (pyproject's package-dir).
SOURCES = {"tsac_bench": ROOT / "tsac_bench", "tsac_bench.solvers": ROOT / "solvers",
           "tsac_bench.formulations": ROOT / "formulations"}
#: Lower layers first; a module may import its own layer and the ones before it.
LAYERS = (
    ("tsac_bench.errors",),
    ("tsac_bench.model",),
    ("tsac_bench.planning",),
    ("tsac_bench.formulations",),
    ("tsac_bench.solvers",),
    ("tsac_bench.batch", "tsac_bench.testing"),
    # Inside reporting, each concept builds on the ones before it; figures depend only on
    # data types and statistics, as PyVRP's plotting does.
    ("tsac_bench.reporting", "tsac_bench.reporting.data"),
    ("tsac_bench.reporting.stats", "tsac_bench.reporting.budgets"),
    ("tsac_bench.reporting.tables", "tsac_bench.reporting.figures"),
    ("tsac_bench.reporting.budget_tables",),
    ("tsac_bench.reporting.report",),
    ("tsac_bench.cli", "tsac_bench.__main__", "tsac_bench"),
)


def module_files() -> dict[str, Path]:
    modules = {}
    for package, folder in SOURCES.items():
        for path in folder.rglob("*.py"):
            parts = path.relative_to(folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            name = ".".join((package, *parts))
            if package == "tsac_bench" and parts and parts[0] in ("solvers", "formulations"):
                continue
            modules[name] = path
    return modules


def imports_of(path: Path, known: set[str]) -> set[str]:
    """The project modules ``path`` imports: ``from P import name`` counts as P.name where
    that is a module, else as P."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name in known)
        elif isinstance(node, ast.ImportFrom) and node.module in known:
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                found.add(sub if sub in known else node.module)
    return found


def import_graph() -> dict[str, set[str]]:
    files = module_files()
    known = set(files)
    return {name: imports_of(path, known) - {name} for name, path in files.items()}


def layer_of(module: str) -> int:
    """The layer of the longest prefix naming ``module`` (``tsac_bench`` alone is the top)."""
    matches = [(len(prefix), rank) for rank, prefixes in enumerate(LAYERS) for prefix in prefixes
               if module == prefix or (prefix != "tsac_bench" and module.startswith(prefix + "."))]
    assert matches, f"{module} belongs to no layer: add it to LAYERS"
    return max(matches)[1]


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    return sorted(f"{a} (layer {layer_of(a)}) imports {b} (layer {layer_of(b)})"
                  for a, targets in graph.items() for b in targets if layer_of(b) > layer_of(a))


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

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


def test_every_module_is_in_a_layer_and_no_layer_imports_a_higher_one():
    graph = import_graph()
    assert "tsac_bench.model.evaluator" in graph and "tsac_bench.solvers.ocf.engine" in graph
    assert upward_imports(graph) == []


def test_reporting_reads_the_results_store_and_nothing_else_of_the_batch_layer():
    graph = import_graph()
    batch = {b for a, targets in graph.items() if a.startswith("tsac_bench.reporting")
             for b in targets if b.startswith("tsac_bench.batch")}
    assert batch == {"tsac_bench.batch.store"}


def test_no_two_modules_import_each_other():
    assert cycles(import_graph()) == []


def test_the_checks_catch_an_upward_import_and_a_cycle():
    graph = {"tsac_bench.model.evaluator": {"tsac_bench.batch.runner"},
             "tsac_bench.batch.runner": {"tsac_bench.reporting.figures"},
             "tsac_bench.reporting.figures": {"tsac_bench.batch.runner"}}
    assert upward_imports(graph) == [
        "tsac_bench.batch.runner (layer 5) imports tsac_bench.reporting.figures (layer 8)",
        "tsac_bench.model.evaluator (layer 1) imports tsac_bench.batch.runner (layer 5)"]
    assert cycles(graph) == [["tsac_bench.batch.runner", "tsac_bench.reporting.figures"]]
