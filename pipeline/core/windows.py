"""A clip cut into windows of a set number of frames (``<source>.clip_frames``, which a training run
sets), each a clip of its own: their frames and names."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Window:
    """The clip ``name`` of frames [start, stop) of a longer one (offsets into its frames)."""

    name: str
    start: int
    stop: int


def cut(name: str, frames: int, length: int, min_frames: int) -> list[Window]:
    """The windows of the clip ``name`` of ``frames`` frames: the whole clip, under its name, when
    ``length`` is 0 or at least ``frames``; else consecutive windows of ``length`` frames from its
    first, window k named ``<name>_w<k>``, and the shorter rest only with at least ``min_frames``."""
    if not length or frames <= length:
        return [Window(name, 0, frames)]
    starts = range(0, frames, length)
    windows = [Window(f"{name}_w{k}", start, min(start + length, frames)) for k, start in enumerate(starts)]
    return [w for w in windows if w.stop - w.start == length or w.stop - w.start >= min_frames]
