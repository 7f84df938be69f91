"""One benchmark job, run inside a worker process: the unit both executors share.

A job spec (``records.JobSpec``, JSON: the instance travels inside it, so cluster workers need
no shared file system) becomes a result (``records.JobResult``, JSON). Everything that can
go wrong inside the job (unknown method or mode, an allocator that raises, an invalid plan) is
caught here and returned as a result with a status, so one bad job never stops a batch. A job
that hangs or kills its process is handled by the caller, which runs it in a separate process
with a hard timeout (``run_in_subprocess`` here, or the local pool in ``executors``).

``python -m tsac_bench.batch.worker SPEC.json RESULT.json`` runs one job from files.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import signal
import socket
import subprocess
import sys
import tempfile
import traceback
from importlib import metadata
from pathlib import Path
from typing import Any

from tsac_bench.batch.records import JobResult, JobSpec

#: Packages whose versions a result records when the job imported them.
_VERSIONED_PACKAGES = {
    "numpy": "numpy", "scipy": "scipy", "pyomo": "pyomo", "highspy": "highspy",
    "ortools": "ortools", "cvxpy": "cvxpy", "torch": "torch", "gymnasium": "gymnasium",
}

#: Default seconds a job may overrun its solver time limit (imports, evaluation) before its
#: process is killed; a spec's ``grace`` overrides it.
GRACE_SECONDS = 30.0


def hard_timeout(spec: JobSpec) -> float | None:
    """Wall-clock seconds after which the job's process is killed.

    A dynamic run plans once at t = 0 and once per distinct release time, each plan under the
    time limit, so its budget grows with the number of events."""
    limit = spec.get("time_limit")
    if limit is None:
        return None
    plans = 1
    if spec["mode"] != "static":
        plans += len({t["release"] for t in spec["instance"]["tasks"] if t.get("release", 0) > 0})
    return plans * float(limit) * 1.5 + float(spec.get("grace", GRACE_SECONDS))


def failure(status: str, message: str, detail: str = "") -> JobResult:
    """The result of a job that produced no solution."""
    return JobResult(status=status, message=message, detail=detail, solution=None, J=None,
                     terms=None, runtime=None, stats={}, versions=_versions(None),
                     host=socket.gethostname())


#: The methods (name and settings) this process has run once untimed (``warm_up``).
_warmed: set[str] = set()
#: The instance and budget of that untimed run: small, so that it costs little.
WARM_UP_SCALE, WARM_UP_BUDGET = "3/6", 0.05


def warm_up(method: str, settings: dict[str, Any]) -> None:
    """Run ``method`` once, untimed, on a small generated instance before its first budgeted
    job in this process: loading a policy file, a compiled kernel or a solver library is not
    planning, and a budget of a tenth of a second would lose most of itself to it on that
    job alone. Whatever goes wrong here goes wrong again, recorded, in the job itself."""
    key = json.dumps([method, settings], sort_keys=True, default=str)
    if key in _warmed:
        return
    _warmed.add(key)
    from tsac_bench.model.generator import generate
    from tsac_bench.planning.solve import solve

    with contextlib.suppress(Exception):
        solve(generate(WARM_UP_SCALE, 0), method, settings=settings, budget=WARM_UP_BUDGET)


def execute_job(spec: JobSpec) -> JobResult:
    """Run one (instance, method, mode, seed) job; never raises for a job's own failure. A
    budgeted job's method is warmed up first (``warm_up``)."""
    from tsac_bench.errors import TsacBenchError
    from tsac_bench.model.io import instance_from_dict, solution_to_dict
    from tsac_bench.planning.solve import InvalidPlan, solve

    instance = instance_from_dict(spec["instance"], spec.get("instance_file", "<instance>"))
    try:
        budget = spec.get("budget")
        if budget is not None:
            warm_up(spec["method"], spec.get("settings") or {})
        outcome = solve(instance, spec["method"], seed=spec["seed"],
                        time_limit=spec.get("time_limit") if budget is None else None,
                        mode=spec["mode"], settings=spec.get("settings") or {}, budget=budget)
        solution, evaluation, stats = outcome.solution, outcome.evaluation, dict(outcome.stats)
    except InvalidPlan as exc:
        return failure("invalid", str(exc))
    except TsacBenchError as exc:
        return failure("error", str(exc))
    except Exception as exc:  # a plug-in may raise anything; the batch must go on
        text = f"{type(exc).__name__}: {exc}"
        return failure("error", text.splitlines()[0], traceback.format_exc())
    return JobResult(status="ok", message="", detail="",
                     solution=solution_to_dict(solution, instance), J=evaluation.J,
                     terms=dict(evaluation.terms), runtime=outcome.wall_time,
                     over_budget=outcome.over_budget if budget is not None else None,
                     stats=jsonable(stats), versions=_versions(spec["method"]),
                     host=socket.gethostname())


