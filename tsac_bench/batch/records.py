"""The records of a batch run: a job's spec (what a worker is sent, as JSON), its result
(what the worker answers) and its row in the results store (``store.COLUMNS``, one column
per key). The spec and the row both carry the job's identity, ``JobIdentity``: its keys
have this one owner."""

from __future__ import annotations

from typing import Any, NotRequired, Required, TypedDict


class JobIdentity(TypedDict, total=False):
    """What a job's spec and its row both say. The runner writes every key; a spec written by
    hand for ``python -m tsac_bench.batch.worker`` needs only ``mode`` and ``seed`` of them
    (the worker takes no time limit, budget or settings where they are absent)."""

    key: str  # store.job_key: instance|method label|mode|seed[|budget=...]
    mode: Required[str]
    seed: Required[int]
    instance_file: str
    settings: dict[str, Any]
    time_limit: float | None  # seconds per plan call
    budget: float | None  # seconds each plan call spends; None: the method's own stopping rule


class JobSpec(JobIdentity):
    """A job as a worker gets it; the instance travels inside, so that cluster workers need
    no shared file system."""

    instance: dict[str, Any]  # the instance file's content (model.io)
    method: str  # the method's name; the row's ``method`` is its spec label
    grace: NotRequired[float]  # seconds the process may overrun 1.5 x its time limit


class JobResult(TypedDict):
    """What a worker answers for one job: a scored solution, or a failure's status and
    message (``worker.failure``)."""

    status: str  # store.OK, or how the job failed: error, invalid, crash, timeout
    message: str
    detail: str
    solution: dict[str, Any] | None  # the solution file's content (model.io)
    J: float | None
    terms: dict[str, float] | None
    runtime: float | None
    over_budget: NotRequired[int | None]
    stats: dict[str, Any]  # planning.solve's stats, as JSON (worker.jsonable)
    versions: dict[str, str]
    host: str


class JobRow(JobIdentity, total=False):
    """A job's row in the results store; a job about to run has only what is known up front
    (its identity, the instance and the references). Rows of older stores hold NULL (None)
    in the columns added since."""

    instance: str  # the instance's name
    instance_set: str
    scale: str
    n_aavs: int
    n_tasks: int
    method: str  # the method spec's label (``hocf:init=incumbent``)
    J_star: float | None  # the manifest's references
    lower_bound: float | None
    best_J: float | None  # the lowest J of any plan known before the run
    reference: str | None  # where J_star and lower_bound came from
    status: str
    message: str
    detail: str | None
    J: float | None  # the evaluator's, of the stored solution
    J_load: float | None
    J_time: float | None
    J_op: float | None
    runtime: float | None
    over_budget: int | None  # plan calls that returned later than the budget allows
    stats: dict[str, Any]
    versions: dict[str, str]
    host: str
    solution_file: str | None  # relative to the run directory
    finished_at: str
