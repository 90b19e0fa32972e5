"""Batch evaluation: many (dataset or rendered scenario, settings) jobs run in parallel, on local
worker processes or on a Dask cluster, collected into one table.

``jobs`` describes the work (pure records: what to run, with which parameters, how a grid of
settings expands, how progress reads); ``executors`` and ``runner`` are the adapter that runs it
(processes, the Dask client, the per-job result files that make a batch resumable)."""
