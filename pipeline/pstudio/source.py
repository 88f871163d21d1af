"""Panoptic Studio (Dynamic 3D Gaussians) as a Source: (sequence, camera) units, one clip each;
a sequence's cameras are annotated in groups of ``CAMERAS_PER_GROUP`` (one read of its Gaussians
and masks per group)."""

from __future__ import annotations

import operator

from pipeline.pstudio.annotate import annotate_group
from pipeline.pstudio.settings import PstudioConfig
from pipeline.pstudio.units import SequenceCamera, clip_scene, list_units, scene_of
from pipeline.sources import Licence, Source


def sample_input(folder: str) -> str:
    """Write (once) the embedded sample world in Dynamic 3D Gaussians' layout; returns its path."""
    from pipeline.pstudio.sample.dynamic3dgs_files import write_sample

    return write_sample(folder)


SOURCE: Source[SequenceCamera] = Source(
    name="pstudio",
    bench="pipeline.pstudio.bench",
    list_units=list_units,
    annotate_group=annotate_group,
    sample_input=sample_input,
    mask_min_agreement=lambda config: config.section(PstudioConfig).mask_min_agreement,
    sweepable=("pstudio.mask_min_agreement",),
    settings=PstudioConfig,
    group_of=operator.attrgetter("group"),
    scene_of=scene_of,
    clip_scene=clip_scene,
    licence=Licence(
        "CMU Panoptic Studio: non-commercial research use; the trained scenes also under Dynamic 3D "
        "Gaussians' own licence",
        ("http://domedb.perception.cs.cmu.edu/", "https://github.com/JonathonLuiten/Dynamic3DGaussians"),
    ),
)
