"""Many runs at once on Dask (docs/scale.md): evaluate and reconcile run files, simulate campaign sweeps.

``inputs`` finds the run files, ``cluster`` opens the Dask client (a local
cluster sized to the machine, or a remote scheduler), ``tasks`` holds what a
worker does for one run (the same functions as ``labctl evaluate`` and
``labctl reconcile``), ``sweep`` expands a sweep file into simulated runs,
``execute`` submits the tasks and follows them, ``orchestrate`` ties a whole
batch together, ``index``, ``report`` and ``calibration`` write what was found
across all runs.
"""
