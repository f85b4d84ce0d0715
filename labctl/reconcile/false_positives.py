"""The false-positive rate reconcile's decisions are held to, and the number of null runs that makes it
attainable (docs/reconcile.md, Null calibration)."""

#: the false-positive rate each decision is held to (a conventional 5 %); with K null runs the smallest
#: attainable p-value is 1 / (K + 1), so K must be at least 19 for a decision to reach it
ALPHA = 0.05
#: the smallest K for which p <= ALPHA is attainable (1 / (K + 1) = 0.05)
DEFAULT_NULL_RUNS = 19
