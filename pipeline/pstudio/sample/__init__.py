"""Panoptic Studio's embedded sample world: a dome of Gaussians with analytic motion (rigid,
deforming and passing bodies, a floor, planted floaters), written in Dynamic 3D Gaussians' layout.
Every Gaussian's position and every camera's view are known exactly at any time, so the tests
compare the pipeline's outputs with this truth, and ``python -m pipeline.run --source pstudio``
without ``--input`` runs on it.

- ``studio_world``: the world;
- ``dynamic3dgs_files``: writes it as a Dynamic 3D Gaussians sequence.
"""
