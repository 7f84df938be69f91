import subprocess
import sys

HEAVY = ("torch", "pyomo", "ortools", "highspy", "gymnasium", "cvxpy", "dask", "matplotlib",
         "pyvrp", "pandas", "numba")


def test_importing_the_package_and_the_cli_loads_no_solver_backend():
    # A fresh interpreter: what this test process imported already must not hide a leak.
    code = ("import sys, tsac_bench, tsac_bench.cli, tsac_bench.batch.runner, "
            "tsac_bench.planning.simulator; "
            f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert done.stdout.strip() == ""


def test_every_package_directory_is_listed_for_installation():
    # setuptools installs only the packages pyproject.toml lists: one left out works in an
    # editable checkout and is missing from a wheel.
    import tomllib
    from pathlib import Path

    root = Path(__file__).parent.parent
    config = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = set()
    for name, folder in config["package-dir"].items():
        for init in (root / folder).rglob("__init__.py"):
            parts = init.parent.relative_to(root / folder).parts
            found.add(".".join((name, *parts)))
    assert found - set(config["packages"]) == set()
