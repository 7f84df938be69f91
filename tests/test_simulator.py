"""The dynamic run of docs/model.md: committed prefixes, what a re-plan sees, checks on every
plan, the recorded cost curve; hand-computed on a one-AAV instance."""

import math
from dataclasses import replace

import pytest

from tsac_bench.model import AAV, Depot, Instance, Task, TaskKind, Visit
from tsac_bench.model.evaluator import CostEvaluator
from tsac_bench.model.generator import generate
from tsac_bench.planning import Anchor, PlanningState, PlanResult
from tsac_bench.planning.simulator import InvalidPlan, committed_prefixes, simulate
from tsac_bench.planning.solve import solve
from tsac_bench.solvers.greedy import GreedyAllocator

HEAVY = dict(speed=10.0, capacity=30, max_range=60_000.0, alpha=20.0, lam=2000.0)


def line(release: float) -> Instance:
    """A0 at the depot (0, 0); T0 1 km east (known at 0), T1 1 km north (released later).
    E_base = 20 * 60 + 2000 = 3200."""
    tasks = (Task("T0", 1000, 0, TaskKind.PICKUP, 5, 0, 3600, 0),
             Task("T1", 0, 1000, TaskKind.PICKUP, 5, release, 3600, release))
    return Instance("line", (AAV("A0", 1, 0, 0, **HEAVY),), (Depot("D0", 0, 0),), tasks)


T0, T1, D0 = 0, 1, 2


class Recording:
    """Wraps an allocator and keeps every planning state it was given and its answer."""

    def __init__(self, inner):
        self.inner, self.name = inner, inner.name
        self.calls: list[tuple[PlanningState, PlanResult]] = []

    def plan(self, state, *, seed=0, time_limit=None):
        result = self.inner.plan(state, seed=seed, time_limit=time_limit)
        self.calls.append((state, result))
        return result


def test_committed_prefix_is_every_visit_whose_previous_node_was_left():
    instance = line(50)
    trace = CostEvaluator(instance).trace(0, (Visit(T0, 5), Visit(D0)))
    assert trace.arrivals == (100.0, 200.0)
    assert committed_prefixes(instance, [trace], 50.0) == ((Visit(T0, 5),),)  # start left at 0
    assert committed_prefixes(instance, [trace], 99.9) == ((Visit(T0, 5),),)
    # dep_1 = tau_0 <= t
    assert committed_prefixes(instance, [trace], 100.0) == ((Visit(T0, 5), Visit(D0)),)
    empty = CostEvaluator(instance).trace(0, ())
    assert committed_prefixes(instance, [empty], 500.0) == ((),)


def test_replan_keeps_the_prefix_and_prices_the_curve_by_hand():
    instance = line(50)
    recorder = Recording(GreedyAllocator())
    run = simulate(instance, recorder)
    (first, plan0), (second, _) = recorder.calls
    assert first.visible == {T0} and plan0.routes == ((Visit(T0, 5), Visit(D0)),)
    # T0 is finished: the committed visit (under way, on time at 100) covers its demand.
    assert second.time == 50 and second.visible == {T1}
    assert second.committed == ((Visit(T0, 5),),)
    # Flying to T0 (arrives at 100), then T1 (sqrt(2) km on, 10 m/s), then home; the visits
    # the re-plan placed carry its time (they leave T0 at 100 > 50 all the same).
    assert run.routes == ((Visit(T0, 5), Visit(T1, 5, planned_at=50.0),
                           Visit(D0, planned_at=50.0)),)
    t0 = 10 * 100 / 3600 + 20 * 1.0 / 3200
    t1 = 10 * (100 + 100 * math.sqrt(2) - 50) / 3600 + 20 * math.sqrt(2) / 3200
    assert pytest.approx(t0 + t1, rel=1e-12) == run.evaluation.J
    r0, r1 = run.replans
    assert (r0.time, r0.released, r0.visible, r0.committed) == (0.0, ("T0",), 1, 0)
    assert pytest.approx(t0 + 110, rel=1e-12) == r0.J and r0.J_known == pytest.approx(t0)
    assert r0.J_known_before is None
    assert (r1.time, r1.released, r1.visible, r1.committed) == (50.0, ("T1",), 1, 1)
    assert r1.J_known_before == pytest.approx(t0 + 110, rel=1e-12)  # the Fig. 5 spike
    assert r1.J == r1.J_known == pytest.approx(t0 + t1, rel=1e-12)


