"""Visualisation of clips (tracks on frames beside a 3D trajectory view, or a Rerun recording) and
of dataset statistics."""

from pipeline.viz.clip_figure import load_clip, write_clip_figure
from pipeline.viz.recording import write_recording
from pipeline.viz.stats_figure import dataset_stats, format_table, write_stats_figure

__all__ = [
    "dataset_stats",
    "format_table",
    "load_clip",
    "write_clip_figure",
    "write_recording",
    "write_stats_figure",
]
