"""``python -m pipeline.audit compare REF NEW_DIR [--clips LIST] [--out PREFIX] [--jobs N] [--set K=V]``:
TAPVid-3D metrics of NEW against REF, scored as tapnet's ``tapvid3d/evaluation/evaluate_model.py``
scores them, and each clip's agreement with REF.

REF is a folder, or a base URL (``gs://``, ``http(s)://``, e.g. the release's bucket,
``https://storage.googleapis.com/dm-tapnet/tapvid3d/release_files/v1.0``). Clips are matched by
``<source>/<clip>.npz``; REF's clips (a URL cannot be listed: then the release clips of NEW_DIR's
verdicts, ``release_<source>.jsonl``), or those named in ``--clips`` (one ``<source>/<clip>.npz`` a
line, e.g. a run's ``manifests/minival.txt``: tapnet's ``use_minival``) are the benchmark, NEW's
``tracks_XYZ`` and ``visibility`` the prediction (other members are ignored, so a file holding only
those two is scored); tracks correspond by index. Per clip: 3D-AJ and APD under each rescaling of
``pipeline.audit.metrics.SCALINGS``, OA (the visibility agreement) and the median 3D error in metres
(not a tapnet metric); and its agreement (``pipeline/audit/agreement.py``): the share of equal query
frames, the visibility agreement, the median and 95th percentile of the track distance (mm), and
whether it agrees fully (``--agree-mm``). Over HTTP only the members scored are read, by Range
requests (``pipeline.io.http``), ``--jobs`` clips at a time: a clip's frames never, but the start of
its first JPEG, for the frame size; ``fetched_bytes`` counts each clip's bytes received. As in tapnet:

- a REF clip whose prediction is missing, unreadable, refused or of another shape counts with every
  metric 0 (status ``zero``); a release clip the run did not make is left out (``not_made``: its
  verdict says why; REF is not fetched for it);
- per source, each metric is the plain mean over its clips, whatever their length (a NaN metric,
  from a REF clip with no visible point, makes the mean NaN); ``all`` is the mean of the source means.

A clip REF does not hold (HTTP 404, or absent from a local REF) is ``not_in_ref``, left out of the
means; one whose REF file cannot be read (tapnet's evaluator would stop there) is ``ref_error``, left
out too. Writes ``PREFIX.md`` and ``PREFIX.json`` (default prefix ``NEW_DIR/compare``) and, when
NEW_DIR is a release run, each verdict row's ``agreement``, all together or not at all
(``pipeline.io.file_set``). A compare never erases an earlier finding it could not replace: a clip it
could not read from REF keeps the earlier report's row (``carried``) and its verdict keeps the
agreement of the last compare that scored it, with that compare's reference and time. After
``max_failures_in_a_row`` clips in a row failed alike (a dead server) it stops, writes what it found,
and says so.

Exit status: 0 every requested clip was scored, counted 0 or is absent from REF, and one at least
was scored; 1 a REF clip could not be read (the last line says how many; a rerun completes them), or
none was scored; 2
bad arguments, a missing folder, an unreadable ``--clips`` list or outputs that cannot be written; 4 it
stopped itself (``max_failures_in_a_row``); 130 Ctrl-C (nothing written).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import math
import os
import re
import sys
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from pipeline import sources as registry
from pipeline.audit.agreement import AGREE_MM
from pipeline.audit.compare_rows import (
    Carried,
    ClipRow,
    CompareReport,
    RefUnread,
    Scored,
    Status,
    Zero,
    carried_row,
    markdown,
    summarise,
)
from pipeline.audit.scoring import read_reference, score_pair
from pipeline.audit.verdict_rows import ClipAgreement, amended_verdicts, read_verdicts, release_clip_keys
from pipeline.commandline import StrictParser
from pipeline.core.outcomes import FailureStreak
from pipeline.export.layout import release_verdicts_path
from pipeline.io.clip_reader import DEFAULT_LIMITS, ReadLimits, add_limit_argument, limits_from
from pipeline.io.file_set import complete_commits, output_lock, reclaim_temporaries, write_together
from pipeline.io.files import exists, is_local, list_files, read_bytes
from pipeline.io.http import HttpClient, is_http, join, shown
from pipeline.settings.fields import SettingsError, add_set_argument, not_in_clips, with_overrides
from pipeline.settings.run_config import MAX_FAILURES_IN_A_ROW, HttpConfig

__all__ = ["Status", "compare_dirs", "main", "read_reference"]

CLIP_ENTRY = re.compile(r"[^/\s]+/[^/\s]+\.npz")
MAX_LIST_BYTES = 16 << 20
MAX_REPORT_BYTES = 256 << 20
DEFAULT_JOBS = 8
MAX_JOBS = 64
NOT_REACHED = "not compared: the compare stopped first"


@dataclasses.dataclass(frozen=True)
class CompareSettings:
    """What ``--set`` changes for a compare: the run's rules for transfers and for stopping.

    max_failures_in_a_row: the compare stops (exit status 4) once this many clips in a row could not
      be read from REF for the same cause (a dead server); 0: never.
    http: how every transfer behaves (retries, deadline, stall rule), as in a run.
    """

    max_failures_in_a_row: int = not_in_clips(MAX_FAILURES_IN_A_ROW, "[0, 1000000]")
    http: HttpConfig = dataclasses.field(default_factory=HttpConfig)


@dataclasses.dataclass(frozen=True)
class Benchmark:
    """The clips to score, in order (``<source>/<clip>.npz``), REF's path of each it holds, NEW's
    clips, REF's clips when it can be listed (None over HTTP), how many of NEW's clips ``--clips``
    left out, and why a release run made no clip of a name (its verdict's reason)."""

    keys: list[str]
    ref: Mapping[str, str]
    new: Mapping[str, str]
    listed: frozenset[str] | None
    not_requested: int
    not_made: Mapping[str, str]


def clip_keys(root: str) -> dict[str, str]:
    """``<source>/<clip>.npz`` -> path, for every clip under ``root/<source>/``."""
    paths = list_files(f"{root.rstrip('/')}/*/*.npz")
    return {"/".join(path.replace("\\", "/").split("/")[-2:]): path for path in paths}


def read_clip_list(path: str) -> list[str]:
    """The ``<source>/<clip>.npz`` entries of a list file, one a line, in its order (blank lines
    and repeats skipped); ValueError naming a malformed line, OSError when unreadable."""
    lines = read_bytes(path, MAX_LIST_BYTES).decode("utf-8", errors="replace").splitlines()
    entries = [line.strip() for line in lines if line.strip()]
    malformed = [entry for entry in entries if not CLIP_ENTRY.fullmatch(entry)]
    if malformed:
        raise ValueError(f"{path}: {malformed[0]!r} is not <source>/<clip>.npz")
    return list(dict.fromkeys(entries))


def not_made_by_run(new_dir: str) -> dict[str, str]:
    """``<source>/<clip>.npz`` -> the verdict's reason, for each release clip a release run in
    ``new_dir`` did not write."""
    found = {}
    for source in registry.names():
        for row in read_verdicts(new_dir, source) or []:
            if row.verdict.status != "written":
                found[f"{source}/{row.verdict.clip}.npz"] = f"{row.verdict.status}: {row.verdict.reason}"
    return found


def benchmark_clips(ref_dir: str, new_dir: str, clips: list[str] | None) -> Benchmark:
    """The clips to score: ``clips``, else REF's own (sorted), else, for a REF that cannot be listed
    (HTTP), the release clips of NEW_DIR's verdicts; ValueError when there is no way to know them."""
    new = clip_keys(new_dir)
    not_made = not_made_by_run(new_dir)
    if is_http(ref_dir):
        keys = clips if clips is not None else release_clip_keys(new_dir)
        if keys is None:
            raise ValueError(
                f"{shown(ref_dir)} cannot be listed: give --clips, or compare a --release run "
                "(its verdicts name the release's clips)"
            )
        ref = {key: join(ref_dir, key) for key in keys}
        return Benchmark(keys, ref, new, None, len(new.keys() - set(keys)) if clips else 0, not_made)
    listed = clip_keys(ref_dir)
    keys = sorted(listed) if clips is None else clips
    left_out = len((new.keys() & listed.keys()) - set(keys))
    return Benchmark(keys, listed, new, frozenset(listed), left_out, not_made)


class ClipScorer:
    """Scores benchmark clips ``jobs`` at a time, each worker thread with its own HTTP client (its
    bytes counted per clip), notes printed once; ``cancel`` ends every transfer in flight."""

    def __init__(self, bench: Benchmark, at: str, limits: ReadLimits, agree_mm: float, http: HttpConfig):
        self.bench, self.at, self.limits, self.agree_mm, self.http = bench, at, limits, agree_mm, http
        self.cancel = threading.Event()
        self._local = threading.local()
        self._noted: set[str] = set()
        self._lock = threading.Lock()

    def _note(self, text: str) -> None:
        with self._lock:
            if text not in self._noted:
                self._noted.add(text)
                print(f"note: {text}", file=sys.stderr)

    def client(self) -> HttpClient:
        if not hasattr(self._local, "client"):
            self._local.client = HttpClient(self.http, self._note, self.cancel)
        return self._local.client

    def score(self, key: str) -> ClipRow:
        ref = self.bench.ref.get(key)
        client = self.client() if ref is not None and is_http(ref) else None
        new = self.bench.new.get(key)
        return score_pair(
            key, ref, new, self.at, self.limits, client, self.agree_mm, self.bench.not_made.get(key, "")
        )


@dataclasses.dataclass(frozen=True)
class Scoring:
    """The rows found (in the benchmark's order; a clip not reached has none) and, when the stop rule
    ended the compare, why."""

    rows: dict[str, ClipRow]
    stopped: str = ""


def score_clips(scorer: ClipScorer, jobs: int, max_failures_in_a_row: int) -> Scoring:
    """Every benchmark clip scored, ``jobs`` at a time, until ``max_failures_in_a_row`` clips in a row
    (as they finish) could not be read from REF for one cause (0: never stop). Ctrl-C cancels the
    transfers in flight and is raised again."""
    bench = scorer.bench
    # A release clip the run did not make is known without reading REF: found first, whatever stops.
    found: dict[str, ClipRow] = {key: scorer.score(key) for key in bench.keys if _not_made(bench, key)}
    keys = [key for key in bench.keys if key not in found]
    streak = FailureStreak(max_failures_in_a_row, "clips")
    stopped, finished = "", False
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="compare")
    try:
        futures = {pool.submit(scorer.score, key): key for key in keys}
        for future in concurrent.futures.as_completed(futures):
            row = future.result()
            found[futures[future]] = row
            if not (isinstance(row, RefUnread) and row.status is Status.REF_ERROR):
                streak.succeeded()
            elif stopped := streak.failed(row.error):
                break
        finished = not stopped
    finally:
        if not finished:  # stopped, or Ctrl-C: the clips in flight end at their next read, unrecorded
            scorer.cancel.set()
        pool.shutdown(wait=finished, cancel_futures=True)
    return Scoring({key: found[key] for key in bench.keys if key in found}, stopped)


