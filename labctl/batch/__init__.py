"""Many runs at once on Dask: evaluate and reconcile run files, simulate campaign sweeps (docs/scale.md)."""
