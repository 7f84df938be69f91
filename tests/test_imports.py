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