def _not_made(bench: Benchmark, key: str) -> bool:
    return key in bench.not_made and key not in bench.new


def compare_dirs(
    ref_dir: str,
    new_dir: str,
    limits: ReadLimits = DEFAULT_LIMITS,
    clips: list[str] | None = None,
    agree_mm: float = AGREE_MM,
    settings: CompareSettings | None = None,
    jobs: int = 1,
    earlier: Mapping[str, Mapping[str, Any]] | None = None,
) -> CompareReport:
    """The report of NEW_DIR's clips against REF's (``benchmark_clips``, in their order: each mean sums
    its clips in that order, as tapnet sums a split's), scored ``jobs`` at a time under ``settings``;
    a clip REF could not give takes its row in ``earlier`` (``<source>/<clip>.npz`` -> an earlier
    report's row, against this REF) when there is one; ``stopped`` says whether the stop rule ended it."""
    settings = settings or CompareSettings()
    bench = benchmark_clips(ref_dir, new_dir, clips)
    at = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    scorer = ClipScorer(bench, at, limits, agree_mm, settings.http)
    scoring = score_clips(scorer, jobs, settings.max_failures_in_a_row)
    rows: list[ClipRow] = []
    for key in bench.keys:
        source, clip = key.split("/")
        row = scoring.rows.get(key) or RefUnread(source, clip, Status.REF_ERROR, NOT_REACHED, at)
        if isinstance(row, RefUnread) and row.status is Status.REF_ERROR and earlier and key in earlier:
            row = carried_row(earlier[key], row.error) or row
        rows.append(row)
    only_in_new = None if bench.listed is None else sorted(bench.new.keys() - bench.listed)
    if bench.listed is None and clips is None:
        only_in_new = sorted(bench.new.keys() - set(bench.keys))
    return CompareReport(
        shown(ref_dir),
        new_dir,
        agree_mm,
        at,
        rows,
        summarise(rows),
        only_in_new,
        bench.not_requested,
        scoring.stopped,
    )


