"""The runtime: every thread, process, pool, queue and lock EVP runs; the core computes, this schedules."""
