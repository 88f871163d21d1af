"""The training data's dataset card, ``<out>/train/DATASET_CARD.json`` and its Markdown page
``DATASET_CARD.md``: one section per source, each written by that source's training run from its
records (``runner/training_output.py``); a run replaces its own source's section and keeps the
others'. The page is made from the JSON alone, so the two never disagree."""

from __future__ import annotations

import json
from collections.abc import Mapping

from pipeline.core.outcomes import FILTER_ORDER
from pipeline.export.layout import card_path
from pipeline.io.files import exists, read_bytes

CARD_VERSION = 1
MAX_CARD_BYTES = 16 << 20
TITLE = "Real-world 3D point tracks for training"
INTRODUCTION = """\
Clips of 3D point tracks made by the TAPVid-3D pipeline from real recordings, for training: every
unit of a scene the TAPVid-3D benchmark evaluates on (a Waymo segment, an ADT sequence, a Panoptic
Studio sequence one of its clips comes from) was left out before any work, and is listed with those
clips in `exclusions_<source>.jsonl`. `<source>/*.parquet` holds the clips, one row each (read with
`pipeline.clips.shards` or `datasets.load_dataset("parquet", ...)`); the clips are the `.npz` files
of `../<source>/`. Each source's data keeps its own licence, below.
"""


def earlier_sections(output: str) -> dict[str, dict]:
    """The sections the card in ``output`` holds, by source; none when there is no card or it is not
    one of ours (it is then written anew)."""
    path = card_path(output, "json")
    if not exists(path):
        return {}
    try:
        card = json.loads(read_bytes(path, MAX_CARD_BYTES))
    except (OSError, ValueError):
        return {}
    sections = card.get("sources") if isinstance(card, dict) else None
    if not isinstance(sections, dict):
        return {}
    return {name: section for name, section in sections.items() if isinstance(section, dict)}


def card_files(output: str, source: str, section: Mapping | None) -> dict[str, bytes]:
    """The card's two files (path -> bytes) with ``source``'s section replaced by ``section`` (None:
    removed), the other sources' kept."""
    sections = {name: held for name, held in earlier_sections(output).items() if name != source}
    if section is not None:
        sections[source] = dict(section)
    card = {"card_version": CARD_VERSION, "title": TITLE, "sources": dict(sorted(sections.items()))}
    return {
        card_path(output, "json"): (json.dumps(card, indent=2, sort_keys=True) + "\n").encode(),
        card_path(output, "md"): card_markdown(card).encode(),
    }


def card_markdown(card: Mapping) -> str:
    """The card's page: the introduction, a table of the sources' counts, then each source's section."""
    sections = card["sources"]
    lines = [
        f"# {card['title']}",
        "",
        INTRODUCTION,
        "| source | units | clips | tracks | frames | units left out |",
    ]
    lines.append("|---|---|---|---|---|---|")
    for name, section in sections.items():
        counts = section.get("counts", {})
        left_out = section.get("exclusions", {}).get("units", 0)
        row = [counts.get(key, 0) for key in ("units", "clips", "tracks", "frames")]
        lines.append(f"| {name} | " + " | ".join(f"{value:,}" for value in [*row, left_out]) + " |")
    for name, section in sections.items():
        lines += ["", f"## {name}", "", *section_lines(section)]
    return "\n".join(lines) + "\n"


def section_lines(section: Mapping) -> list[str]:
    """One source's section of the page, a bullet each: licence, counts, filters, exclusions,
    shards, how it was made."""
    counts, filters = section.get("counts", {}), section.get("filters", {})
    left_out, shards = section.get("exclusions", {}), section.get("shards", {})
    licence = section.get("licence") or {"terms": "not stated by the source", "links": []}
    links = ", ".join(f"<{link}>" for link in licence.get("links", []))
    dropped = ", ".join(f"{name} {filters.get('dropped', {}).get(name, 0):,}" for name in FILTER_ORDER)
    changed = ", ".join(f"`{key}={value}`" for key, value in section.get("settings_changed", {}).items())
    return [
        f"- **Licence**: {licence['terms']}" + (f" ({links})" if links else ""),
        f"- **Counts**: {counts.get('units', 0):,} unit(s) ({counts.get('units_failed', 0):,} failed), "
        f"{counts.get('clips', 0):,} clip(s), {counts.get('tracks', 0):,} tracks, "
        f"{counts.get('frames', 0):,} frames",
        f"- **Filters**: {filters.get('candidate_tracks', 0):,} candidate tracks; dropped: {dropped}; "
        f"{filters.get('passed', 0):,} passed every filter; "
        f"{filters.get('clips_below_target', 0):,} clip(s) below their target track count",
        f"- **Left out**: {left_out.get('units', 0):,} unit(s) of {left_out.get('scenes', 0):,} benchmark "
        f"scene(s) (`{left_out.get('file', '')}`), from `{left_out.get('splits_file', '')}`",
        f"- **Shards**: {shards.get('files', 0):,} file(s) in `{shards.get('folder', '')}`, "
        f"about {shards.get('shard_mb', 0):,} MiB each",
        f"- **Made by**: `{section.get('command', '')}` (rules={section.get('rules', '')}), "
        f"finished {section.get('finished', '')}; every setting in `{section.get('provenance', '')}` "
        "and this card's JSON",
        f"- **Settings not at their defaults**: {changed or 'none'}",
    ]
