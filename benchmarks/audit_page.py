"""``python -m benchmarks.audit_page RUN... [--release SPLITS_JSON]``: the audit page's size and speed.

For each RUN (a run's output folder), and with ``--release`` for a synthetic output folder of the
release's size, it writes ``python -m pipeline.audit report``'s page (timed as a command) and opens it
in headless Chromium: the time from navigation to the page's ready marker (median of 3 loads), the
time of one recount (a slider move, median of 9) and the script's heap.

The synthetic folder (``<workdir>/release_size``, made once) is a --release run of every clip
SPLITS_JSON names (the official file: ADT 1,956, DriveTrack 2,457, Panoptic Studio 156 clips). Each
audit table is drawn from the RUNs' tables of its source (ADT, without one, from DriveTrack's, whose
flips spread widest): rows with replacement up to the source's candidates per clip (ADT 4,096,
DriveTrack 1,024, Panoptic Studio 400: about 10.6 million tracks in all), the release's frames per
clip (300, 24 to 199, 150), flips and visible frames scaled to them, flips jittered x0.5 to x1.5 and
mask agreement by N(0, 0.03), which spreads the tracks over more slider buckets than the samples do.
Each clip file is a hard link to a real clip of its source (or the template's), for the thumbnails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from glob import glob
from statistics import median

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from benchmarks.entry import entry
from pipeline import sources
from pipeline.audit.sweep import evaluate, load_statistics
from pipeline.commandline import StrictParser
from pipeline.export.layout import audit_path, clip_path, provenance_path, release_verdicts_path
from pipeline.runner.splits import read_release
from pipeline.settings.run_config import RunConfig

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
FLAGS = (
    "--headless=new --no-sandbox --disable-gpu --disable-dev-shm-usage --disable-background-networking "
    "--disable-component-update --no-first-run --disable-sync"
).split()
MOVE_SCRIPT = """
const input = document.querySelector("input[type=range]"), times = [];
for (let i = 0; i < 9; i++) {
  const start = performance.now();
  input.value = (i * 7) % Number(input.max);
  input.dispatchEvent(new Event("input"));
  times.push(performance.now() - start);
}
times.sort((a, b) => a - b);
return [times[4], performance.memory.usedJSHeapSize];
"""


def templates(runs: list[str]) -> dict[str, tuple[list[pa.Table], str]]:
    """source -> (the RUNs' audit tables of it, one of its clip files), for each source they hold."""
    found = {}
    for source in sources.names():
        tables = [pq.read_table(path) for run in runs for path in sorted(glob(audit_path(run, source, "*")))]
        clips = [path for run in runs for path in sorted(glob(clip_path(run, source, "*")))]
        if tables and clips:
            found[source] = (tables, clips[0])
    return found


def synthetic_table(template: pa.Table, source: str, clip: str, rng: np.random.Generator) -> pa.Table:
    """One clip's audit table drawn from ``template``'s rows at the source's release shape."""
    count, (fewest, most) = entry(source).RELEASE_SHAPE
    frames = int(rng.integers(fewest, most + 1))
    rows = rng.integers(0, template.num_rows, count)
    scale = frames / template.column("num_frames")[0].as_py()
    flips = np.asarray(template.column("visibility_flips"))[rows] * scale * rng.uniform(0.5, 1.5, count)
    visible = np.asarray(template.column("visible_frames"))[rows] * scale
    agreement = np.asarray(template.column("mask_agreement"), np.float64)[rows] + rng.normal(0, 0.03, count)
    return pa.table(
        {
            "source": [source] * count,
            "clip": [clip] * count,
            "num_frames": np.full(count, frames),
            "target_tracks": np.full(count, count // 4),
            "candidate": np.arange(count),
            "visible_frames": np.clip(np.round(visible), 0, frames).astype(np.int64),
            "visibility_flips": np.clip(np.round(flips), 0, frames - 1).astype(np.int64),
            "mask_agreement": np.clip(agreement, 0, 1),
        }
    )


def synthetic_release(runs: list[str], splits_json: str, folder: str, seed: int = 0) -> None:
    """Writes the release-size --release run (audit tables, clip links, runs' provenance, verdicts)."""
    release = read_release(splits_json)
    found = templates(runs)
    rng = np.random.default_rng(seed)
    for source, named in sorted(release.clips.items()):
        # A source without a run of its own borrows the first found's tables (the registry's order).
        tables, clip_file = found.get(source) or next(iter(found.values()))
        for path in (audit_path(folder, source, "x"), clip_path(folder, source, "x")):
            os.makedirs(os.path.dirname(path), exist_ok=True)
        for clip in sorted(named):
            table = synthetic_table(tables[rng.integers(len(tables))], source, clip, rng)
            pq.write_table(table, audit_path(folder, source, clip))
            os.link(clip_file, clip_path(folder, source, clip))
        result = evaluate(load_statistics(folder, source), sources.get(source), RunConfig(), dict(named))
        summary = {
            "candidate_tracks": result.candidates,
            "dropped_by_filter": dict(result.dropped),
            "tracks_passing_filters": result.passed,
            "clips_below_target": result.clips_below_target,
            "clips_written": result.clips_written,
        }
        record = {"config": RunConfig().to_dict(), "release": splits_json, "summary": summary}
        with open(provenance_path(folder, source), "w") as handle:
            json.dump(record, handle)
        with open(release_verdicts_path(folder, source), "w") as handle:
            for clip, split in sorted(named.items()):
                row = {"clip": clip, "split": split, "status": "written", "tracks": 0, "reason": "synthetic"}
                handle.write(json.dumps(row) + "\n")


def browser():
    """Headless Chromium through chromedriver (selenium)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in [
        *FLAGS,
        f"--user-data-dir={tempfile.mkdtemp(prefix='chromium-')}",
        "--window-size=1300,1500",
    ]:
        options.add_argument(flag)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)


def measure(output: str, page: str, thumbnails: int) -> dict:
    """The page of ``output``: seconds to write, MB, ms to ready (median of 3 loads), ms per recount,
    heap MB."""
    started = time.perf_counter()
    command = [sys.executable, "-m", "pipeline.audit", "report", output, "--out", page]
    subprocess.run([*command, "--thumbnails", str(thumbnails)], check=True, capture_output=True)
    written = time.perf_counter() - started
    ready, moves, heaps = [], [], []
    for _ in range(3):
        driver = browser()
        try:
            driver.get("file://" + os.path.abspath(page))
            for _ in range(1200):
                if driver.execute_script("return document.documentElement.dataset.ready") == "true":
                    break
                time.sleep(0.05)
            ready.append(driver.execute_script("return window.auditReadyMs"))
            move, heap = driver.execute_script(MOVE_SCRIPT)
            moves.append(move)
            heaps.append(heap)
        finally:
            driver.quit()
    clips = sum(len(glob(audit_path(output, source, "*"))) for source in sources.names())
    return {
        "output": output,
        "clips": clips,
        "write_s": round(written, 1),
        "page_mb": round(os.path.getsize(page) / 1e6, 2),
        "ready_ms": round(median(ready)),
        "recount_ms": round(median(moves), 1),
        "heap_mb": round(median(heaps) / 1e6, 1),
    }


def main(argv: list[str] | None = None) -> int:
    parser = StrictParser(prog="python -m benchmarks.audit_page", description=__doc__)
    parser.add_argument("runs", nargs="+", metavar="RUN", help="a run's output folder")
    parser.add_argument(
        "--release", metavar="SPLITS_JSON", help="also a synthetic run of this release's size"
    )
    parser.add_argument(
        "--workdir", default="out/bench/audit_page", help="pages and the synthetic run (default %(default)s)"
    )
    parser.add_argument("--thumbnails", type=int, default=12, help="per source (default %(default)s)")
    args = parser.parse_args(argv)
    os.makedirs(args.workdir, exist_ok=True)
    outputs = [os.path.abspath(run) for run in args.runs]
    if args.release:
        folder = os.path.abspath(os.path.join(args.workdir, "release_size"))
        if not os.path.exists(os.path.join(folder, ".complete")):
            print(f"writing the release-size run into {folder} (a few minutes, once)")
            synthetic_release(outputs, args.release, folder)
            open(os.path.join(folder, ".complete"), "w").close()
        outputs.append(folder)
    rows = []
    for index, output in enumerate(outputs):
        rows.append(measure(output, os.path.join(args.workdir, f"page_{index}.html"), args.thumbnails))
        print(json.dumps(rows[-1]))
    with open(os.path.join(args.workdir, "audit_page.json"), "w") as handle:
        json.dump(rows, handle, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
