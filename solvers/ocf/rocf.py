"""``rocf``: the OCF game with random selection (paper Sec. III-A-1, the ROCF baseline [31]).

The deciding AAV picks one of its candidate tasks uniformly at random: every valid task it
could join and every task of its own free route it could leave, with equal probability.
Everything else is the shared engine of ``solvers/ocf/engine.py``.
"""

from __future__ import annotations

import numpy as np

from tsac_bench.planning import PlanningState
from tsac_bench.solvers.ocf.engine import DecisionView, OCFAllocator, SelectionRule


class UniformSelection:
    def select(self, view: DecisionView, rng: np.random.Generator) -> int:
        return view.candidates[int(rng.integers(len(view.candidates)))]


class ROCFAllocator(OCFAllocator):
    name = "rocf"

    def rule(self, state: PlanningState) -> SelectionRule:
        del state
        return UniformSelection()
