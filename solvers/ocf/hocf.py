"""``hocf``: the heuristic OCF game of Li et al. [14] as the paper describes it (Sec. I and
III-A-2): task-validity matching, ineffective-resource exit and a tabu list.

* Task-validity matching: the AAV only considers tasks its resources match: the engine's
  validity mask (residual demand left for it, reachable before the deadline and within
  range) - and among those, the task with the highest priority score (below).
* Ineffective-resource exit: before anything else, the AAV leaves a coalition in which its
  resource does nothing: its visit is late, or the other members already cover the demand on
  time without it.
* Tabu list: the engine's (every structure passed through is tabu).

Priority of joining task m for AAV n (each term in [0, 1], weights are settings):
  w_urgency  * (1 - slack / T_hor)        slack = t_end - earliest arrival from n's anchor
+ w_distance * (1 - d / d_max)            d = distance from the nearest node of n's free
                                          route (or its anchor) to m; d_max = the instance's
                                          largest distance
+ w_residual * min(R^_m, B_n) / R_m       the share of m's demand n can still cover (Eq. 19)
The last term is the part of C_load (weight w1) that n alone could remove. Ties go to the
lower task index. When no join is left to try, the AAV tries to leave its own coalition
with the lowest priority first.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from tsac_bench.model import Instance
from tsac_bench.planning import Interval, PlanningState, declare
from tsac_bench.solvers.ocf.engine import (
    C_MAX,
    INIT,
    K_MAX,
    SAMPLES,
    DecisionView,
    OCFAllocator,
    SelectionRule,
)


class HeuristicSelection:
    def __init__(self, instance: Instance, w_urgency: float, w_distance: float,
                 w_residual: float) -> None:
        self.w_urgency, self.w_distance, self.w_residual = w_urgency, w_distance, w_residual
        self.d_max = float(instance.dist.max()) or 1.0

    def priorities(self, view: DecisionView, tasks: Sequence[int]) -> dict[int, float]:
        """The priority score of each of ``tasks`` (visible ones) for the deciding AAV (module
        docstring), all at once."""
        game, n = view.game, view.aav
        instance = game.instance
        if not tasks:
            return {}
        at = [game.visible_index[m] for m in tasks]
        arrival = view.earliest_arrivals(np.asarray(tasks, dtype=int))
        urgency = 1.0 - np.minimum(1.0, np.maximum(
            0.0, (game.visible_t_end[at] - arrival) / instance.horizon))
        nearest, _ = game.route_proximity()
        proximity = 1.0 - nearest[n, at] / self.d_max
        share = (np.minimum(view.residuals()[at], instance.aavs[n].capacity)
                 / game.visible_demand[at])
        scores = (self.w_urgency * urgency + self.w_distance * proximity
                  + self.w_residual * share)
        return dict(zip(tasks, scores.tolist(), strict=True))

    def ineffective(self, view: DecisionView, m: int) -> bool:
        game, n = view.game, view.aav
        own = game.plan.members[m][n]
        late = not game.instance.tasks[m].on_time(own.arrival)
        return late or view.residual(m) == 0

    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        del rng  # deterministic given the structure; the engine's permutation is random
        return self.choice(view, self.priorities(view, view.candidates).__getitem__)

    def choice(self, view: DecisionView, priority: Callable[[int], float]) -> int:
        """The rule given the priorities (``select``'s, or ones already computed, as the
        teacher columns of the learned policy's state do for every visible
        task, ``solvers/tsac/features.py``)."""
        own = [m for m in view.candidates if view.is_member(m)]
        for m in own:
            if self.ineffective(view, m):
                return m
        joins = [m for m in view.candidates if not view.is_member(m)]
        if joins:
            return max(joins, key=lambda m: (priority(m), -m))
        return min(own, key=lambda m: (priority(m), m))


class HOCFAllocator(OCFAllocator):
    name = "hocf"
    # A negative weight would turn a criterion of the priority into its opposite.
    setting_constraints = declare(**OCFAllocator.setting_constraints,
                                  **{w: Interval(float, 0, None)
                                     for w in ("w_urgency", "w_distance", "w_residual")})

    def __init__(self, w_urgency: float = 1.0, w_distance: float = 2.0,
                 w_residual: float = 1.0, k_max: int = K_MAX, c_max: int = C_MAX,
                 init: str = INIT, samples: int | None = SAMPLES,
                 decisions: int | None = None) -> None:
        super().__init__(k_max=k_max, c_max=c_max, init=init, samples=samples,
                         decisions=decisions)
        self.w_urgency = w_urgency
        self.w_distance = w_distance
        self.w_residual = w_residual

    def rule(self, state: PlanningState) -> SelectionRule:
        return HeuristicSelection(state.instance, self.w_urgency, self.w_distance,
                                  self.w_residual)
