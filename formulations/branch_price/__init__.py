"""Branch-and-price for Problem 1 (``exact-bp``): a route master solved by column generation
in HiGHS (highspy), exact labelling pricing (formulations/pricing.py), best-bound branching.
docs/formulations.md, "Branch-and-price", has the model, why each part is there and what it
measured. The parts, each of which reads only those before it:
- ``options``: every setting, its default and why (``BranchPriceOptions``);
- ``columns``: a column of the master, and the branching decisions that restrict columns;
- ``cuts``: the arrival cuts' coefficients, separation and prices;
- ``master``: the LP, its rows, the column pool and a node's decisions on it;
- ``duals``: the LP's duals as the labelling's prices, a column's reduced cost;
- ``column_generation``: one node's pricing rounds, bounds and cut rounds;
- ``branching``: the candidates, strong branching and pseudo-costs;
- ``search``: the node queue, dives, the integer master, bounds and the stop.

Master LP. A column c of AAV k is a whole schedule from k's anchor (its committed prefix,
then free visits, each trip from a depot, amounts fixed) with a set S_c of the tasks it
"closes", with op_c = w3 * sum of its q_k(m) (Eq. 9, range overrun included), a_cm its
on-time amount at task m and theta_cm = (t_cm - t_start(m)) / T_hor its arrival term.
Variables lambda_c >= 0, covered_m in [0, R_m], Ctime_m >= 0, nobody_m in [0, 1]:
  min  sum op_c lambda_c + sum_m w1 (1 - covered_m / R_m) + w2 Ctime_m
  s.t. sum_{c of k} lambda_c = 1                                 (convexity, per AAV)
       sum_c a_cm lambda_c - covered_m >= 0                      (coverage)
       sum_{c: m in S_c} lambda_c + nobody_m >= 1                (each task has a closer)
       Ctime_m - sum_{c: m in S_c} theta_cm lambda_c - nobody_m >= 0
       Ctime_m - sum_{c of k} theta_cm lambda_c - nobody_m >= 0  (every member's arrival)
       sum_{n in S} coef_n x_nm - covered_m >= -rest  (coalition cover cuts, as in the MILP:
                                                      x_nm = sum of n's columns visiting m)
       Ctime_m - nobody_m - sum_c coef_c lambda_c >= 0  (arrival cuts, separated).
At a point with one column per AAV this is J exactly when the closer of each task is its
latest member: covered = min(R, on-time goods); the per-AAV rows make Ctime at least the
latest arrival, the closer no more; nobody = 1 exactly when no column closes m, which costs
C_time = 1. Any other choice of closers only raises the objective, so the integer optimum is
J*. Tasks whose committed visit is late keep C_time = 1 as a constant. The variants of one
schedule with every subset S are the LP of "closer" variables z_cm in [0, lambda_c]; pricing
picks the best S of a new schedule, so its reduced cost is
op_c - dual(conv_k) + sum_m [-dual(cover_m) a_cm + dual(aav_km) theta_cm
                             + min(0, dual(closer_time_m) theta_cm - dual(closer_m))],
the labelling's objective. With a lower bound rc_k on every AAV's least reduced cost (the
exact labelling's, or the ng relaxation's), the Lagrangian bound LP + sum_k min(0, rc_k) is
valid at every iteration.

Branching (``branching``) fixes visits, arrival windows, arcs and amounts: the "0" and
"amount" sides are enforced in pricing (and on the existing columns), the "1" sides as rows
sum lambda >= 1 with an artificial column of prohibitive cost (the node is infeasible if it
stays positive). Plans come from the incumbent given, each node's LP (each AAV's column of
largest lambda) and dives from the root and some nodes.
"""

from __future__ import annotations

from typing import Any

from tsac_bench.formulations.branch_price.options import BranchPriceOptions

__all__ = ["BranchDecision", "BranchPrice", "BranchPriceOptions", "BranchPriceResult"]


def __getattr__(name: str) -> Any:
    """The search's classes on first use: they import highspy's and numba's users, which
    the settings of ``exact-bp`` (``BranchPriceOptions``) must not load."""
    if name in ("BranchPrice", "BranchPriceResult"):
        from tsac_bench.formulations.branch_price import search

        return getattr(search, name)
    if name == "BranchDecision":
        from tsac_bench.formulations.branch_price import columns

        return columns.BranchDecision
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
