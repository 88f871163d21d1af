"""Per-track filter statistics and verdicts as a Parquet table, one per clip."""

from __future__ import annotations

import io

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.filters.select import FilterOutcome


def outcome_table(outcome: FilterOutcome) -> pa.Table:
    """One row per candidate track: its statistics, each filter's verdict, and whether it was
    written (``output_index`` = its column in the clip, -1 if not)."""
    count = outcome.stats.count
    output_index = np.full(count, -1, dtype=np.int64)
    output_index[outcome.selected] = np.arange(len(outcome.selected))
    columns = {
        "source": pa.array([outcome.source] * count),
        "clip": pa.array([outcome.clip] * count),
        "num_frames": pa.array(np.full(count, outcome.num_frames, dtype=np.int64)),
        "target_tracks": pa.array(np.full(count, outcome.target_tracks, dtype=np.int64)),
        "candidate": pa.array(np.arange(count, dtype=np.int64)),
    }
    stats = outcome.stats.columns()
    for name in sorted(stats):
        columns[name] = pa.array(stats[name])
    for name in sorted(outcome.verdicts):
        columns[f"pass_{name}"] = pa.array(outcome.verdicts[name])
    columns["output_index"] = pa.array(output_index)
    return pa.table(columns)


def encode_parquet(table: pa.Table) -> bytes:
    buffer = io.BytesIO()
    pq.write_table(table, buffer, compression="zstd")
    return buffer.getvalue()
