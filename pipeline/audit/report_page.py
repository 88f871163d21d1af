"""``python -m pipeline.audit report OUT --out report.html``: one self-contained HTML page (no server,
no network: data, script and thumbnails inlined) to audit a run's filter thresholds.

Per source with audit tables in OUT (``OUT/audit/<source>/*.parquet``): the filter funnel, a
histogram of each filter's statistic with its threshold, a slider per threshold
(``flicker.max_fraction``, ``<source>.mask_min_agreement``, ``min_tracks``) that recounts kept
tracks, clips written, clips below target and, on a ``--release`` run, the release clips surviving
per split; and a table of the clips, with thumbnails of a few written ones. At every slider value
the counts are exactly those of ``python -m pipeline.audit sweep --grid KEY=VALUE`` (the sweep, like
the page, counts only the release's clips on a release run). Reads OUT only; writes ``--out`` only.
"""

from __future__ import annotations

import base64
import html
import json
import os
import sys

import numpy as np
import pyarrow as pa

from pipeline import sources
from pipeline.audit.report_data import FoldedClip, SourceData, counts_at, page_data
from pipeline.audit.report_script import SCRIPT, STYLE
from pipeline.audit.report_thumbs import MAX_TRACKS, thumbnails
from pipeline.audit.sweep import matches_run
from pipeline.audit.verdict_rows import agreement_summary
from pipeline.commandline import StrictParser
from pipeline.core.errors import InputError
from pipeline.io.files import write_atomic
from pipeline.io.storage import StorageError, check_scheme

THUMBNAILS = 12  # per source, by default
SUMMARY_KEYS = ("candidate_tracks", "dropped_by_filter", "tracks_passing_filters", "clips_below_target")


def packed(values, dtype) -> str:
    """Base64 of ``values`` as a little-endian array of ``dtype`` (read by the page as a typed array)."""
    return base64.b64encode(np.asarray(values, dtype=np.dtype(dtype).newbyteorder("<")).tobytes()).decode()


def pairs_json(clips: list[FoldedClip]) -> dict:
    """Every clip's (flicker bucket, mask bucket, count) pairs, concatenated, with offsets [C + 1]."""
    offsets = np.cumsum([0] + [len(clip.count) for clip in clips])
    count = np.concatenate([clip.count for clip in clips] + [np.zeros(0, np.int64)])
    wide = len(count) and count.max() > 0xFFFF
    return {
        "offsets": packed(offsets, np.uint32),
        "flicker": packed(np.concatenate([clip.flicker for clip in clips] + [np.zeros(0)]), np.uint8),
        "mask": packed(np.concatenate([clip.mask for clip in clips] + [np.zeros(0)]), np.uint8),
        "count": packed(count, np.uint32 if wide else np.uint16),
        "count_bytes": 4 if wide else 2,
    }


def slider_json(data: SourceData) -> list[dict]:
    """The three sliders: config key, grid of values, the run's value, a line on what it does."""
    flicker, mask, min_tracks = data.grids
    grids, run = data.grids, data.thresholds
    steps = "0 to 1 in steps of 0.01 and the run's value"
    notes = {
        flicker: f"keep a track whose visibility flips <= this x T frames; "
        f"{len(grids[flicker])} values ({steps})",
        mask: f"keep a track whose mask agreement >= this, or that has no mask evidence; "
        f"{len(grids[mask])} values ({steps})",
        min_tracks: f"write a clip when at least this many of its tracks pass; 1 to {grids[min_tracks][-1]}",
    }
    return [
        {"id": ident, "key": key, "values": grids[key], "run": run[key], "note": notes[key]}
        for ident, key in zip(("flicker", "mask", "min_tracks"), grids, strict=True)
    ]


def about(data: SourceData) -> str:
    """One paragraph on where the source's numbers come from."""
    run = ", ".join(f"{key}={value}" for key, value in data.thresholds.items())
    if data.summary is None:
        return f"No run's provenance (run_{data.name}.json): the sliders start at the defaults ({run})."
    text = f"The run's thresholds: {run}."
    if data.named is not None:
        named = ", ".join(f"{split} {count}" for split, count in data.named.items())
        splits = f" ({data.release_path})" if data.release_path else ""
        text += (
            f" Release run{splits}: only the release's clips count; release clips named: {named}. "
            "A release clip survives when it is written (a clip the run could not make never does)."
        )
    return text


def missing_json(data: SourceData) -> list[dict]:
    """The release verdicts of clips without an audit table (input absent, not made, failed)."""
    made = {clip.clip for clip in data.clips}
    verdicts = [row.verdict for row in data.verdicts or []]
    return [
        {"clip": row.clip, "split": row.split, "status": row.status, "reason": row.reason}
        for row in verdicts
        if row.clip not in made
    ]


