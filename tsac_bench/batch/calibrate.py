"""The machine-speed reference: a fixed workload timed on the machine a run uses, so that
budgets from two machines can be read together (the 12th DIMACS Implementation Challenge
normalised its time limits by such a rating).

The workload is one HOCF plan call (one game, seed 0) on the generator's 32/80 instance of
seed 0, the shipped ``instances/paper-mc/32-80/gen-32-80-s0.json``, and the evaluator's
pricing of its plan: the two things every budgeted OCF plan call spends its time on. Its
median over ``REPEATS`` timings (after one untimed call that loads the code) is the machine's
*reference second*: a budget of B seconds is B / reference seconds *reference units*.
"""

from __future__ import annotations

import socket
import statistics
import time
from datetime import UTC, datetime
from typing import Any

#: The generator's scale and seed of the reference instance.
REFERENCE_SCALE, REFERENCE_SEED = "32/80", 0
REPEATS = 5
WORKLOAD = ("one hocf plan call (one game, seed 0) and the evaluator on the 32/80 instance "
            "of seed 0 (instances/paper-mc/32-80/gen-32-80-s0.json)")


def reference_workload() -> float:
    """Seconds the reference workload takes once."""
    from tsac_bench.model.evaluator import CostEvaluator
    from tsac_bench.model.generator import generate
    from tsac_bench.planning import PlanningState
    from tsac_bench.solvers.ocf.hocf import HOCFAllocator

    instance = generate(REFERENCE_SCALE, REFERENCE_SEED)
    began = time.perf_counter()
    result = HOCFAllocator().plan(PlanningState.static(instance), seed=0)
    CostEvaluator(instance).evaluate(result.routes)
    return time.perf_counter() - began


def calibrate(repeats: int = REPEATS) -> dict[str, Any]:
    """The machine's reference second: what ``tsac-bench calibrate`` prints and a budgeted
    run stores in its meta (``calibration``)."""
    reference_workload()  # imports and first-call costs are not the machine's speed
    timings = [reference_workload() for _ in range(repeats)]
    return {"host": socket.gethostname(), "seconds": statistics.median(timings),
            "repeats": timings, "workload": WORKLOAD,
            "measured_at": datetime.now(UTC).isoformat(timespec="seconds")}
