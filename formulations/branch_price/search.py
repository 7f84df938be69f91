"""The search of ``exact-bp`` (docs/formulations.md, "Branching and search"): best-bound
order over open nodes, each node's column generation and cuts, dives for plans, the
integer master between nodes, and the stop at the time limit with the least open bound."""

from __future__ import annotations

import heapq
import itertools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tsac_bench.formulations.branch_price.branching import Brancher, other_side
from tsac_bench.formulations.branch_price.column_generation import (
    ColumnGeneration,
    reaches,
)
from tsac_bench.formulations.branch_price.columns import BranchDecision, Kind, Side
from tsac_bench.formulations.branch_price.master import INTEGRALITY, Master
from tsac_bench.formulations.branch_price.options import BranchPriceOptions
from tsac_bench.formulations.network import canonical_routes
from tsac_bench.formulations.pricing import schedule_tail
from tsac_bench.model import Instance, Route

#: The integer master (``master_mip_nodes`` > 0) runs at the root and then whenever the
#: columns have grown by this factor since its last run: new columns, new combinations.
MASTER_MIP_GROWTH = 1.5
#: ... for at most this share of the time left, so that the search keeps most of it,
MASTER_MIP_SHARE = 0.1
#: ... and for at most this long without a time limit.
MASTER_MIP_SECONDS = 60.0
#: A dive fixes to 0, with each step, the visits nearer to 0 than this: from 20 tasks up it
#: is otherwise a step per visit.
DIVE_DROP = 0.1
#: An integral LP whose plan's J exceeds its value by more than this (relative) is a bug.
INTEGRAL_LP_AGREEMENT = 1e-6

Plan = tuple[Route, ...]
Basis = tuple[list, list]


@dataclass
class BranchPriceResult:
    routes: Plan
    J: float
    lower_bound: float | None  # None where no exact pricing finished in time
    status: str  # optimal | feasible | error
    stats: dict[str, Any]


@dataclass
class _Incumbent:
    evaluator: Any
    routes: Plan
    J: float

    def offer(self, plan: Plan) -> tuple[float, bool]:
        """The plan's J, and whether it replaced the incumbent."""
        J = self.evaluator.cost(plan)
        if not reaches(J, self.J):
            self.J, self.routes = J, plan
            return J, True
        return J, False


@dataclass
class _OpenNodes:
    """Open nodes as a heap of (bound, tie-break, decisions, the parent's final LP basis or
    None), the tie-break their order of creation; ``moved``: the children of visit
    branches, by tie-break: (AAV, task), side, how far x_km moves, the parent's LP value.
    The rise of a child explored further feeds the pseudo-costs (a pruned child's LP is
    mostly cut short at the incumbent)."""

    heap: list = field(default_factory=lambda: [(-math.inf, 0, (), None)])
    counter: Any = field(default_factory=lambda: itertools.count(1))
    moved: dict[int, tuple[tuple[int, int], int, float, float]] = field(default_factory=dict)

    def push(self, bound: float, decisions: tuple[BranchDecision, ...],
             basis: Basis | None) -> int:
        tie = next(self.counter)
        heapq.heappush(self.heap, (bound, tie, decisions, basis))
        return tie


@dataclass
class _Run:
    """What one ``solve`` counts and times."""

    began: float
    deadline: float
    clock: dict[str, float] = field(default_factory=lambda: dict.fromkeys(
        ("lp", "pricing", "cuts", "branching", "master_mip", "dive"), 0.0))
    nodes: int = 0
    branches: dict[Kind, int] = field(default_factory=lambda: dict.fromkeys(Kind, 0))
    root_bound: float | None = None
    status: str = "optimal"
    stop_reason: str = "optimal"
    dives: int = 0
    dive_lps: int = 0  # master LPs the dives solved
    dive_improved: int = 0
    mip_columns: int = 0  # the columns at the integer master's last run (0: not yet run)
    mip_improved: int = 0