def source_json(output: str, data: SourceData, count: int) -> tuple[dict, list[str]]:
    """The page's data of one source, and the lines on thumbnails that could not be drawn."""
    clips = data.clips
    if not clips:
        note = "A release run that annotated no clip of this source: its verdicts "
        note += f"(release_{data.name}.jsonl)."
        return {"name": data.name, "verdicts_only": True, "about": note, "missing": missing_json(data)}, []
    names = [clip.clip for clip in clips]
    images, problems = thumbnails(output, data.name, names, count)
    splits = None
    if data.verdicts is not None:
        split_of = {row.verdict.clip: row.verdict.split for row in data.verdicts}
        splits = [split_of.get(name) for name in names]
    missing = missing_json(data)
    summary = None if data.summary is None else {key: data.summary[key] for key in SUMMARY_KEYS}
    agreement = None if data.verdicts is None else agreement_summary(data.verdicts)
    return {
        "name": data.name,
        "about": about(data),
        "sliders": slider_json(data),
        "clips": {
            "clip": names,
            "frames": [clip.num_frames for clip in clips],
            "target": [clip.target_tracks for clip in clips],
            "candidates": [clip.candidates for clip in clips],
            "never_visible": [clip.never_visible for clip in clips],
            "split": splits,
        },
        "pairs": pairs_json(clips),
        "histograms": data.histograms,
        "summary": summary,
        "named": data.named,
        "missing": missing,
        "agreement": None if agreement is None else agreement.to_json(),
        "thumbnails": images,
        "thumbnail_note": f"Thumbnails: the middle frame of {len(images)} written clip(s), evenly spaced by "
        f"name, at most {MAX_TRACKS} tracks drawn (large filled = visible, small grey = occluded); "
        "click one to enlarge it.",
    }, problems


def to_json(value) -> str:
    """``value`` as compact JSON, NumPy arrays and integers as lists and ints."""

    def plain(item):
        if isinstance(item, np.ndarray):
            return item.tolist()
        if isinstance(item, np.integer):
            return int(item)
        raise TypeError(f"{type(item).__name__} is not JSON")

    return json.dumps(value, default=plain, separators=(",", ":"), allow_nan=False)


def page_html(output: str, sources_json: list[dict]) -> str:
    """The page: style, the data as JSON, the script."""
    data = to_json({"output": output, "sources": sources_json}).replace("</", "<\\/")
    links = " | ".join(f'<a href="#{s["name"]}">{s["name"]}</a>' for s in sources_json)
    title = f"Filter audit: {output}"
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{STYLE}</style></head><body>"
        f"<h1>{html.escape(title)}</h1><p>{links}</p>"
        '<p class="note">Move a slider: every count below is recomputed in this page, exactly as '
        "<code>python -m pipeline.audit sweep --grid KEY=VALUE</code> counts it at that value. A track is "
        "counted against the first filter that drops it (never_visible, flicker, mask).</p>"
        f'<main id="sources"></main><script type="application/json" id="audit-data">{data}</script>'
        f"<script>{SCRIPT}</script></body></html>\n"
    )


def run_check(data: SourceData) -> str:
    """Whether the folded counts at the run's thresholds reproduce its provenance file, in words."""
    if data.summary is None:
        return "no run's provenance"
    flicker_index, mask_index = (
        grid.index(data.thresholds[key]) for key, grid in list(data.grids.items())[:2]
    )
    result = counts_at(data, flicker_index, mask_index, int(data.thresholds["min_tracks"]))
    if matches_run(result, data.summary):
        return "reproduces the run's provenance"
    return "DOES NOT reproduce it"


def main(argv: list[str]) -> int:
    parser = StrictParser(prog="python -m pipeline.audit report", description=__doc__)
    parser.add_argument("output", help="the run's output folder (OUT)")
    parser.add_argument("--out", required=True, help="the HTML file to write")
    parser.add_argument(
        "--source",
        action="append",
        choices=sources.names(),
        help="a source to show (repeatable; default: every source with audit tables in OUT)",
    )
    parser.add_argument(
        "--thumbnails",
        type=int,
        default=THUMBNAILS,
        metavar="N",
        help="thumbnails per source, evenly spaced over its written clips (default %(default)s; 0: none)",
    )
    args = parser.parse_args(argv)
    if args.thumbnails < 0:
        parser.error(f"--thumbnails {args.thumbnails}: must be 0 or more")
    if os.path.isdir(args.out) or args.out.endswith("/"):
        parser.error(f"--out {args.out} is a folder: name the HTML file to write")
    try:
        check_scheme(args.out)
    except StorageError as error:
        parser.error(f"--out {args.out}: {error}")
    output = os.path.abspath(args.output) if "://" not in args.output else args.output
    try:
        found = page_data(output, args.source or list(sources.names()))
        absent = sorted(set(args.source or []) - {data.name for data in found})
        if absent:
            raise ValueError(f"--source {absent[0]}: no audit tables in {output}/audit/{absent[0]}/")
        if not found:
            raise ValueError(f"no audit tables nor release verdicts in {output}: run python -m pipeline.run")
        parts = [source_json(output, data, args.thumbnails) for data in found]
        page = page_html(output, [part for part, _ in parts]).encode()
    except (ValueError, KeyError, OSError, pa.ArrowException, InputError) as error:
        print(f"report: {error}", file=sys.stderr)
        return 2
    try:
        write_atomic(args.out, page)
    except (OSError, ValueError) as error:  # said of --out, never of the hidden temporary it goes through
        cause = getattr(error, "strerror", None) or type(error).__name__
        print(f"report: cannot write --out {args.out} ({cause})", file=sys.stderr)
        return 2
    for data, (part, problems) in zip(found, parts, strict=True):
        for line in problems:
            print(f"report: {data.name}: {line}", file=sys.stderr)
        if not data.clips:
            verdicts = len(data.verdicts or [])
            print(f"{data.name}: no audit tables; the page shows its {verdicts} release verdicts")
            continue
        print(
            f"{data.name}: {len(data.clips)} clips, {len(part['thumbnails'])} thumbnails; "
            f"at the run's thresholds the page {run_check(data)}"
        )
    print(f"report: {args.out} ({len(page) / 1e6:.2f} MB)")
    return 0
