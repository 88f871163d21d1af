"""Aria Digital Twin as a Source: (sequence, 300-frame chunk) units, one clip each, from local
sequence folders or fetched from the download-URLs JSON; a sequence's chunks are annotated in
groups (one opening, or one download, of the sequence per group)."""

from __future__ import annotations

import operator

from pipeline.adt.annotate import annotate_group
from pipeline.adt.download import reclaim_scratch
from pipeline.adt.sample.excerpt import demo_args, no_sample_message
from pipeline.adt.settings import AdtConfig
from pipeline.adt.units import SequenceChunk, clip_scene, list_units, scene_of, scratch_folder
from pipeline.sources import Licence, NoSample, Source


def sample_input(folder: str) -> str:
    """There is no embedded ADT sample: NoSample says how to get ADT and run the shared excerpt."""
    raise NoSample(no_sample_message())


SOURCE: Source[SequenceChunk] = Source(
    name="adt",
    bench="pipeline.adt.bench",
    list_units=list_units,
    annotate_group=annotate_group,
    sample_input=sample_input,
    mask_min_agreement=lambda config: config.section(AdtConfig).mask_min_agreement,
    sweepable=("adt.mask_min_agreement",),
    has_sample=False,
    demo_args=demo_args,
    reclaim_scratch=lambda config: reclaim_scratch(scratch_folder(config.section(AdtConfig))),
    settings=AdtConfig,
    group_of=operator.attrgetter("group"),
    scene_of=scene_of,
    clip_scene=clip_scene,
    licence=Licence(
        "Aria Digital Twin dataset licence (Project Aria's terms, accepted when downloading)",
        ("https://www.projectaria.com/datasets/adt/license/",),
    ),
)
