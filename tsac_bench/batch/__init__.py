"""Batch runs: instance sets and their manifests, jobs, workers and executors (local
processes or Dask), the SQLite results store, and `verify` of proven optima."""
