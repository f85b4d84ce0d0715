"""Performance benchmarks (``python -m bench`` or ``make bench``); see docs/benchmarks.md."""

import os

# the benchmarks time what they simulate: no null replicas from labctl's cache (labctl/reconcile/replica_cache.py)
os.environ["LABCTL_CACHE_DIR"] = ""
