"""``cnp``: the contract net protocol (Smith 1980), the paper's market-based baseline [9].

A manager holds the tasks and contracts them out; every AAV is a contractor that holds its own
route. The manager announces one task at a time, earliest deadline first. Every contractor
answers with at most one bid: the change in J (priced by the evaluator) of inserting the task
into its own route at its best position, for as much of the announced demand as it can carry
there. The manager awards the contract to the lowest bid; the winner inserts the visit and
from then on is bound by it. Whatever the award leaves uncovered is announced again, to the
same contractors, until the demand is covered or nobody bids; then the next task is announced.

What makes this CNP rather than the ``greedy`` insertion heuristic (which is what a sequential
auction without commitments amounts to):
* contracts bind: a bid states the arrival time the contractor will keep, and the award makes
  it a promise; a contractor never bids an insertion that would delay a visit it holds
  (setting ``commitment="arrival"``, the default) or, with ``commitment="deadline"``, that
  would make an on-time visit late. Greedy reorders routes freely whenever J drops;
* contracts persist: on a dynamic event the contracts in force (the incumbent plan after the
  committed prefix) are kept, and only new and uncovered tasks are announced; greedy re-plans
  every visible task from the committed prefixes;
* no bid without gain: a contractor whose best insertion does not lower J stays silent.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

from tsac_bench.model import Route
from tsac_bench.model.evaluator import (
    TIME_TOLERANCE,
    Contribution,
    PlanState,
    Proposal,
    RouteTrace,
)
from tsac_bench.planning import Options, PlanningState, PlanResult, Settings, declare
from tsac_bench.planning.budget import ONE_PASS
from tsac_bench.planning.insertion import best_insertion

#: A bid must lower J by more than float noise to count.
PRICE_TOLERANCE = 1e-9
#: What an award binds a contractor to (setting ``commitment``).
COMMITMENTS = ("arrival", "deadline")


@dataclass(frozen=True, slots=True)
class Bid:
    aav: int
    amount: int  # kg offered, at most the residual demand announced
    price: float  # change in J if awarded
    proposal: Proposal


@dataclass(frozen=True, slots=True)
class Award:
    task: int
    aav: int
    amount: int
    price: float
    route: Route  # the winner's route after the award


def _promised_arrival(task: int, held: Contribution) -> float:
    return held.arrival + TIME_TOLERANCE


class Contractor:
    """One AAV: bids on announced tasks against its own route and honours its contracts.

    ``commitment`` is what an award binds the contractor to: "arrival" (the arrival time its
    bid stated: no later bid may delay an awarded visit) or "deadline" (an awarded visit that
    is on time stays on time, a late one gets no later)."""

    def __init__(self, plan: PlanState, aav: int, first_free: int, commitment: str) -> None:
        self.plan = plan
        self.aav = aav
        self.first_free = first_free
        instance = plan.evaluator.instance
        if commitment == "arrival":
            self._promised = _promised_arrival
        else:
            deadline = tuple(t.latest_on_time for t in instance.tasks)
            self._promised = lambda m, c: max(c.arrival, deadline[m])

    def keeps_contracts(self, before: RouteTrace, proposal: Proposal) -> bool:
        """No visit held in ``before`` arrives later than promised after ``proposal``."""
        after = dict(proposal.trace.contributions)
        promised = self._promised
        return all(after[m].arrival <= promised(m, c) for m, c in before.contributions)

    def bid(self, task: int) -> Bid | None:
        """The contractor's answer to an announcement of ``task``; None is no bid."""
        before = self.plan.traces[self.aav]
        proposal = best_insertion(self.plan, self.aav, task, self.first_free,
                                  admissible=lambda p: self.keeps_contracts(before, p))
        if proposal is None or proposal.delta >= -PRICE_TOLERANCE:
            return None
        amount = next(c.amount for m, c in proposal.trace.contributions if m == task)
        return Bid(self.aav, amount, proposal.delta, proposal)


class ContractNetManager:
    """The manager: announces tasks earliest deadline first, collects one bid per contractor,
    awards the lowest and re-announces the residual demand."""

    def __init__(self, state: PlanningState, commitment: str = "arrival") -> None:
        self.state = state
        instance = state.instance
        self.plan = state.evaluator().state(state.warm_routes())
        self.contractors = [Contractor(self.plan, n, state.first_free(n), commitment)
                            for n in range(instance.n_aavs)]
        self.awards: list[Award] = []
        self.announcements = 0
        self.bids = 0
        self.unawarded: list[int] = []  # tasks left with residual demand: nobody bid

    def residual(self, task: int) -> int:
        return self.state.instance.tasks[task].demand - self.plan.covered(task)

    def agenda(self) -> list[int]:
        """What to announce: visible tasks that the contracts in force leave short, by
        deadline (ties: task index)."""
        tasks = self.state.instance.tasks
        return sorted((m for m in self.state.visible if self.residual(m) > 0),
                      key=lambda m: (tasks[m].t_end, m))

    def announce(self, task: int) -> Award | None:
        """One round of the protocol for ``task``: announce, collect bids, award."""
        self.announcements += 1
        bids = [bid for contractor in self.contractors if (bid := contractor.bid(task))]
        self.bids += len(bids)
        if not bids:
            return None
        best = min(bids, key=lambda b: (b.price, b.aav))
        self.plan.apply(best.proposal)
        award = Award(task, best.aav, best.amount, best.price, best.proposal.trace.route)
        self.awards.append(award)
        return award

    def run(self, deadline: float | None = None) -> str:
        """Contract out the agenda; returns why it stopped ("done" or "time-limit")."""
        for task in self.agenda():
            while self.residual(task) > 0:
                if deadline is not None and time.perf_counter() > deadline:
                    return "time-limit"
                if self.announce(task) is None:
                    self.unawarded.append(task)
                    break
        return "done"


class ContractNetAllocator(Settings):
    name = "cnp"
    budget_use: ClassVar[str] = ONE_PASS
    setting_constraints = declare(commitment=Options(*COMMITMENTS))

    def __init__(self, commitment: str = "arrival") -> None:
        self.commitment = commitment

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        del seed  # deterministic by construction
        deadline = None if time_limit is None else time.perf_counter() + time_limit
        manager = ContractNetManager(state, self.commitment)
        stop = manager.run(deadline)
        return PlanResult(manager.plan.routes, {
            "stop": stop,
            "announcements": manager.announcements,
            "bids": manager.bids,
            "awards": len(manager.awards),
            "unawarded": len(manager.unawarded),
        })
