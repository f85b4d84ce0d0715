"""Running a campaign: configuration, planning, the lab's devices, the runner and the HDF5 run file."""