def test_an_aav_under_way_leaves_its_anchor_when_it_reaches_it():
    # At t = 150 A0 has reached T0 (100) and left it for D0: its whole plan is committed
    # and T0 is covered by a committed visit, so only T1 is visible. A0 reaches D0 at 200,
    # after the re-plan, and leaves it for T1 at once.
    instance = line(150)
    recorder = Recording(GreedyAllocator())
    run = simulate(instance, recorder)
    state = recorder.calls[1][0]
    assert state.committed == ((Visit(T0, 5), Visit(D0)),)
    assert state.visible == {T1}
    assert state.anchor(0) == Anchor(D0, 200.0, 2000.0, None)
    assert run.routes == ((Visit(T0, 5), Visit(D0), Visit(T1, 5, planned_at=150.0),
                           Visit(D0, planned_at=150.0)),)
    assert run.evaluation.traces[0].arrivals == (100.0, 200.0, 300.0, 400.0)


def test_an_idle_aav_leaves_at_the_replan_not_at_its_last_arrival():
    # A0 is back at D0 at 200, idle; T1 (1 km north, window [250, 3600]) is released at 250.
    # It can leave only then: T1 at 250 + 100 = 350, home at 450 (Eq. 7 alone would time it
    # from 200 and reach T1 at 300, before anybody knew of it).
    instance = line(250)
    recorder = Recording(GreedyAllocator())
    run = simulate(instance, recorder)
    state = recorder.calls[1][0]
    assert state.committed == ((Visit(T0, 5), Visit(D0)),)
    assert state.anchor(0) == Anchor(D0, 250.0, 2000.0, None)
    assert run.routes == ((Visit(T0, 5), Visit(D0), Visit(T1, 5, planned_at=250.0),
                           Visit(D0, planned_at=250.0)),)
    trace = run.evaluation.traces[0]
    assert trace.departures == (0.0, 100.0, 250.0, 350.0)
    assert trace.arrivals == (100.0, 200.0, 350.0, 450.0)
    # T0: on time at 100, C_time 100 / 3600, 1 km at alpha 20; T1: (350 - 250) / 3600.
    op = 20 * 1.0 / 3200
    assert pytest.approx(10 * 100 / 3600 + op + 10 * 100 / 3600 + op,
                                             rel=1e-12) == run.evaluation.J
    assert recorder.calls[1][1].routes[0][2].planned_at is None  # the simulator stamps


def deliveries(release: float) -> Instance:
    """A0 at (0, 0) beside D0 (0, 0); deliveries T0 (1 km east, known at 0) and T1 (2 km
    east, released later), 5 kg each."""
    tasks = (Task("T0", 1000, 0, TaskKind.DELIVERY, 5, 0, 3600, 0),
             Task("T1", 2000, 0, TaskKind.DELIVERY, 5, release, 3600, release))
    return Instance("deliveries", (AAV("A0", 1, 0, 0, **HEAVY),), (Depot("D0", 0, 0),), tasks)