class BranchPrice:
    """The whole method for one planning state (tasks, committed prefixes): ``master``
    (the LP and its columns), ``pricing`` (column generation) and ``branching``.
    ``reach``: per AAV, the tasks its free visits may take (None: every task of the state),
    as a neighbourhood search holds most AAVs to their routes (``neighbourhoods.py``)."""

    def __init__(self, instance: Instance, tasks: Sequence[int] | None = None,
                 committed: Sequence[Route] | None = None, plan_time: float = 0.0,
                 options: BranchPriceOptions | None = None,
                 reach: Sequence[frozenset[int] | None] | None = None) -> None:
        self.master = Master(instance, tasks, committed, plan_time,
                             options if options is not None else BranchPriceOptions(), reach)
        self.options = self.master.options
        self.pricing = ColumnGeneration(self.master)
        self.branching = Brancher(self.master)

    def root(self, time_limit: float | None = None) -> dict[str, float]:
        """The root LP by column generation alone (no incumbent, no branching): its value,
        the Lagrangian bound, whether it converged, columns and seconds."""
        began = time.perf_counter()
        deadline = math.inf if time_limit is None else began + time_limit
        clock = {"lp": 0.0, "pricing": 0.0, "cuts": 0.0}
        value, bound, _, converged = self.pricing.cut_and_price(self.master.apply(()),
                                                                math.inf, deadline, clock)
        return {"lp": value, "bound": bound if not converged else value,
                "converged": converged, "columns": self.master.generated,
                "seconds": time.perf_counter() - began}

    def solve(self, starts: Sequence[Plan], time_limit: float | None = None
              ) -> BranchPriceResult:
        """The optimum from the best of ``starts`` on (each plan's routes are columns), or
        at ``time_limit`` the best plan and the least bound of the open nodes."""
        began = time.perf_counter()
        run = _Run(began, math.inf if time_limit is None else began + time_limit)
        best = self._start(starts)
        open_nodes = _OpenNodes()
        while open_nodes.heap:
            bound, tie, decisions, basis = heapq.heappop(open_nodes.heap)
            parent = open_nodes.moved.pop(tie, None)
            if reaches(bound, best.J):
                continue
            if time.perf_counter() >= run.deadline:
                open_nodes.push(bound, decisions, basis)
                run.status, run.stop_reason = "feasible", "time limit"
                break
            if run.nodes and self.options.master_mip_nodes and \
                    self.master.generated >= MASTER_MIP_GROWTH * run.mip_columns:
                self._integer_master(run, best)  # between nodes: the LP at the root's bounds
                if reaches(bound, best.J):
                    continue
            error = self._node(bound, decisions, basis, parent, run, best, open_nodes)
            if error is not None:
                run.status, run.stop_reason = "error", error
                break
        return self._result(run, best, open_nodes)

    def _start(self, starts: Sequence[Plan]) -> _Incumbent:
        """The best of ``starts`` as the incumbent; every start in canonical form, its
        routes the first columns (the integer master and the dives combine them)."""
        if not starts:
            raise ValueError("exact-bp needs at least one start plan")
        evaluator = self.master.evaluator
        best = min((self._start_columns(plan) for plan in starts), key=evaluator.cost)
        return _Incumbent(evaluator, best, evaluator.cost(best))

    def _start_columns(self, plan: Plan) -> Plan:
        """A start plan in canonical form, its routes added as columns, each task closed by
        its latest member (the plan's J exactly)."""
        master = self.master
        free = [len(p) for p in master.committed]
        routes = canonical_routes(master.instance, plan, free, master.plan_time)
        latest: dict[int, tuple[float, int]] = {}
        for trace in master.evaluator.evaluate(routes).traces:
            for m, c in trace.contributions:
                latest[m] = max(latest.get(m, (-math.inf, -1)), (c.arrival, trace.aav))
        for n, route in enumerate(routes):
            tail = schedule_tail(master.instance, route, free[n])
            if tail:
                master.add_column(n, tail, frozenset(m for m, (_, k) in latest.items()
                                                     if k == n))
        return routes

    def _node(self, bound: float, decisions: tuple[BranchDecision, ...],
              basis: Basis | None, parent: tuple | None, run: _Run, best: _Incumbent,
              open_nodes: _OpenNodes) -> str | None:
        """Solve one node; it is pruned, kept open (cut short), closed by its integral LP or
        branched. An error message where an integral LP's plan disagrees with it."""
        master = self.master
        run.nodes += 1
        restrictions = master.apply(decisions)
        master.restore_basis(basis)
        lp = self.pricing.cut_and_price(restrictions, best.J, run.deadline, run.clock)
        node_bound = max(lp.bound, bound)
        if run.root_bound is None:
            run.root_bound = node_bound
        best.offer(master.rounded_plan(lp.x))
        if reaches(node_bound, best.J):
            return None
        if not lp.converged:  # the deadline: keep the node open with its bound
            open_nodes.push(node_bound, decisions, basis)
            return None
        if master.infeasible(lp.x):
            return None
        if parent is not None:
            key, side, move, parent_value = parent
            self.branching.record_rise(key, side, lp.value - parent_value, move)
        x = lp.x
        # The dives' share is counted in master LPs, not seconds: the same search then
        # dives from the same nodes on any machine (same seed, same result).
        if self.options.dive_share and \
                run.dive_lps <= self.options.dive_share * (master.lp_solves - run.dive_lps):
            x = self._dive_from(decisions, x, run, best)
            if reaches(node_bound, best.J):
                return None
        if time.perf_counter() >= run.deadline:
            # The node stays open rather than strong branching past the limit.
            open_nodes.push(node_bound, decisions, basis)
            return None
        # Here the LP is the node's (its reduced costs rank the columns) and the basis its
        # children will start from is the present one.
        x, open_nodes.heap = master.purge_columns(x, open_nodes.heap)
        return self._branch(x, lp.value, node_bound, decisions, run, best, open_nodes)

    def _branch(self, x: np.ndarray, value: float, node_bound: float,
                decisions: tuple[BranchDecision, ...], run: _Run, best: _Incumbent,
                open_nodes: _OpenNodes) -> str | None:
        """Two children of the node, or its integral LP's plan offered (an error message
        where that plan's J is above the LP value)."""
        choosing = time.perf_counter()
        choice = self.branching.choose(x)
        run.clock["branching"] += time.perf_counter() - choosing
        if isinstance(choice, BranchDecision):
            run.branches[choice.kind] += 1
            basis = self.master.basis()
            v = self.master.visits(x).get((choice.aav, choice.key), 0.0) \
                if choice.kind is Kind.VISIT else None
            for index, side in enumerate((choice, other_side(choice))):
                tie = open_nodes.push(node_bound, (*decisions, side), basis)
                if v is not None:
                    open_nodes.moved[tie] = ((choice.aav, choice.key), index,
                                             (v, 1.0 - v)[index], value)
            return None
        J, _ = best.offer(choice)
        if value + INTEGRAL_LP_AGREEMENT * max(1.0, abs(value)) < J:
            return f"integral LP {value} but its plan has J {J}"
        return None

    def _integer_master(self, run: _Run, best: _Incumbent) -> None:
        run.mip_columns = self.master.generated
        solving = time.perf_counter()
        left = run.deadline - solving
        plan = self.master.integer_master_plan(
            best.J, MASTER_MIP_SECONDS if left == math.inf else MASTER_MIP_SHARE * left)
        run.clock["master_mip"] += time.perf_counter() - solving
        if plan is not None:
            run.mip_improved += best.offer(plan)[1]

    def _dive_from(self, decisions: tuple[BranchDecision, ...], x: np.ndarray, run: _Run,
                   best: _Incumbent) -> np.ndarray:
        """A dive from the node, its plans offered; the node's LP again, for branching."""
        master = self.master
        diving, solves = time.perf_counter(), master.lp_solves
        saved = master.basis()
        for plan in self.dive(decisions, x, run.deadline):
            run.dive_improved += best.offer(plan)[1]
        master.apply(decisions)
        master.restore_basis(saved)
        _, x, _ = master.solve_lp()
        run.dives += 1
        run.dive_lps += master.lp_solves - solves
        run.clock["dive"] += time.perf_counter() - diving
        return x

    def dive(self, decisions: tuple[BranchDecision, ...], x: np.ndarray, deadline: float
             ) -> list[Plan]:
        """Diving (Sadykov, Lazarev, Shmonin, Uchoa, Vanderbeck and Yakovlev 2019): from a
        node's LP solution, fix the fractional visit x_km nearest to 0 or 1 to that value
        (and the visits nearer to 0 than DIVE_DROP to 0), re-run column generation with
        heuristic pricing only, and repeat; once the visits are integral, go down the
        branching rule's later steps (the earlier side of an arrival window, arcs and
        amounts rounded) until the LP is integral or needs its artificial columns. Returns
        the plans read off the way (each AAV's column of largest lambda, and the integral
        LP's plan): the best-bound search reaches such deep plans late or never. The
        node's bounds are restored by the next ``apply``; the columns priced on the way
        stay (columns like any other)."""
        plans = []
        clock = dict.fromkeys(("lp", "pricing"), 0.0)  # the caller times the dive whole
        while time.perf_counter() < deadline:
            plans.append(self.master.rounded_plan(x))
            steps = self._dive_steps(x)
            if not isinstance(steps, list):
                plans.append(steps)  # the LP is integral: this plan is its solution
                return plans
            decisions = (*decisions, *steps)
            x = self.pricing.column_generation(self.master.apply(decisions), math.inf,
                                               deadline, clock, heuristic_only=True).x
            if self.master.infeasible(x):
                break
        return plans

    def _dive_steps(self, x: np.ndarray) -> list[BranchDecision] | Plan:
        """A dive's next decisions at the LP point ``x``, or the plan of an integral LP.
        The visit nearest to 0 or 1 goes there, and with it every visit nearer to 0 than
        DIVE_DROP (a "0" side never empties the LP; several "1"s of an AAV could)."""
        fractional = [(min(v, 1.0 - v), key, v) for key, v in self.master.visits(x).items()
                      if INTEGRALITY < v < 1.0 - INTEGRALITY]
        if fractional:
            _, (k, m), v = min(fractional)
            steps = [BranchDecision(Kind.VISIT, k, m,
                                    Side.REQUIRED if v >= 0.5 else Side.EXCLUDED)]
            steps += [BranchDecision(Kind.VISIT, *key, Side.EXCLUDED)
                      for _, key, w in fractional if w < DIVE_DROP and key != (k, m)]
            return steps
        step = self.branching.choose(x)
        if not isinstance(step, BranchDecision):
            return step
        return [self.branching.dive_side(step, x)]

    def _result(self, run: _Run, best: _Incumbent, open_nodes: _OpenNodes
                ) -> BranchPriceResult:
        master = self.master
        open_bounds = [b for b, _, _, _ in open_nodes.heap]
        global_bound = min([best.J, *open_bounds]) if run.status != "optimal" else best.J
        if run.status == "feasible" and not open_bounds:
            run.status, run.stop_reason = "optimal", "optimal"
        clock = run.clock
        stats = {
            "status": run.status,
            "stop_reason": run.stop_reason,
            "J": best.J,
            "lower_bound": _finite(global_bound),
            "root_bound": _finite(run.root_bound),
            "nodes": run.nodes,
            "open_nodes": len(open_nodes.heap),
            **{f"{kind.value}_branches": count for kind, count in run.branches.items()},
            "columns": master.generated,
            "purged_columns": master.purged,
            "lp_solves": master.lp_solves,
            "lp_time": clock["lp"],
            "pricing_time": clock["pricing"],
            "arrival_cuts": sum(map(len, master.arrival_cuts.values())),
            "cut_time": clock["cuts"],
            "branching_time": clock["branching"],
            "master_mip_time": clock["master_mip"],
            "master_mip_improvements": run.mip_improved,
            "dive_time": clock["dive"],
            "dives": run.dives,
            "dive_improvements": run.dive_improved,
            "other_time": time.perf_counter() - run.began - sum(clock.values()),
            "wall_time": time.perf_counter() - run.began,
        }
        return BranchPriceResult(tuple(best.routes), best.J, _finite(global_bound),
                                 run.status, stats)


def _finite(value: float | None) -> float | None:
    """A bound, or None where none was proven (no exact pricing finished in time)."""
    return value if value is not None and math.isfinite(value) else None