def earlier_rows(prefix: str, ref_dir: str) -> dict[str, dict[str, Any]]:
    """``<source>/<clip>.npz`` -> row of the report at ``PREFIX.json`` when it was made against REF
    (as shown); empty when there is none or it cannot be read."""
    try:
        report = json.loads(read_bytes(f"{prefix}.json", MAX_REPORT_BYTES))
    except (OSError, ValueError):
        return {}
    if not isinstance(report, dict) or report.get("ref") != shown(ref_dir):
        return {}
    rows = report.get("clips")
    if not isinstance(rows, list):
        return {}
    return {
        f"{row['source']}/{row['clip']}": row
        for row in rows
        if isinstance(row, dict) and isinstance(row.get("source"), str) and isinstance(row.get("clip"), str)
    }


def agreement_entry(row: ClipRow, agree_mm: float, ref: str) -> ClipAgreement:
    """A verdict row's agreement from a clip's row: its status, REF and when; the agreement and two of
    tapnet's metrics when scored, else why not."""
    if isinstance(row, Scored):
        measured = row.agreement
        return ClipAgreement(
            row.status.value,
            agree_mm,
            ref=ref,
            compared_at=row.at,
            clip_sha256=row.clip_sha256,
            query_frames_equal=_plain(measured.query_frames_equal),
            visibility=_plain(measured.visibility),
            median_mm=_plain(measured.median_mm),
            p95_mm=_plain(measured.p95_mm),
            agrees=row.agrees,
            aj_median=_plain(row.scores.aj["median"]),
            oa=_plain(row.scores.oa),
        )
    assert not isinstance(row, Carried)  # an earlier compare's finding: its verdict keeps its own entry
    return ClipAgreement(row.status.value, agree_mm, row.error, ref=ref, compared_at=row.at)