def test_goods_not_loaded_at_the_depot_need_another_depot_visit():
    # The plan at 0 is [D0, T0 5, D0]: A0 leaves D0 at 0 with T0's 5 kg. At 50 it is flying
    # to T0, so D0 records load 5: T1's goods were never loaded, and A0 must fetch them
    # (T0 at 100, D0 at 200, T1 at 400, D0 at 600) instead of flying on to T1 (200).
    instance = deliveries(50)
    recorder = Recording(GreedyAllocator())
    run = simulate(instance, recorder)
    state = recorder.calls[1][0]
    assert state.committed == ((Visit(D0, load=5), Visit(T0, 5)),)
    assert state.anchor(0) == Anchor(T0, 100.0, 1000.0, 0)
    assert run.routes == ((Visit(D0, load=5), Visit(T0, 5), Visit(D0, planned_at=50.0),
                           Visit(T1, 5, planned_at=50.0), Visit(D0, planned_at=50.0)),)
    trace = run.evaluation.traces[0]
    assert trace.arrivals == (0.0, 100.0, 200.0, 400.0, 600.0)
    op = 20 * 1.0 / 3200
    assert pytest.approx(10 * 100 / 3600 + op + 10 * 350 / 3600 + 2 * op,
                                             rel=1e-12) == run.evaluation.J
    # The route that delivers T1 from D0's first load is infeasible with the record.
    flown_on = (Visit(D0, load=5), Visit(T0, 5), Visit(T1, 5), Visit(D0))
    errors = CostEvaluator(instance).trace(0, flown_on).errors
    assert [e.code for e in errors] == ["load-exceeded"]


def test_a_task_whose_window_closed_is_not_offered_again():
    instance = line(150)
    tasks = (replace(instance.tasks[0], t_start=0, t_end=50), instance.tasks[1])
    instance = replace(instance, tasks=tasks)

    class Idle:
        name = "idle"

        def plan(self, state, *, seed=0, time_limit=None):
            return PlanResult(state.base_routes())

    recorder = Recording(Idle())
    simulate(instance, recorder)
    assert recorder.calls[1][0].visible == {T1}  # T0 closed at 50, never served


class Adversary:
    """Plans like greedy, then breaks one rule at the re-plan."""

    name = "adversary"

    def __init__(self, cheat):
        self.cheat = cheat

    def plan(self, state, *, seed=0, time_limit=None):
        routes = GreedyAllocator().plan(state).routes
        if state.time > 0:
            routes = self.cheat(state, routes)
        return PlanResult(routes)


def drop_first_committed_visit(state, routes):
    return tuple(r[1:] if c else r for r, c in zip(routes, state.committed, strict=True))


def change_a_committed_amount(state, routes):
    n = next(n for n, c in enumerate(state.committed) if c)
    first = routes[n][0]
    return (*routes[:n], (Visit(first.node, first.amount + 1), *routes[n][1:]),
            *routes[n + 1:])


def visit_an_unreleased_task(state, routes):
    hidden = next(m for m in range(state.instance.n_tasks) if m not in state.visible)
    depot = state.instance.nearest_depot(hidden)
    return (*routes[:-1], (*routes[-1], Visit(depot), Visit(hidden, 1), Visit(depot)))


def overload(state, routes):
    n = len(routes) - 1
    m = next(iter(state.visible))
    depot = state.instance.nearest_depot(m)
    big = state.instance.aavs[n].capacity + 1
    return (*routes[:n], (*routes[n], Visit(depot), Visit(m, big), Visit(depot)))


@pytest.mark.parametrize(("cheat", "message"), [
    (drop_first_committed_visit, "committed prefix was changed"),
    (change_a_committed_amount, "committed prefix was changed"),
    (visit_an_unreleased_task, "not visible"),
    (overload, "infeasible plan"),
])
def test_a_replan_that_breaks_a_rule_stops_the_run(cheat, message):
    instance = generate("4/10", seed=3)
    with pytest.raises(InvalidPlan, match=message):
        simulate(instance, Adversary(cheat))
    with pytest.raises(InvalidPlan, match=message):
        solve(instance, Adversary(cheat), mode="dynamic")


def without_loads(route):
    return tuple(v._replace(load=None) for v in route)


@pytest.mark.parametrize("method", ["greedy", "rocf", "hocf"])
def test_every_replan_keeps_every_earlier_prefix(method):
    from tsac_bench.planning import make_allocator

    instance = generate("8/20", seed=5)
    recorder = Recording(make_allocator(method))
    run = simulate(instance, recorder, seed=2)
    assert len(recorder.calls) == 3  # t = 0 and the generator's two events
    for i, (state, _) in enumerate(recorder.calls):
        assert state.visible <= instance.released_by(state.time)
        # Later re-plans record the loads of depots left since; nothing else changes.
        for _, later in recorder.calls[i:]:
            for prefix, route in zip(state.committed, later.routes, strict=True):
                assert without_loads(route[:len(prefix)]) == without_loads(prefix)
        for prefix, route in zip(state.committed, run.routes, strict=True):
            assert without_loads(route[:len(prefix)]) == without_loads(prefix)
            assert all(v.load in (None, w.load) for v, w in zip(prefix, route, strict=False))
    assert run.evaluation.feasible


