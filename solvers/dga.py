"""``dga``: a distributed genetic algorithm, the paper's evolutionary baseline [30].

Island model: ``islands`` sub-populations evolve independently; every ``migration_interval``
generations each island sends copies of its ``migrants`` best individuals to the next island
of a ring, where they replace the worst. Islands run one after another in this process, or in
``workers`` processes; both give the same result for the same seed.

Encoding. An individual is one gene string per AAV: the free part of its route, a sequence of
``(node, amount)`` genes where the node is a task (the amount is that AAV's share of the
task's demand, so a task split across a coalition is one gene in each member's string) or a
depot (a reload/unload stop). The committed prefix is fixed and not part of the genome.
Fitness is the evaluator's J of the decoded routes (lower is better).

Operators keep every individual feasible: genes move only through the insertion and removal
edits of ``tsac_bench.planning.insertion``, whose results the evaluator checks, and every child is
repaired by re-inserting whatever demand it leaves uncovered.
* Crossover (route exchange, after Ombuki et al.'s best-cost route crossover): the child is
  parent A with one AAV's gene string taken from parent B; visits elsewhere that the
  transplanted string makes redundant are dropped when that lowers J; then repair.
* Mutation (one, drawn uniformly): relocate (drop a task visit), reset (drop every visit to
  one task), amount (shrink one visit's share), swap (exchange two visits of a route),
  depot (drop a depot stop); each followed by repair.
* Repair: the visible tasks with uncovered demand, in random order, each go to the cheapest
  insertion among ``candidates`` AAVs drawn with weight 1 / (d + 1 km)^2 (d: the AAV's
  distance to the task), for as much as fits, while that lowers J.
The initial population is built by the same repair from the committed prefixes; on a dynamic
event half of it starts from the incumbent plan instead (its first individual unmutated).
Selection is a tournament of ``tournament`` individuals; the ``elite`` best survive.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from tsac_bench.model import Route, Visit
from tsac_bench.model.evaluator import PlanState
from tsac_bench.planning import (
    Interval,
    NoneOr,
    PlanningState,
    PlanResult,
    Settings,
    declare,
)
from tsac_bench.planning.budget import ANYTIME, IncumbentTrace, WorkStop, require_a_stop
from tsac_bench.planning.insertion import best_insertion, removal_route

#: A change must lower J by more than float noise to count as an improvement.
GAIN_TOLERANCE = 1e-9
#: An AAV is drawn to bid for a task with weight 1 / (d + PROXIMITY_SCALE)^2, d its distance (m)
#: to the task: near AAVs are likelier, and one already at the task does not take all the mass.
PROXIMITY_SCALE = 1000.0


@dataclass(frozen=True, slots=True)
class Individual:
    routes: tuple[Route, ...]
    J: float


class Problem:
    """One planning moment seen by the genetic operators."""

    def __init__(self, state: PlanningState, candidates: int, tournament: int, elite: int,
                 crossover_rate: float, mutation_rate: float) -> None:
        self.state = state
        self.instance = instance = state.instance
        self.evaluator = state.evaluator()
        self.first_free = tuple(state.first_free(n) for n in range(instance.n_aavs))
        self.visible = tuple(sorted(state.visible))
        self.candidates = candidates
        self.tournament = tournament
        self.elite = elite
        self.crossover_rate = crossover_rate
        self.mutation_rate = mutation_rate
        self.base = state.base_routes()
        self.warm = state.warm_routes() if state.incumbent is not None else None
        self.mutations: tuple[Callable[[PlanState, np.random.Generator], None], ...] = (
            self.relocate, self.reset, self.shrink, self.swap, self.drop_depot)

    # --- helpers ---------------------------------------------------------------------
    def individual(self, plan: PlanState) -> Individual:
        return Individual(plan.routes, plan.cost)

    def plan_of(self, routes: Sequence[Route]) -> PlanState:
        return self.evaluator.state(routes)

    def free_task_visits(self, plan: PlanState) -> list[tuple[int, int]]:
        """(AAV, task) of every task visit after the committed prefixes."""
        n_tasks = self.instance.n_tasks
        return [(n, v.node) for n, trace in enumerate(plan.traces)
                for v in trace.route[self.first_free[n]:] if v.node < n_tasks]

    def remove(self, plan: PlanState, n: int, task: int) -> None:
        plan.set_route(n, removal_route(self.instance, plan.traces[n].route, task,
                                        self.first_free[n]))

    def bidders(self, plan: PlanState, task: int, rng: np.random.Generator) -> np.ndarray:
        """``candidates`` AAVs for ``task``, drawn without replacement, nearer ones likelier
        (d: from the AAV's start or the nearest node of its route to the task)."""
        n_aavs = self.instance.n_aavs
        if self.candidates >= n_aavs:
            return np.arange(n_aavs)
        to_task = self.instance.dist_rows[task]
        near = np.array([min((to_task[self.instance.start_node(n)],
                              *(to_task[v.node] for v in trace.route)))
                         for n, trace in enumerate(plan.traces)])
        weights = 1.0 / (near + PROXIMITY_SCALE) ** 2
        return rng.choice(n_aavs, size=self.candidates, replace=False, p=weights / weights.sum())

    # --- repair ----------------------------------------------------------------------
    def repair(self, plan: PlanState, rng: np.random.Generator) -> None:
        """Insert the uncovered demand of every visible task, in random order, into the
        cheapest of a few AAVs' routes, while that lowers J."""
        tasks = self.instance.tasks
        for task in rng.permutation(self.visible):
            task = int(task)
            while plan.covered(task) < tasks[task].demand:
                best = None
                for n in self.bidders(plan, task, rng):
                    n = int(n)
                    proposal = best_insertion(plan, n, task, self.first_free[n])
                    if proposal is not None and (best is None or proposal.delta < best.delta):
                        best = proposal
                if best is None or best.delta >= -GAIN_TOLERANCE:
                    break
                plan.apply(best)

    def construct(self, start: Sequence[Route], rng: np.random.Generator) -> Individual:
        plan = self.plan_of(start)
        self.repair(plan, rng)
        return self.individual(plan)

    # --- crossover -------------------------------------------------------------------
    def crossover(self, a: Individual, b: Individual, rng: np.random.Generator) -> PlanState:
        plan = self.plan_of(a.routes)
        differing = [n for n in range(self.instance.n_aavs) if a.routes[n] != b.routes[n]]
        if not differing:
            return plan
        n = differing[int(rng.integers(len(differing)))]
        plan.set_route(n, b.routes[n])
        n_tasks = self.instance.n_tasks
        for task in {v.node for v in b.routes[n][self.first_free[n]:] if v.node < n_tasks}:
            for k in sorted(plan.members[task]):
                if k == n or not any(v.node == task for v in
                                     plan.traces[k].route[self.first_free[k]:]):
                    continue
                proposal = plan.propose(k, removal_route(self.instance, plan.traces[k].route,
                                                         task, self.first_free[k]))
                if proposal is not None and proposal.delta < -GAIN_TOLERANCE:
                    plan.apply(proposal)
        return plan

    # --- mutations (each may leave demand uncovered; repair follows) -----------------
    def relocate(self, plan: PlanState, rng: np.random.Generator) -> None:
        visits = self.free_task_visits(plan)
        if visits:
            n, task = visits[int(rng.integers(len(visits)))]
            self.remove(plan, n, task)

    def reset(self, plan: PlanState, rng: np.random.Generator) -> None:
        visits = self.free_task_visits(plan)
        if visits:
            _, task = visits[int(rng.integers(len(visits)))]
            for n, other in visits:
                if other == task:
                    self.remove(plan, n, task)

    def shrink(self, plan: PlanState, rng: np.random.Generator) -> None:
        """Give part of one visit's share back, so that repair may split it differently."""
        visits = [(n, i) for n, trace in enumerate(plan.traces)
                  for i in range(self.first_free[n], len(trace.route))
                  if trace.route[i].amount > 1]
        if visits:
            n, i = visits[int(rng.integers(len(visits)))]
            route = plan.traces[n].route
            shrunk = Visit(route[i].node, int(rng.integers(1, route[i].amount)))
            proposal = plan.propose(n, (*route[:i], shrunk, *route[i + 1:]))
            if proposal is not None:
                plan.apply(proposal)

    def swap(self, plan: PlanState, rng: np.random.Generator) -> None:
        n_tasks = self.instance.n_tasks
        routes = [(n, [i for i in range(self.first_free[n], len(t.route))
                       if t.route[i].node < n_tasks]) for n, t in enumerate(plan.traces)]
        routes = [(n, idx) for n, idx in routes if len(idx) >= 2]
        if routes:
            n, idx = routes[int(rng.integers(len(routes)))]
            i, j = sorted(int(k) for k in rng.choice(idx, size=2, replace=False))
            route = list(plan.traces[n].route)
            route[i], route[j] = route[j], route[i]
            proposal = plan.propose(n, route)
            if proposal is not None:
                plan.apply(proposal)

    def drop_depot(self, plan: PlanState, rng: np.random.Generator) -> None:
        stops = [(n, i) for n, trace in enumerate(plan.traces)
                 for i in range(self.first_free[n], len(trace.route) - 1)
                 if self.instance.is_depot(trace.route[i].node)]
        if stops:
            n, i = stops[int(rng.integers(len(stops)))]
            route = plan.traces[n].route
            proposal = plan.propose(n, (*route[:i], *route[i + 1:]))
            if proposal is not None:
                plan.apply(proposal)

    # --- one generation --------------------------------------------------------------
    def select(self, population: Sequence[Individual], rng: np.random.Generator) -> Individual:
        picks = rng.choice(len(population), size=min(self.tournament, len(population)),
                           replace=False)
        return min((population[int(i)] for i in picks), key=lambda ind: ind.J)

    def offspring(self, population: Sequence[Individual],
                  rng: np.random.Generator) -> Individual:
        a = self.select(population, rng)
        if rng.random() < self.crossover_rate:
            plan = self.crossover(a, self.select(population, rng), rng)
        else:
            plan = self.plan_of(a.routes)
        if rng.random() < self.mutation_rate:
            self.mutations[int(rng.integers(len(self.mutations)))](plan, rng)
        self.repair(plan, rng)
        return self.individual(plan)

    def initial_population(self, size: int, rng: np.random.Generator, stop: WorkStop,
                           trace: IncumbentTrace) -> list[Individual]:
        """Up to ``size`` individuals (fewer if ``stop`` is reached; the call's first
        individual is always built)."""
        population: list[Individual] = []
        while len(population) < size:
            if stop.work and stop.reached() is not None:
                break
            if self.warm is not None and len(population) < (size + 1) // 2:
                plan = self.plan_of(self.warm)
                if population:
                    self.mutations[int(rng.integers(len(self.mutations)))](plan, rng)
                self.repair(plan, rng)
                individual = self.individual(plan)
            else:
                individual = self.construct(self.base, rng)
            population.append(individual)
            stop.done()
            trace.offer(individual.J)
        return population

    def evolve(self, population: list[Individual] | None, size: int,
               rng: np.random.Generator, generations: int, stop: WorkStop,
               trace: IncumbentTrace) -> tuple[list[Individual], list[float]]:
        """Run ``generations`` generations (fewer if ``stop`` is reached, which is checked
        before each individual: one individual, one unit of work). Returns the new population
        and its best J before the first and after every generation begun."""
        if population is None:
            population = self.initial_population(size, rng, stop, trace)
        if not population:
            return population, []
        history = [min(ind.J for ind in population)]
        for _ in range(generations):
            if stop.reached() is not None:
                break
            ranked = sorted(population, key=lambda ind: ind.J)
            survivors = ranked[:self.elite]
            children: list[Individual] = []
            while len(survivors) + len(children) < size and stop.reached() is None:
                children.append(self.offspring(ranked, rng))
                stop.done()
                trace.offer(children[-1].J)
            complete = len(survivors) + len(children) == size
            # A generation cut short ends the call: only its best matters then.
            population = survivors + children if complete else ranked + children
            history.append(min(ind.J for ind in population))
        return population, history


# --- islands in worker processes ---------------------------------------------------------
_worker_problem: Problem | None = None


def _start_worker(state: PlanningState, settings: dict[str, Any]) -> None:
    global _worker_problem
    _worker_problem = Problem(state, **settings)


def _evolve_in_worker(population: list[Individual] | None, size: int,
                      rng: np.random.Generator, generations: int, stop: WorkStop,
                      ) -> tuple[list[Individual], list[float], np.random.Generator, int,
                                 list[list[float]]]:
    """``Problem.evolve`` in a worker: also returns the work it did and its trace (the
    caller's stop and trace stay in the caller's process)."""
    assert _worker_problem is not None
    before = stop.work
    trace = IncumbentTrace(stop.began)
    population, history = _worker_problem.evolve(population, size, rng, generations, stop,
                                                  trace)
    return population, history, rng, stop.work - before, trace.points


class DGAAllocator(Settings):
    """Settings as the module docstring says; ``generations`` (None: no cap) and
    ``evaluations`` (the most individuals built in a plan call, the initial ones included,
    over all islands; None: no cap) bound the work. An anytime method
    (``tsac_bench.planning.budget``): under a budget it evolves until the budget is spent,
    checked before each individual, and ``evaluations`` set to a budgeted call's work count
    gives the same plan without the budget (with ``workers=0``: islands that run side by
    side in worker processes do not split their work the same way twice)."""

    name = "dga"
    setting_constraints = declare(
        islands=Interval(int, 1, None),
        population=Interval(int, 1, None),
        generations=NoneOr(Interval(int, 0, None)),
        evaluations=NoneOr(Interval(int, 1, None)),
        migration_interval=Interval(int, 1, None),
        # Elites and migrants are drawn from one island's population, never all of it.
        migrants=Interval(int, 0, "population", closed="left"),
        crossover_rate=Interval(float, 0, 1),
        mutation_rate=Interval(float, 0, 1),
        tournament=Interval(int, 1, None),
        elite=Interval(int, 0, "population", closed="left"),
        candidates=Interval(int, 1, None),
        workers=Interval(int, 0, None),
    )
    budget_use: ClassVar[str] = ANYTIME
    unbounded_settings: ClassVar[Mapping[str, Any]] = MappingProxyType({"generations": None})
    work_setting: ClassVar[str] = "evaluations"
    work_unit: ClassVar[str] = "individuals"

    def __init__(self, islands: int = 2, population: int = 8, generations: int | None = 25,
                 evaluations: int | None = None, migration_interval: int = 5,
                 migrants: int = 1, crossover_rate: float = 0.9, mutation_rate: float = 0.5,
                 tournament: int = 2, elite: int = 1, candidates: int = 6,
                 workers: int = 0) -> None:
        self.islands = islands
        self.population = population
        self.generations = generations
        self.evaluations = evaluations
        self.migration_interval = migration_interval
        self.migrants = migrants
        self.crossover_rate = crossover_rate
        self.mutation_rate = mutation_rate
        self.tournament = tournament
        self.elite = elite
        self.candidates = candidates
        self.workers = workers

    def _problem_settings(self) -> dict[str, Any]:
        return {"candidates": self.candidates, "tournament": self.tournament,
                "elite": self.elite, "crossover_rate": self.crossover_rate,
                "mutation_rate": self.mutation_rate}

    def plan(self, state: PlanningState, *, seed: int = 0,
             time_limit: float | None = None) -> PlanResult:
        require_a_stop(self.name, "generations", time_limit, self.generations,
                       self.evaluations)
        stop = WorkStop(time_limit, self.evaluations, look_ahead=True)
        trace = IncumbentTrace(stop.began)
        rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(self.islands)]
        populations: list[list[Individual] | None] = [None] * self.islands
        if self.workers:
            with ProcessPoolExecutor(min(self.workers, self.islands), initializer=_start_worker,
                                     initargs=(state, self._problem_settings())) as pool:

                def evolve_in_pool(jobs: list[tuple]) -> list[tuple]:
                    results = []
                    for population, history, rng, work, points in pool.map(
                            _evolve_in_worker, *zip(*jobs, strict=True)):
                        stop.done(work)
                        for seconds, cost in points:
                            trace.offer(cost, stop.began + seconds)
                        results.append((population, history, rng))
                    return results

                history, done, ended = self._run(populations, rngs, stop, evolve_in_pool)
        else:
            problem = Problem(state, **self._problem_settings())

            def evolve_here(population, size, rng, generations, stop):
                population, island_history = problem.evolve(population, size, rng,
                                                            generations, stop, trace)
                return population, island_history, rng

            history, done, ended = self._run(populations, rngs, stop,
                                             lambda jobs: [evolve_here(*job) for job in jobs])
        best = min((ind for population in populations if population for ind in population),
                   key=lambda ind: ind.J)
        return PlanResult(best.routes, {"stop": ended, "generations": done,
                                        "best_J_per_generation": history, "work": stop.work,
                                        "trace": trace.points, "seconds": stop.elapsed()})

    def _run(self, populations: list[list[Individual] | None],
             rngs: list[np.random.Generator], stop: WorkStop,
             evolve_islands: Callable[[list[tuple]], list[tuple]],
             ) -> tuple[list[float], int, str]:
        """Evolve all islands epoch by epoch (``migration_interval`` generations), migrating
        between epochs. Fills ``populations`` in place; returns the best J before the first
        and after every generation, the generations run and why it stopped."""
        history: list[float] = []
        done = 0
        while True:
            epoch = (self.migration_interval if self.generations is None
                     else min(self.migration_interval, self.generations - done))
            results = evolve_islands([(populations[i], self.population, rngs[i], epoch, stop)
                                      for i in range(self.islands)])
            histories = []
            for i, (population, island_history, rng) in enumerate(results):
                populations[i], rngs[i] = population, rng
                if island_history:
                    histories.append(island_history)
            ran = max(len(h) for h in histories) - 1
            # An island stopped early keeps its last best for later generations.
            start = 0 if not history else 1
            history += [min(h[min(g, len(h) - 1)] for h in histories)
                        for g in range(start, ran + 1)]
            done += ran
            reason = stop.reached()
            if reason is not None:
                return history, done, reason
            if self.generations is not None and done >= self.generations:
                return history, done, "generations"
            self._migrate(populations)

    def _migrate(self, populations: list[list[Individual] | None]) -> None:
        """Ring migration: copies of each island's best replace the next island's worst."""
        if self.islands < 2 or not self.migrants:
            return
        ranked = [sorted(p or [], key=lambda ind: ind.J) for p in populations]
        for i in range(self.islands):
            target = (i + 1) % self.islands
            incoming = ranked[i][:self.migrants]
            keep = ranked[target][:len(ranked[target]) - len(incoming)]
            populations[target] = keep + incoming
