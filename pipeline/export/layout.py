"""Where a run's files go, under one output folder shared by the three sources::

<out>/<source>/<clip>.npz             the clips (released schema)
<out>/audit/<source>/<clip>.parquet   every candidate track's filter statistics
<out>/depth/<source>/<clip>.npz       the depth the visibility test read (--export-depth)
<out>/units/<source>/<unit>.json      a finished unit's record, which lets a rerun skip it
<out>/manifests/{minival,full_test}.txt
<out>/run_<source>.json, <out>/failures_<source>.jsonl
<out>/release_<source>.jsonl          a release run's verdict on every release clip of the source
<out>/sweep_<source>/                 ``pipeline.audit sweep``'s report
<out>/sample_input/<source>/          the embedded sample world, when a run has no --input
<out>/train/<source>/*.parquet        a training run's clips as Parquet shards (--training)
<out>/train/exclusions_<source>.jsonl the units a training run dropped: their scene is the benchmark's
<out>/train/DATASET_CARD.{md,json}    the training data's card, one section per source
"""

from __future__ import annotations

import hashlib
import re

from pipeline.core.errors import InputError

# A clip name becomes a file name on every filesystem Beam writes to: letters, digits, '_', '-',
# '.', '+', not starting with '.' (no hidden files, no '..').
CLIP_NAME = re.compile(r"[A-Za-z0-9_+-][A-Za-z0-9_.+-]*")


MAX_CLIP_NAME = 160


def is_clip_name(name: str) -> bool:
    """Whether ``name`` can be a clip's file name (``check_clip_name`` would accept it)."""
    return isinstance(name, str) and bool(CLIP_NAME.fullmatch(name)) and len(name) <= MAX_CLIP_NAME


def check_clip_name(name: str) -> str:
    """``name`` when it is a plain file name, else an InputError naming the offending characters."""
    if len(name) > MAX_CLIP_NAME:
        raise InputError(f"clip name {name[:40]!r}... is {len(name)} characters, at most {MAX_CLIP_NAME}")
    if not CLIP_NAME.fullmatch(name):
        bad = sorted({c for c in name if not re.fullmatch(r"[A-Za-z0-9_.+-]", c)})
        cause = f"characters {bad}" if bad else "a leading '.'" if name else "an empty name"
        raise InputError(
            f"clip name {name!r} is not a plain file name ({cause}; path separators are refused): "
            "rename the input"
        )
    return name


def clip_path(output: str, source: str, clip: str) -> str:
    return f"{clip_folder(output, source)}/{clip}.npz"


def audit_path(output: str, source: str, clip: str) -> str:
    return f"{output}/audit/{source}/{clip}.parquet"


def depth_path(output: str, source: str, clip: str) -> str:
    return f"{output}/depth/{source}/{clip}.npz"


def checkpoint_path(output: str, source: str, unit: str) -> str:
    """A unit name may hold '/' (``segment/camera_1``): the file name is a readable slug of it plus a
    short hash of the whole name, so two units never share a record."""
    slug = re.sub(r"[^A-Za-z0-9_.+-]+", "_", unit).strip("._")[:80]
    digest = hashlib.sha256(unit.encode()).hexdigest()[:12]
    return f"{output}/units/{source}/{slug}-{digest}.json"


def clip_folder(output: str, source: str) -> str:
    return f"{output}/{source}"


def manifest_path(output: str, split: str) -> str:
    return f"{output}/manifests/{split}.txt"


def provenance_path(output: str, source: str) -> str:
    return f"{output}/run_{source}.json"


def failures_path(output: str, source: str) -> str:
    return f"{output}/failures_{source}.jsonl"


def release_verdicts_path(output: str, source: str) -> str:
    return f"{output}/release_{source}.jsonl"


def sweep_folder(output: str, source: str) -> str:
    return f"{output}/sweep_{source}"


def sample_folder(output: str, source: str) -> str:
    return f"{output}/sample_input/{source}"


def train_folder(output: str) -> str:
    return f"{output}/train"


def shard_folder(output: str, source: str) -> str:
    return f"{train_folder(output)}/{source}"


def exclusions_path(output: str, source: str) -> str:
    return f"{train_folder(output)}/exclusions_{source}.jsonl"


def card_path(output: str, suffix: str) -> str:
    """The dataset card's file: ``suffix`` ``md`` (to read) or ``json`` (its record)."""
    return f"{train_folder(output)}/DATASET_CARD.{suffix}"


def temporary_patterns(output: str, source: str, partial: str) -> list[str]:
    """Globs of the hidden temporaries (``.<name><partial>*``) a run of ``source`` may leave."""
    folders = [
        clip_folder(output, source),
        *(f"{output}/{kind}/{source}" for kind in ("audit", "depth", "units")),
    ]
    patterns = [
        f"{folder}/.*{partial}*" for folder in [*folders, f"{output}/manifests", train_folder(output)]
    ]
    for path in (
        provenance_path(output, source),
        failures_path(output, source),
        release_verdicts_path(output, source),
    ):
        folder, _, name = path.rpartition("/")
        patterns.append(f"{folder}/.{name}{partial}*")
    return patterns