@pytest.mark.parametrize("method", ["greedy", "rocf", "hocf"])
def test_static_mode_is_one_plan_call(method):
    from tsac_bench.planning import make_allocator

    instance = generate("8/20", seed=4)
    direct = make_allocator(method).plan(PlanningState.static(instance), seed=3)
    outcome = solve(instance, method, seed=3, mode="static")
    assert outcome.solution.routes == direct.routes
    assert outcome.cost == CostEvaluator(instance).cost(direct.routes)
    # A dynamic run with nothing released late is that same single call.
    at_once = replace(instance, tasks=tuple(replace(t, release=0) for t in instance.tasks))
    dynamic = solve(at_once, method, seed=3, mode="dynamic")
    assert len(dynamic.stats["replans"]) == 1
    assert dynamic.solution.routes == direct.routes


def test_unknown_mode_is_a_user_error():
    from tsac_bench.errors import TsacBenchError

    with pytest.raises(TsacBenchError, match="unknown mode 'online'"):
        solve(line(50), "greedy", mode="online")


def test_replan_seeds_are_derived_and_fit_a_signed_32_bit_int():
    seeds = []

    class SeedRecorder(GreedyAllocator):
        def plan(self, state, *, seed=0, time_limit=None):
            seeds.append(seed)
            return super().plan(state, seed=seed, time_limit=time_limit)

    simulate(generate("4/10", 5), SeedRecorder(), seed=7)
    assert seeds[0] == 7 and len(seeds) == 3  # t = 0 and the generator's two events
    assert len(set(seeds)) == 3 and all(0 <= s < 2**31 for s in seeds)


class Cheat:
    """Plans like greedy at t = 0; at the re-plan returns ``routes(state)`` as they are."""

    name = "cheat"

    def __init__(self, routes):
        self.routes = routes

    def plan(self, state, *, seed=0, time_limit=None):
        if state.time == 0:
            return GreedyAllocator().plan(state)
        return PlanResult(self.routes(state))


def test_delivering_goods_never_loaded_is_an_error_of_the_method():
    # At 50 A0 left D0 with T0's 5 kg; flying on from T0 to T1 needs 5 kg more.
    flown_on = Cheat(lambda state: ((*state.committed[0], Visit(T1, 5), Visit(D0)),))
    with pytest.raises(InvalidPlan, match="load-exceeded"):
        simulate(deliveries(50), flown_on)


def test_writing_a_stamp_is_the_simulators_job():
    extra = Cheat(lambda state: ((*state.committed[0], Visit(D0, load=5), Visit(T1, 5),
                                  Visit(D0)),))
    with pytest.raises(InvalidPlan, match="carries a stamp"):
        simulate(deliveries(50), extra)
    early = Cheat(lambda state: ((*state.committed[0], Visit(D0, planned_at=0.0),
                                  Visit(T1, 5), Visit(D0)),))
    with pytest.raises(InvalidPlan, match="carries a stamp"):
        simulate(deliveries(50), early)


@pytest.mark.parametrize(("instance", "J"), [
    (line(250), 2 * (10 * 100 / 3600 + 20 * 1.0 / 3200)),
    (deliveries(50), 10 * 100 / 3600 + 20 * 1.0 / 3200 + 10 * 350 / 3600 + 2 * 20 / 3200),
], ids=["idle-aav", "unloaded-goods"])
def test_the_exact_milp_plans_the_physical_optimum_of_the_hand_cases(instance, J):
    outcome = solve(instance, "exact", mode="dynamic")
    assert outcome.stats["replans"][-1]["stats"]["status"] == "optimal"
    assert outcome.cost == pytest.approx(J, rel=1e-9)
    assert outcome.claim_matches
