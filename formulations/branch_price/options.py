"""Every setting of ``exact-bp``: its default, what it admits and why it is there
(docs/formulations.md, "Branch-and-price", has the measurements behind each default).
``solvers/exact.py`` offers each field as a setting of the method under the same name."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar

from tsac_bench.planning.settings import Boolean, Constraint, Interval, NoneOr, declare

#: The size rules of the settings whose default is None (by planning state): each measure
#: pays only from this many tasks up (docs/formulations.md, "Master" and "Pricing").
NG_FROM_TASKS = 20  # below it a relaxed call costs what an exact one does
NG_SIZE = 8  # tasks each ng neighbourhood remembers
PRIMAL_FROM_TASKS = 30  # below it the primal simplex's other duals changed the tree
SMOOTHING_FROM_TASKS = 30  # where the degenerate master's duals jump between extremes
SMOOTHING = 0.7  # weight of the last smoothed point (Wentges)
NEIGHBOURHOOD_ORDERS = ("shuffled", "excess")  # NeighbourhoodSettings.order


def _knob(default: Any, allowed: Constraint) -> Any:
    """A field with its default and the setting's constraint (``setting_constraints``)."""
    return field(default=default, metadata={"allowed": allowed})


@dataclass(frozen=True)
class BranchPriceOptions:
    """The search's knobs; None on ``ng_size``, ``primal_resolves`` and ``dual_smoothing``
    lets the size of the planning state decide (``for_tasks``)."""

    # Pricing: cheap and partial before exact (docs/formulations.md, "Pricing").
    #: Labels kept per task and path length in the heuristic rounds (0: exact pricing only).
    heuristic_cap: int = _knob(3, Interval(int, 0, None))
    #: Columns one pricing call adds per AAV: a few good ones, then fresh duals.
    columns_per_aav: int = _knob(30, Interval(int, 1, None))
    #: A heuristic round ends after this many columns: with many AAVs fresh duals pay
    #: more than one LP per round (0: every AAV each round).
    heuristic_round_columns: int = _knob(120, Interval(int, 0, None))
    #: ng neighbourhood size: a cheaper relaxed labelling and bound first (0: exact only).
    ng_size: int | None = _knob(None, NoneOr(Interval(int, 0, None)))
    #: Time steps of the completion bounds that drop labels which cannot price out (0: off).
    completion_steps: int = _knob(512, Interval(int, 0, None))
    #: Times a call grows the neighbourhoods by its cycles before asking the exact labelling.
    ng_growth_rounds: int = _knob(5, Interval(int, 0, None))
    #: Weight of the last smoothed duals in the heuristic rounds: a degenerate master's
    #: duals jump between extreme points.
    dual_smoothing: float | None = _knob(None, NoneOr(Interval(float, 0, 1, closed="left")))
    # The master: each family lifts the root bound ("Master", "Root bounds").
    #: Closer rows: a unit of the earliest arrivals on offer is charged, whatever the split.
    closer_rows: bool = _knob(True, Boolean())
    #: Coalition cover cuts (as the MILP's): a large task needs particular AAVs in full.
    cover_cuts: bool = _knob(True, Boolean())
    #: Identical AAVs ordered by their smallest task: no permuted copies of one plan.
    symmetry: bool = _knob(True, Boolean())
    #: Arrivals weighed by the goods they bring: the time term, nearly all of J, leaks less.
    goods_time_rows: bool = _knob(True, Boolean())
    #: Rounds of arrival-cut separation per node, each followed by pricing (0: none).
    arrival_cut_rounds: int = _knob(2, Interval(int, 0, None))
    #: Columns per row of the master as built before the pool sheds (0: keep every
    #: column): every LP pays for every column.
    columns_per_row: float = _knob(16.0, Interval(float, 0, None))
    #: Re-solve by the primal simplex after columns are added: faster on large LPs.
    primal_resolves: bool | None = _knob(None, NoneOr(Boolean()))
    #: HiGHS threads of the master LPs.
    threads: int = _knob(1, Interval(int, 1, None))
    # Branching and plans ("Branching and search").
    #: Most fractional visits scored by their children's LPs (1: the most fractional one).
    strong_candidates: int = _knob(8, Interval(int, 1, None))
    #: Measured rises per side after which pseudo-costs score a candidate instead of two
    #: LPs (0: strong branching always).
    strong_reliability: int = _knob(1, Interval(int, 0, None))
    #: Branch on arrival windows: the time rows see an average of an AAV's arrivals.
    time_branching: bool = _knob(True, Boolean())
    #: Share of the master LPs the dives may solve, counted in LPs so that the search is
    #: the same on any machine (0: no dives).
    dive_share: float = _knob(0.1, Interval(float, 0, 1, closed="both"))
    #: Node cap of the integer master over the pool (0: off; in time it improved nothing).
    master_mip_nodes: int = _knob(0, Interval(int, 0, None))
    #: Columns of least reduced cost the integer master takes (0: the whole pool).
    master_mip_columns: int = _knob(1500, Interval(int, 0, None))

    #: What each field admits, as a method's ``setting_constraints``.
    setting_constraints: ClassVar[Any]

    def for_tasks(self, n_tasks: int) -> BranchPriceOptions:
        """These options with every None decided by a planning state of ``n_tasks`` tasks."""
        return dataclasses.replace(
            self,
            ng_size=(NG_SIZE if n_tasks >= NG_FROM_TASKS else 0) if self.ng_size is None
            else self.ng_size,
            primal_resolves=n_tasks >= PRIMAL_FROM_TASKS if self.primal_resolves is None
            else self.primal_resolves,
            dual_smoothing=(SMOOTHING if n_tasks >= SMOOTHING_FROM_TASKS else 0.0)
            if self.dual_smoothing is None else self.dual_smoothing)


BranchPriceOptions.setting_constraints = declare(
    **{f.name: f.metadata["allowed"] for f in dataclasses.fields(BranchPriceOptions)})


@dataclass(frozen=True)
class NeighbourhoodSettings:
    """The knobs of the neighbourhood search over a plan (``neighbourhoods.search``,
    ``tsac-bench bks lns``); the defaults were chosen on validation instances apart from
    paper-mc (reports/lns-settings.md)."""

    #: AAVs each repair frees at first (one more once every such neighbourhood is proved).
    aavs: int = 3
    #: Tasks beyond the freed AAVs' own, nearest to those, that a repair may give them.
    extra: int = 4
    #: Seconds of exact-bp per repair, doubled after a round of repairs in vain.
    repair_limit: float = 60.0
    #: The order of the AAVs the neighbourhoods are built around: "shuffled", or "excess"
    #: (by the most any task an AAV visits costs above its tasks-on-their-own bound, ties
    #: shuffled), which lowered the start less at 32/80 (reports/lns-order.md).
    order: str = "shuffled"

    def __post_init__(self) -> None:
        if self.order not in NEIGHBOURHOOD_ORDERS:
            raise ValueError(f"order: {self.order!r} is not one of "
                             f"{', '.join(NEIGHBOURHOOD_ORDERS)}")
