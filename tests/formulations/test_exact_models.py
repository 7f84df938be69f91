"""The exact models against brute force and against the evaluator.

* every canonical plan is a point of the MILP whose objective is its J (so the MILP's optimum
  is <= J* ... ) and canonicalising never raises J;
* brute force == HiGHS == CP-SAT on random tiny instances (the MILP's optimum is the true one).
"""

from __future__ import annotations

import math

import pytest
from brute_force import brute_force
from plans import random_plan
from tiny import tiny_instance

from tsac_bench.formulations.cpsat import solve_cpsat_isolated
from tsac_bench.formulations.milp import (
    MilpOptions,
    build_milp,
    canonical_warm_start,
    decode,
    solve_milp,
    violated_constraints,
)
from tsac_bench.formulations.network import canonical_routes
from tsac_bench.model.evaluator import CostEvaluator

pyo = pytest.importorskip("pyomo.environ")


def close(a: float, b: float, rel: float = 1e-6) -> bool:
    return abs(a - b) <= rel * max(1.0, abs(b))


@pytest.mark.parametrize("seed", range(12))
def test_canonical_plans_are_model_points_with_objective_J(seed: int) -> None:
    instance = tiny_instance(seed, n_aavs=3, n_tasks=5, max_demand=6)
    evaluator = CostEvaluator(instance)
    plan = random_plan(instance, seed)
    before = evaluator.cost(plan)
    model = build_milp(instance)
    loaded = canonical_warm_start(model, plan)
    after = evaluator.cost(loaded)
    assert after <= before + 1e-9
    assert violated_constraints(model) == []
    assert math.isclose(pyo.value(model.J), after, rel_tol=1e-9, abs_tol=1e-9)


def test_canonical_form_drops_late_visits_and_excess() -> None:
    # Seed 1's random plan has late visits and over-supplied tasks (checked here).
    instance = tiny_instance(1, n_aavs=3, n_tasks=5, max_demand=6)
    evaluator = CostEvaluator(instance)
    plan = random_plan(instance, 1)
    result = evaluator.evaluate(plan)
    assert any(not ok for b in result.per_task for ok in b.on_time.values())
    canonical = evaluator.evaluate(canonical_routes(instance, plan))
    assert all(all(b.on_time.values()) for b in canonical.per_task)
    over = [sum(b.amounts.values()) > t.demand for b, t in zip(result.per_task,
                                                               instance.tasks, strict=True)]
    assert any(over)
    for b, task in zip(canonical.per_task, instance.tasks, strict=True):
        assert sum(b.amounts.values()) <= task.demand
    assert canonical.J < result.J


# (seed, tasks, max demand, tight range): 3 tasks fast, 4 tasks with one depot slower.
FAST = [(s, 3, 4 + s % 3, None) for s in range(30)]
SLOW = [(1000 + s, 4, 5, s % 2 == 0) for s in range(10)]


def _cross_check(seed: int, n_tasks: int, max_demand: int, tight: bool | None) -> None:
    instance = tiny_instance(seed, n_aavs=2, n_tasks=n_tasks, max_demand=max_demand,
                             tight_range=tight, n_depots=1 if n_tasks > 3 else None)
    J_brute, _ = brute_force(instance)
    model = build_milp(instance)
    report = solve_milp(model)
    assert report.status == "optimal"
    J_milp = CostEvaluator(instance).cost(decode(model))
    assert close(report.objective, J_milp)
    assert close(J_milp, J_brute), (J_milp, J_brute)
    assert report.lower_bound <= J_brute + 1e-6
    cpsat = solve_cpsat_isolated(instance)
    assert cpsat.stats["status"] == "optimal"
    assert close(cpsat.stats["objective"], J_brute), (cpsat.stats["objective"], J_brute)
    assert cpsat.stats["lower_bound"] <= J_brute + 1e-9


