"""The results store of one run directory: ``results.sqlite`` plus solution JSON files.

Only the driver writes it, one transaction per finished job, so a run killed at any moment
(even ``kill -9``) leaves every finished job recorded and no half-recorded one: SQLite's
journal rolls back an interrupted transaction. The solution file of a job is written (by
write-then-rename) before its row is committed, so a row never points to a missing file.

One row per job; ``key`` (instance, method, mode, seed) identifies a job across restarts.
``method`` is the label of the job's method spec (``hocf`` or ``hocf:init=incumbent``,
``tsac_bench.planning.settings``), so the keys of stores written before specs existed (plain
names) are the keys of the same jobs now.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from tsac_bench.batch.records import JobRow
from tsac_bench.errors import InputError, TsacBenchError
from tsac_bench.planning.settings import file_label, format_value

DB_NAME = "results.sqlite"
#: The status of a job that produced a scored solution; anything else is a failure.
OK = "ok"
SOLUTIONS_DIR = "solutions"

#: Column name -> SQLite type: the keys of ``records.JobRow``. JSON columns hold text and
#: come back as Python objects.
COLUMNS: dict[str, str] = {
    "key": "TEXT PRIMARY KEY",
    "instance": "TEXT NOT NULL",
    "instance_set": "TEXT",
    "instance_file": "TEXT",
    "scale": "TEXT",
    "n_aavs": "INTEGER",
    "n_tasks": "INTEGER",
    "method": "TEXT NOT NULL",
    "mode": "TEXT NOT NULL",
    "seed": "INTEGER NOT NULL",
    "settings": "TEXT",  # JSON
    "time_limit": "REAL",
    "budget": "REAL",  # seconds per plan call; NULL: the method's own stopping rule
    "over_budget": "INTEGER",  # plan calls that returned later than the budget allows
    "status": "TEXT NOT NULL",
    "message": "TEXT",
    "detail": "TEXT",
    "J": "REAL",
    "J_load": "REAL",
    "J_time": "REAL",
    "J_op": "REAL",
    "J_star": "REAL",
    "lower_bound": "REAL",
    "best_J": "REAL",  # the manifest's best-known J (batch/best_known.py)
    "reference": "TEXT",  # where J_star / lower_bound came from
    "runtime": "REAL",  # seconds the method planned (solve's wall time)
    "stats": "TEXT",  # JSON
    "versions": "TEXT",  # JSON
    "host": "TEXT",
    "solution_file": "TEXT",  # relative to the run directory
    "finished_at": "TEXT",
}
JSON_COLUMNS = ("settings", "stats", "versions")


def job_key(instance: str, method: str, mode: str, seed: int,
            budget: float | None = None) -> str:
    """A job's key; a job without a budget has the key of stores written before budgets
    existed."""
    key = f"{instance}|{method}|{mode}|{seed}"
    return key if budget is None else f"{key}|budget={format_value(float(budget))}"


class ResultStore:
    """The SQLite database of one run directory."""

    def __init__(self, run_dir: str | Path, *, create: bool = True) -> None:
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / DB_NAME
        if not create and not self.path.exists():
            raise InputError(str(self.run_dir), None, f"no {DB_NAME}: not a tsac-bench run "
                             "directory (make one with `tsac-bench run ... --out DIR`)")
        self.run_dir.mkdir(parents=True, exist_ok=True)
        # isolation_level=None: transactions are opened explicitly, one per job.
        self._conn = sqlite3.connect(self.path, isolation_level=None)
        self._conn.execute("PRAGMA synchronous=FULL")
        columns = ", ".join(f'"{name}" {kind}' for name, kind in COLUMNS.items())
        self._conn.execute(f"CREATE TABLE IF NOT EXISTS jobs ({columns})")
        # A store written before a column existed gains it (NULL in its old rows).
        present = {row[1] for row in self._conn.execute("PRAGMA table_info(jobs)")}
        for name in COLUMNS.keys() - present:
            self._conn.execute(f'ALTER TABLE jobs ADD COLUMN "{name}" {COLUMNS[name]}')
        self._conn.execute("CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, value TEXT)")

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- writing ---------------------------------------------------------------------------
    def record(self, row: JobRow) -> None:
        """Insert or replace one job's row, in one transaction."""
        unknown = set(row) - set(COLUMNS)
        if unknown:
            raise TsacBenchError(f"unknown result columns: {sorted(unknown)}")
        names = list(row)
        values = [json.dumps(row[n], sort_keys=True) if n in JSON_COLUMNS else row[n]
                  for n in names]
        quoted = ", ".join(f'"{n}"' for n in names)
        marks = ", ".join("?" for _ in names)
        with self._transaction():
            self._conn.execute(f"INSERT OR REPLACE INTO jobs ({quoted}) VALUES ({marks})",
                               values)

    def set_meta(self, items: Mapping[str, Any]) -> None:
        with self._transaction():
            self._conn.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)",
                                   [(k, json.dumps(v)) for k, v in items.items()])

    @contextmanager
    def _transaction(self) -> Iterator[None]:
        self._conn.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            self._conn.execute("ROLLBACK")
            raise
        self._conn.execute("COMMIT")

    def solution_path(self, instance_set: str, instance: str, method: str, mode: str,
                      seed: int, budget: float | None = None) -> Path:
        """Where a job's solution file goes, relative to the run directory (``method``: the
        spec label)."""
        tail = "" if budget is None else "-b" + file_label(format_value(float(budget)))
        return Path(SOLUTIONS_DIR, instance_set, instance,
                    f"{file_label(method)}-{mode}-s{seed}{tail}.json")

    # --- reading ---------------------------------------------------------------------------
    def finished_keys(self, statuses: Iterable[str] | None = None) -> set[str]:
        query = "SELECT key FROM jobs"
        args: list[str] = []
        if statuses is not None:
            wanted = list(statuses)
            query += f" WHERE status IN ({', '.join('?' for _ in wanted)})"
            args = wanted
        return {key for (key,) in self._conn.execute(query, args)}

    def rows(self) -> list[JobRow]:
        """Every job's row, sorted by key, JSON columns decoded."""
        cursor = self._conn.execute("SELECT * FROM jobs ORDER BY key")
        names = [d[0] for d in cursor.description]
        rows = []
        for values in cursor:
            row = dict(zip(names, values, strict=True))
            for name in JSON_COLUMNS:
                row[name] = json.loads(row[name]) if row[name] is not None else None
            rows.append(row)
        return rows

    def meta(self) -> dict[str, Any]:
        return {k: json.loads(v) for k, v in self._conn.execute("SELECT name, value FROM meta")}

    def frame(self) -> Any:
        """The jobs as a pandas DataFrame (JSON columns decoded to Python objects)."""
        import pandas as pd

        frame = pd.DataFrame(self.rows(), columns=list(COLUMNS))
        # All-NULL columns (no J* anywhere) would come back as objects, not numbers.
        real = [name for name, kind in COLUMNS.items() if kind == "REAL"]
        frame[real] = frame[real].astype(float)
        return frame


def export(run_dir: str | Path, fmt: str, out: str | Path) -> int:
    """Write the run's jobs table as Parquet or CSV (JSON columns as JSON text); returns the
    number of rows."""
    with ResultStore(run_dir, create=False) as store:
        frame = store.frame()
    for name in JSON_COLUMNS:
        frame[name] = frame[name].map(lambda v: None if v is None else json.dumps(v,
                                                                                sort_keys=True))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "csv":
        frame.to_csv(out, index=False)
    elif fmt == "parquet":
        frame.to_parquet(out, index=False)
    else:
        raise TsacBenchError(f"--format: unknown format {fmt!r}; use parquet or csv")
    return len(frame)
