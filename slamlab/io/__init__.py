"""Small file helpers every layer may use (core: no slamlab imports but errors, frames,
geometry): atomic writes (`atomic`), TUM trajectories (`tum`), compressed text (`compressed`),
plain PNG images without matplotlib (`png`).

They live below datasets, slam and texture so that a dataset writer (the simulator, the THOR
writer) and the texture stage write files the same way the pipeline does without importing
the pipeline's run-directory code (`slamlab.artifacts`).
"""
