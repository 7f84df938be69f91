import pytest

pytest.importorskip("pyvrp")

from tsac_bench.model import AAV, Depot, Instance, Task, TaskKind
from tsac_bench.model.evaluator import TIME_TOLERANCE, CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.planning import PlanningState
from tsac_bench.planning.solve import solve
from tsac_bench.solvers.pyvrp_peer import PyVRPAllocator, _Mapping


def test_known_optimal_split_is_found():
    # A 20 kg pickup 1 km from the depot and two 10 kg AAVs there: each must take 10 kg (a task
    # is visited once per AAV), both arrive at 50 s. E_base = 10 * 30 + 500 = 800.
    fast = {"speed": 20, "capacity": 10, "max_range": 30000, "alpha": 10, "lam": 500}
    instance = Instance(
        "split", (AAV("A0", 2, 0, 0, **fast), AAV("A1", 2, 0, 0, **fast)),
        (Depot("D0", 0, 0),), (Task("T0", 1000, 0, TaskKind.PICKUP, 20, 0, 3600),))
    outcome = solve(instance, PyVRPAllocator(max_iterations=500))
    assert outcome.evaluation.per_task[0].amounts == {"A0": 10, "A1": 10}
    assert outcome.cost == pytest.approx(10 * 50 / 3600 + 2 * 10 * 1 / 800, rel=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_mapping_keeps_windows_and_capacities(seed):
    import pyvrp
    from pyvrp.stop import MaxIterations

    instance = generate("8/20", seed)
    state = PlanningState.static(instance)
    mapping = _Mapping(state, None, 10.0)
    params = pyvrp.SolveParams(penalty=pyvrp.PenaltyParams(max_penalty=1e12))
    result = pyvrp.solve(mapping.problem_data(), MaxIterations(300), seed=0, params=params)
    assert result.is_feasible()
    evaluator = CostEvaluator(instance)
    for n, route in enumerate(mapping.decode(result.best)):
        trace = evaluator.trace(n, route)
        assert trace.errors == ()  # capacities and loads as PyVRP saw them
        for node, arrival in zip((v.node for v in route), trace.arrivals, strict=True):
            if node < instance.n_tasks:
                assert arrival <= instance.tasks[node].t_end + TIME_TOLERANCE


def test_pyvrp_is_deterministic_per_seed_and_records_its_version():
    instance = generate("4/10", 3)
    first = solve(instance, PyVRPAllocator(max_iterations=300), seed=4)
    again = solve(instance, PyVRPAllocator(max_iterations=300), seed=4)
    assert first.solution.routes == again.solution.routes
    assert first.stats["stop"] == "iterations"
    assert first.stats["solver_version"].startswith("0.14")