def _plain(value: float) -> float | None:
    """A JSON value: NaN as None."""
    return None if math.isnan(value) else value


def write_outputs(report: CompareReport, prefix: str, new_dir: str) -> list[str]:
    """``PREFIX.md``, ``PREFIX.json`` and the verdicts of a release run in NEW_DIR amended with this
    compare's findings, written together; the verdict files amended. OSError when they cannot be."""
    findings = {
        f"{row.source}/{row.clip}": agreement_entry(row, report.agree_mm, report.ref)
        for row in report.clips
        if not isinstance(row, Carried)
    }
    # NEW_DIR is written, and locked, only when it is a release run's folder with verdicts to amend.
    amends = any(exists(release_verdicts_path(new_dir, source)) for source in registry.names())
    with output_lock(new_dir if amends else _folder(prefix)):
        verdicts = amended_verdicts(new_dir, findings) if amends else {}
        files = {
            f"{prefix}.md": markdown(report).encode(),
            f"{prefix}.json": json.dumps(report.to_json(), indent=1, allow_nan=False).encode(),
            **{release_verdicts_path(new_dir, source): data for source, data in verdicts.items()},
        }
        write_together(files, new_dir if verdicts else _folder(prefix))
    return [release_verdicts_path(new_dir, source) for source in verdicts]