def jsonable(value: Any) -> Any:
    """Solver stats as plain JSON: numpy scalars become numbers, non-finite floats None, and
    anything else unknown its repr, so that a plug-in's stats can never break the store."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [jsonable(v) for v in value]
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    item = getattr(value, "item", None)
    if callable(item):
        try:
            return jsonable(item())
        except (TypeError, ValueError):
            pass
    tolist = getattr(value, "tolist", None)
    if callable(tolist):
        return jsonable(tolist())
    return repr(value)


def _versions(method: str | None) -> dict[str, str]:
    from tsac_bench.planning import ENTRY_POINT_GROUP

    versions = {"tsac-bench": metadata.version("tsac-bench"),
                "python": platform.python_version()}
    for module, dist in _VERSIONED_PACKAGES.items():
        if module in sys.modules:
            with contextlib.suppress(metadata.PackageNotFoundError):
                versions[dist] = metadata.version(dist)
    if method is not None:
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            if ep.name == method and ep.dist is not None:
                versions[f"plugin:{ep.dist.name}"] = ep.dist.version
    return versions


def run_in_subprocess(spec: JobSpec) -> JobResult:
    """Run one job in a fresh Python process, killed at the hard timeout.

    Used where the caller may not fork worker processes of its own (a Dask worker is a
    daemonic process); the job's result comes back through a file so that whatever a solver
    prints cannot corrupt it."""
    with tempfile.TemporaryDirectory(prefix="tsac-job-") as tmp:
        spec_file, result_file = Path(tmp, "spec.json"), Path(tmp, "result.json")
        spec_file.write_text(json.dumps(spec), encoding="utf-8")
        timeout = hard_timeout(spec)
        # A new session: on timeout the whole group goes, solver helper processes included.
        process = subprocess.Popen([sys.executable, "-m", "tsac_bench.batch.worker", str(spec_file),
                                    str(result_file)], stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True, start_new_session=True)
        try:
            _, stderr = process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            kill_group(process.pid)
            process.communicate()
            return failure("timeout", f"killed after {timeout:g} s (time limit "
                                      f"{spec.get('time_limit')} s)")
        if result_file.exists():
            return json.loads(result_file.read_text(encoding="utf-8"))
        return failure("crash", f"worker process exited with code {process.returncode}",
                       stderr[-4000:])


def kill_group(pid: int) -> None:
    """SIGKILL the process group led by ``pid``, or just the process where it leads none
    (yet: a worker killed before its ``setsid``; or no process groups on this platform)."""
    sigkill = getattr(signal, "SIGKILL", signal.SIGTERM)
    try:
        os.killpg(pid, sigkill)
        return
    except (AttributeError, ProcessLookupError, PermissionError):
        pass
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.kill(pid, sigkill)


def main(argv: list[str] | None = None) -> None:
    spec_file, result_file = argv or sys.argv[1:]
    result = execute_job(json.loads(Path(spec_file).read_text(encoding="utf-8")))
    Path(result_file).write_text(json.dumps(result), encoding="utf-8")


if __name__ == "__main__":
    main()
