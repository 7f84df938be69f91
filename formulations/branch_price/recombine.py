"""Plans put together from the routes of other plans: the route master over the routes of
many plans of one instance, solved as an integer program (docs/formulations.md,
"Recombining plans"). Heuristics that differ by their seed find different good routes; the
best plan over all their routes is at most the best of them, and often below it."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from tsac_bench.formulations.branch_price.master import Master
from tsac_bench.formulations.branch_price.options import BranchPriceOptions
from tsac_bench.formulations.network import canonical_routes
from tsac_bench.formulations.pricing import schedule_tail
from tsac_bench.model import Instance, Route

Plan = tuple[Route, ...]

#: The master's rows that are exact at every integer point of routes with fixed amounts:
#: the goods-time rows may cut off plans that over-deliver (a recombination of two plans
#: may), and the symmetry rows would keep an AAV from another identical AAV's route.
RECOMBINATION_OPTIONS = BranchPriceOptions(goods_time_rows=False, symmetry=False)


def recombined_plan(instance: Instance, plans: Sequence[Plan], time_limit: float
                    ) -> Plan | None:
    """The plan of least J over the routes of the static ``plans`` (each AAV takes one of
    the routes that any plan gives it or an AAV identical to it), as far as HiGHS's MIP gets
    in ``time_limit`` seconds from the best of ``plans``; None if it found none. The routes
    enter with no closing set and the MIP chooses the closers (z_cm <= lambda_c): one closer
    per task gives the exact C_time, since the per-AAV time rows already lift Ctime_m to the
    latest member, and routes from different plans cannot all keep their own closing sets.
    So the MIP's objective is each integer point's J, and its plan is no worse than the
    best of ``plans``."""
    import highspy

    master = Master(instance, None, None, 0.0, RECOMBINATION_OPTIONS)
    # Each plan as given and in canonical form: the canonical form takes the goods a plan
    # over-delivers off some of its routes, which may be the very routes that a better
    # plan needs whole.
    by_cost = sorted(((tuple(p), canonical_routes(instance, p)) for p in plans),
                     key=lambda pair: master.evaluator.cost(pair[1]))
    for given, canonical in by_cost:
        for plan in (canonical, given):
            for n, route in enumerate(plan):
                tail = schedule_tail(instance, route)
                if tail:
                    for k in master.identical.get(n, (n,)):
                        master.add_column(k, tail, frozenset())
    # The best plan's columns start the MIP, so that it ends no worse.
    start = [master.by_key[n, schedule_tail(instance, route), frozenset()].index
             for n, route in enumerate(by_cost[0][1])]
    mip = highspy.Highs()
    mip.setOptionValue("output_flag", False)
    mip.setOptionValue("threads", master.options.threads)
    mip.setOptionValue("time_limit", max(time_limit, 0.01))
    mip.setOptionValue("mip_rel_gap", 0.0)
    mip.passModel(master.h.getLp())
    lambdas = np.array([c.index for c in master.columns], np.int32)
    mip.changeColsIntegrality(len(lambdas), lambdas,
                              np.full(len(lambdas), highspy.HighsVarType.kInteger))
    n_cols = master.n_cols
    for col in master.columns:
        for m, theta in col.theta.items():
            mip.addCol(0.0, 0.0, 1.0, 2, np.array([master.closer[m], master.closer_time[m]],
                                                   np.int32), np.array([1.0, -theta]))
            mip.addRow(-master.inf, 0.0, 2, np.array([n_cols, col.index], np.int32),
                       np.array([1.0, -1.0]))
            n_cols += 1
    mip.setSolution(len(lambdas), lambdas, np.isin(lambdas, start).astype(float))
    mip.run()
    if not mip.getInfo().primal_solution_status:
        return None
    return canonical_routes(instance, master.rounded_plan(np.asarray(mip.getSolution().col_value)))