def _folder(path: str) -> str:
    return path.rpartition("/")[0] or "."


def tidy(new_dir: str, prefix: str) -> None:
    """Finish what an earlier compare killed while writing left (its commit, its temporaries)."""
    folders = tuple(dict.fromkeys((new_dir, _folder(prefix))))
    for folder in folders:
        complete_commits(folder, folders)
    paths = [f"{prefix}.md", f"{prefix}.json", *(release_verdicts_path(new_dir, s) for s in registry.names())]
    reclaim_temporaries(paths)


def command_parser() -> StrictParser:
    parser = StrictParser(prog="python -m pipeline.audit compare", description=__doc__)
    parser.add_argument(
        "ref_dir",
        metavar="REF",
        help="the reference: a folder or base URL of <source>/<clip>.npz files (e.g. the release's bucket)",
    )
    parser.add_argument("new_dir", metavar="NEW_DIR", help="output folder to score (e.g. a --release run)")
    parser.add_argument("--clips", help="score only these REF clips (a file of <source>/<clip>.npz lines)")
    parser.add_argument("--out", help="write OUT.md and OUT.json (default NEW_DIR/compare)")
    parser.add_argument(
        "--agree-mm",
        type=float,
        default=AGREE_MM,
        help="a clip agrees fully when its query frames and visibility are REF's and the 95th "
        "percentile of its track distance is at most this (millimetres; default %(default)s)",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=DEFAULT_JOBS,
        help=f"clips read and scored at a time (1 to {MAX_JOBS}; default %(default)s)",
    )
    add_set_argument(
        parser,
        "max_failures_in_a_row=N or http.<field>=VALUE (retries, backoff_s, deadline_s, stall_s, "
        "stall_bytes_per_s), as in a run (docs/configuration.md)",
    )
    add_limit_argument(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """The ``compare`` subcommand; exit status as the module doc says."""
    parser = command_parser()
    args = parser.parse_args(argv)
    problems = []
    try:
        limits = limits_from(args.limit)
    except ValueError as error:
        problems.append(str(error))
    try:
        settings = with_overrides(CompareSettings(), args.overrides)
    except SettingsError as error:
        problems += error.problems
    if not args.agree_mm >= 0:
        problems.append(f"--agree-mm {args.agree_mm}: must be a number of millimetres >= 0")
    if not 1 <= args.jobs <= MAX_JOBS:
        problems.append(f"--jobs {args.jobs}: must be 1 to {MAX_JOBS}")
    if problems:
        parser.error("; ".join(problems))
    for folder in (args.ref_dir, args.new_dir):
        if is_local(folder) and not os.path.isdir(folder):
            print(f"compare: {folder} is not a folder", file=sys.stderr)
            return 2
    try:
        clips = None if args.clips is None else read_clip_list(args.clips)
    except (OSError, ValueError) as error:
        print(f"compare: cannot use --clips {args.clips}: {error}", file=sys.stderr)
        return 2
    ref_dir = args.ref_dir if is_http(args.ref_dir) else args.ref_dir.rstrip("/")
    new_dir = _absolute(args.new_dir.rstrip("/"))
    prefix = _absolute(args.out) if args.out else f"{new_dir}/compare"
    try:
        tidy(new_dir, prefix)
        report = compare_dirs(
            ref_dir, new_dir, limits, clips, args.agree_mm, settings, args.jobs, earlier_rows(prefix, ref_dir)
        )
    except ValueError as error:
        print(f"compare: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        print(f"compare: cannot tidy {new_dir}: {error}", file=sys.stderr)
        return 2
    return closing(report, prefix, new_dir, lambda: write_outputs(report, prefix, new_dir))


def _absolute(path: str) -> str:
    return os.path.abspath(path) if is_local(path) else path


def closing(report: CompareReport, prefix: str, new_dir: str, write: Callable[[], list[str]]) -> int:
    """Print the report and the clips not scored; write the outputs (``write``) unless this compare
    found nothing; the last lines say what it could not do. The exit status."""
    rows = report.clips
    if not rows:
        print(f"no REF clip to score in {report.ref}", file=sys.stderr)
        return 1
    # What this compare learnt from REF (a clip the run did not make is known without reading it).
    found = [row for row in rows if row.status in (Status.SCORED, Status.ZERO, Status.NOT_IN_REF)]
    found = [row for row in found if not isinstance(row, Carried)]
    print(markdown(report), end="")
    _not_scored(rows)
    total = report.sources[-1]
    if is_http(report.ref):
        print(
            f"fetched {total.fetched_bytes:,} bytes over HTTP for {len(rows)} clip(s), "
            f"{total.fetched_bytes / len(rows):,.0f} a clip"
        )
    if found:
        try:
            updated = write()
        except OSError as error:
            print(f"compare: cannot write the report {prefix}.md/.json: {error}", file=sys.stderr)
            return 2
        if updated:
            print(f"agreement added to the verdicts in {', '.join(updated)}")
        print(f"report in {prefix}.md and {prefix}.json")
    unread = sum(row.status is Status.REF_ERROR for row in rows)
    carried = sum(isinstance(row, Carried) for row in rows)
    kept = f"; earlier findings kept for {carried}" if carried else ""
    written = "" if found else "; nothing written: the earlier report and verdicts are as they were"
    if report.stopped:
        print(
            f"stopped: {report.stopped}; {len(found)} of {len(rows)} clip(s) compared{written}: "
            "mend the cause and rerun to complete",
            file=sys.stderr,
        )
        return 4
    if unread + carried:
        print(
            f"{unread + carried} of {len(rows)} clip(s) could not be read from REF{kept}{written}; "
            "rerun to complete them",
            file=sys.stderr,
        )
        return 1
    if not any(row.status is Status.SCORED for row in rows):
        print(f"none of the {len(rows)} clip(s) could be scored", file=sys.stderr)
        return 1
    return 0


def _not_scored(rows: list[ClipRow]) -> None:
    """One line on stderr per clip counted 0 or left out, with why; one for those not reached."""
    reached = [row for row in rows if not (isinstance(row, RefUnread) and row.error == NOT_REACHED)]
    if len(reached) < len(rows):
        print(f"not scored: {len(rows) - len(reached)} clip(s) {NOT_REACHED}", file=sys.stderr)
    for row in reached:
        where = f"{row.source}/{row.clip}"
        if isinstance(row, Carried):
            earlier = row.row.get("compared_at")
            print(
                f"not scored: {where}: {row.error} (REF unreadable; the finding of {earlier} kept)",
                file=sys.stderr,
            )
        elif isinstance(row, Zero) and row.status is Status.NOT_MADE:
            print(f"not scored: {where}: {row.error} (left out of the means)", file=sys.stderr)
        elif isinstance(row, Zero):
            print(f"not scored: {where}: {row.error} (counted as 0)", file=sys.stderr)
        elif isinstance(row, RefUnread) and row.status is Status.REF_ERROR:
            print(
                f"not scored: {where}: {row.error} (REF unreadable: left out of the means)", file=sys.stderr
            )
        elif isinstance(row, RefUnread):
            print(f"not scored: {where}: not in REF ({row.error}): left out of the means", file=sys.stderr)
