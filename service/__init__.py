"""The dcseg HTTP service: a thin FastAPI layer over the job store and the queue (no torch)."""
