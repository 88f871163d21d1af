"""DriveTrack's embedded sample world: a small synthetic driving world with analytic motion, written
as a Waymo Open Dataset v2 segment (Parquet, the real schema). Every point's position and every
camera's view are known exactly at any time, so the tests compare the pipeline's outputs with this
truth, and ``python -m pipeline.run --source drivetrack`` without ``--input`` runs on it.

- ``driving_world``: an ego car on a curve among other cars, a pedestrian and a ground plane;
- ``waymo_world``: ray-casts it into the segment's component files.
"""
