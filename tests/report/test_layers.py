"""The reporting layer reads the results store but never loads the runner, and its modules
depend one way: data <- stats <- tables <- report, figures on data and stats only."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import tsac_bench.reporting

PACKAGE = Path(tsac_bench.reporting.__file__).parent
#: What each module may import from the reporting package (at any depth of its code).
ALLOWED = {
    "data": set(),
    "stats": {"data"},
    "tables": {"data", "stats"},
    "figures": {"data", "stats"},
    "report": {"data", "stats", "tables", "figures"},
}


def reporting_imports(name: str) -> set[str]:
    tree = ast.parse((PACKAGE / f"{name}.py").read_text(encoding="utf-8"))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "tsac_bench.reporting":
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom | ast.Import):
            modules = [node.module] if isinstance(node, ast.ImportFrom) else [
                alias.name for alias in node.names]
            found |= {m.removeprefix("tsac_bench.reporting.") for m in modules
                      if m and m.startswith("tsac_bench.reporting.")}
    return found


@pytest.mark.parametrize("name", sorted(ALLOWED))
def test_reporting_modules_import_only_below_them(name):
    assert reporting_imports(name) <= ALLOWED[name]


def test_every_reporting_module_is_placed():
    assert {p.stem for p in PACKAGE.glob("*.py")} - {"__init__"} == set(ALLOWED)


def test_the_report_does_not_load_the_runner():
    code = ("import sys, tsac_bench.reporting.report; "
            "print('tsac_bench.batch.runner' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert done.stdout.strip() == "False"
