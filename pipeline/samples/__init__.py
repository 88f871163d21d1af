"""The embedded sample worlds: small synthetic worlds with analytic motion, written in each
source's real file format.

Every point's position and every camera's view are known exactly at any time, so the tests
compare the pipeline's outputs with this truth (not with the pipeline itself), and
``python -m pipeline.run`` without ``--input`` runs on them.

- ``driving_world``: an ego car on a curve among other cars, a pedestrian and a ground plane;
  ``waymo_world`` ray-casts it into a Waymo Open Dataset v2 segment (Parquet, real schema).
- ``studio_world``: a dome of Gaussians (rigid, deforming and passing bodies, a floor, planted
  floaters); ``dynamic3dgs_files`` writes it in Dynamic 3D Gaussians' layout.
- ``adt_excerpt``: no synthetic ADT world; where the real ADT excerpt lies and how to get ADT.
- ``write_once``: writes a sample into a folder atomically, once, and reuses it after.
"""
