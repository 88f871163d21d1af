"""The run's settings: the run-wide fields, the run-wide sections (``FlickerConfig``, the flicker
filter's threshold; ``HttpConfig``, every HTTP transfer's policy; ``TrainingConfig``, what a training
run makes) and one section per source, named
after it, that each source declares (``Source.settings``: ``pipeline/<source>/settings.py``) and the
registry (``sections.py``) hands over: this module imports no room above ``settings/``.

A source's code reads its own section, ``config.section(AdtConfig)``, and hands its algorithm code
that section (or plain values), never the whole run's settings. Set from the command line with
``--set <source>.<field>=value``. A source registered at run time (a plug-in) brings its section
with it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, TypeVar

from pipeline.settings import sections as registry
from pipeline.settings.fields import (
    NOT_KNOWN,
    RULE_SETS,
    not_in_clips,
    one_of,
    path_setting,
    ranged,
    sections,
    settings_dict,
)

S = TypeVar("S")
# Units (a run) or files (``audit compare``) failing alike in a row that stop a command, by default.
MAX_FAILURES_IN_A_ROW = 20


@dataclasses.dataclass(frozen=True)
class FlickerConfig:
    """Drop a track whose visibility changes state more than ``max_fraction`` x T times.

    max_fraction: a track is dropped when its visibility flips (visible to occluded or back) more
      than this fraction of its T frames (the paper's 10%).
    """

    max_fraction: float = ranged(0.10, "[0, 1]")


@dataclasses.dataclass(frozen=True)
class HttpConfig:
    """How every HTTP transfer of a run behaves: the release's files, ADT's downloads.

    retries: a request that fails with 429, 500, 502, 503, 504, a lost connection or a read timeout
      is retried this many times, waiting backoff_s x 2^(n-1) s before the n-th retry but the first.
    backoff_s: the retries' base wait (seconds).
    deadline_s: a file not transferred within this many seconds, retries and waits included, fails.
    stall_s: a file that received fewer than stall_bytes_per_s x stall_s bytes in the last stall_s
      seconds, retries and waits included, fails: with the defaults, a file trickling from a
      stalled server fails within 2 minutes.
    stall_bytes_per_s: the stall rule's rate (bytes per second; 0: no stall rule).
    """

    retries: int = not_in_clips(5, "[0, 100]")
    backoff_s: float = not_in_clips(2.0, "[0, 600]")
    deadline_s: float = not_in_clips(7200.0, "(0, 604800]")
    stall_s: float = not_in_clips(120.0, "(0, 86400]")
    stall_bytes_per_s: int = not_in_clips(16384, "[0, 1073741824]")

    def wait_before(self, retry: int) -> float:
        """Seconds to wait before the ``retry``-th retry (1 for the first)."""
        return 0.0 if retry <= 1 else self.backoff_s * 2 ** (retry - 1)


@dataclasses.dataclass(frozen=True)
class TrainingConfig:
    """What a training run (``--training``) makes: clips of the scenes the benchmark does not
    evaluate on, written as Parquet shards (docs/training.md).

    splits_file: the benchmark's splits JSON whose scenes a training run leaves out (every unit of a
      scene one of its clips comes from is dropped before any work); empty: the official splits file
      beside the repository (``../shared/data/tapvid3d_official_splits.json``, or the file
      ``$TAPVID3D_OFFICIAL_SPLITS`` names).
    tracks_per_clip: tracks written per clip on a training run: each source's own
      ``<source>.tracks_per_clip`` takes this value there, unless a ``--set`` gives it.
    clip_frames: frames per clip on a training run: each source's clip-length settings
      (``<source>.clip_frames``; ADT's ``chunk_frames`` and ``min_frames``) take this value there,
      unless a ``--set`` gives one of them; 0: each source's own lengths. 64, the long end of the
      24-64-frame windows point trackers train on: a loader cuts any shorter window out of a clip,
      but cannot join two (docs/training.md).
    shard_mb: the bounded size of each Parquet shard of ``<out>/train/<source>/`` (MiB).
    """

    splits_file: str = path_setting("", clip_bytes=False)
    tracks_per_clip: int = not_in_clips(1024, "[1, 100000]")
    clip_frames: int = not_in_clips(64, "[0, 100000]")
    shard_mb: int = not_in_clips(256, "[1, 65536]")


def default_sections() -> dict[str, Any]:
    """Each registered source's section at its defaults, by source name."""
    return {name: kind() for name in registry.names() if (kind := registry.settings_of(name)) is not None}


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Everything that decides a run's output besides its input.

    rules: the rule set: ``release``, every choice as the original generators made it (where the
      release's value is not known, ours is kept); ``refined``, ours where we measured better.
      It sets a group of defaults (docs/release.md); a ``--set`` of one of them still wins. A
      ``--release`` run follows ``release`` unless this is set, any other run ``refined``.
    seed: every random choice is seeded from it and the clip's name.
    splits_file: the release's splits JSON: the manifests follow its membership where clip names
      match (``--release`` also restricts the run to its clips).
    queries_from: a folder of existing clips whose queries are re-annotated instead of sampling
      new ones; only clips found there are made. Set it with ``--queries-from DIR``.
    export_depth: also write the depth each visibility test read (``--export-depth``).
    resume_decode: a unit an earlier run finished is resumed when its clip files have the size and
      SHA-256 its checkpoint recorded (and their audit tables are there); with this on, each of its
      clips is also decoded and checked again, as ``pipeline.validate`` does (slower).
    minival_per_source: without a splits file, minival is a seeded draw of this many clips per
      source; full_test holds every other clip.
    min_tracks: a clip is written only when at least this many tracks pass the filters.
    max_failures_in_a_row: the run stops (exit status 4) once this many units in a row failed with
      the same cause (the error's last part, names and numbers aside), so that a dead server or a
      fault every unit meets is reported in minutes, not after hours of units failing alike; 0:
      never. Finished units are kept; a rerun resumes.
    flicker: the flicker filter's threshold.
    http: how every HTTP transfer behaves (the release's files, ADT's downloads).
    training: what a training run (``--training``) makes.
    source_sections: each source's section, by name (``section`` reads one by its class).
    """

    rules: str = one_of("refined", RULE_SETS, release="release")
    seed: int = ranged(0, "[0, 4294967295]", release=NOT_KNOWN)
    splits_file: str = path_setting("", "splits_file", clip_bytes=False)
    queries_from: str = path_setting("", "--queries-from")
    export_depth: bool = not_in_clips(False)
    resume_decode: bool = not_in_clips(False)
    minival_per_source: int = not_in_clips(50, "[0, 1000000]")
    min_tracks: int = ranged(1, "[1, 100000]", release=NOT_KNOWN)
    max_failures_in_a_row: int = not_in_clips(MAX_FAILURES_IN_A_ROW, "[0, 1000000]")
    flicker: FlickerConfig = dataclasses.field(default_factory=FlickerConfig)
    http: HttpConfig = dataclasses.field(default_factory=HttpConfig, metadata={"clip_bytes": False})
    training: TrainingConfig = dataclasses.field(
        default_factory=TrainingConfig, metadata={"clip_bytes": False}
    )
    source_sections: Mapping[str, Any] = sections(default_sections)

    def section(self, kind: type[S]) -> S:
        """The source section of class ``kind`` (``config.section(AdtConfig)``); LookupError when
        no registered source declares it."""
        for held in self.source_sections.values():
            if type(held) is kind:
                return held
        raise LookupError(f"the run's settings hold no {kind.__name__} section (is its source registered?)")

    def to_dict(self) -> dict:
        return settings_dict(self)