@pytest.mark.parametrize(("seed", "n_tasks", "max_demand", "tight"), FAST)
def test_brute_force_highs_cpsat_agree(seed: int, n_tasks: int, max_demand: int,
                                       tight: bool | None) -> None:
    _cross_check(seed, n_tasks, max_demand, tight)


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "n_tasks", "max_demand", "tight"), SLOW)
def test_brute_force_highs_cpsat_agree_four_tasks(seed: int, n_tasks: int, max_demand: int,
                                                  tight: bool | None) -> None:
    _cross_check(seed, n_tasks, max_demand, tight)


def test_the_tiny_optima_exercise_every_rule() -> None:
    """The cross-checked optima include splits, multi-trip routes, over-range visits and
    partial service: otherwise the agreement above would prove less than it claims."""
    seen = {"split": 0, "trips": 0, "over": 0, "partial": 0}
    for seed, n_tasks, max_demand, tight in FAST:
        instance = tiny_instance(seed, n_aavs=2, n_tasks=n_tasks, max_demand=max_demand,
                                 tight_range=tight)
        _, plan = brute_force(instance)
        result = CostEvaluator(instance).evaluate(plan)
        seen["split"] += sum(len(b.coalition) > 1 for b in result.per_task)
        seen["partial"] += sum(0 < b.cost.load < 1 for b in result.per_task)
        for trace in result.traces:
            depots = [v for v in trace.route if instance.is_depot(v.node)]
            seen["trips"] += len(depots) > 2
            seen["over"] += any(d > instance.aavs[trace.aav].max_range
                                for d, v in zip(trace.distance_at_arrival, trace.route,
                                                strict=True)
                                if not instance.is_depot(v.node))
    assert all(count >= 3 for count in seen.values()), seen


CPSAT_SIZE_SCRIPT = """
from tsac_bench.formulations.cpsat import build_cpsat
from tsac_bench.model.generator import generate

proto = build_cpsat(generate("3/8", 3))[0].Proto()
print(len(proto.variables), len(proto.constraints))
"""


def test_the_models_of_the_measured_3_8_instance_keep_their_size() -> None:
    # generate("3/8", 3) is the instance of the LP bounds in docs/formulations.md; a block of
    # either builder that adds or drops a variable or a row shows here. The counts are those
    # of the models before the builders were split into blocks (the same LP file and proto).
    import subprocess
    import sys

    from tsac_bench.model.generator import generate

    instance = generate("3/8", 3)
    full = build_milp(instance)
    plain = build_milp(instance, options=MilpOptions(
        symmetry=False, capacity_cuts=False, range_time_link=False, time_flow=False,
        cover_cuts=False))
    assert (full.nvariables(), full.nconstraints()) == (909, 1672)
    assert (plain.nvariables(), plain.nconstraints()) == (564, 867)
    # In a process of its own: ortools and highspy cannot share one (docs/formulations.md).
    done = subprocess.run([sys.executable, "-c", CPSAT_SIZE_SCRIPT], capture_output=True,
                          text=True, timeout=300, check=True)
    assert done.stdout.split() == ["968", "2959"]


WORKER_SCRIPT = """
from concurrent.futures import ProcessPoolExecutor

def job(seed):
    from tsac_bench.formulations.cpsat import solve_cpsat_isolated
    from tsac_bench.model.generator import generate
    return solve_cpsat_isolated(generate("2/4", seed)).stats["status"]

if __name__ == "__main__":
    with ProcessPoolExecutor(1) as pool:
        print(list(pool.map(job, [1])))
"""


def test_cpsat_inside_a_worker_process_lets_it_exit(tmp_path) -> None:
    # A worker that used CP-SAT once used to hang at exit: multiprocessing joined the idle
    # CP-SAT process before any atexit hook could shut its pool down.
    import subprocess
    import sys

    script = tmp_path / "run.py"
    script.write_text(WORKER_SCRIPT)
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "['optimal']" in done.stdout
