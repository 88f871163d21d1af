"""The benchmark's table and its JSON (``python -m benchmarks``): built from given figures (the
verdicts against the targets, the ``all`` row), and one tiny real run end to end
(``pstudio --quick --units 1 --workers 1``: a unit process and a floor process), and the
worker's clock for what repeated runs pay again (on a fake clock). No timing
assertions: only that every column is there, each figure positive, and ``all`` sums the sources."""

from __future__ import annotations

import json
import sys
import types

import pytest

from benchmarks import cli, worker
from benchmarks.entry import entry
from benchmarks.processes import UnitRun
from benchmarks.report import GIB, Runs, peaks_by_rules
from benchmarks.table import COLUMNS, CPU_HOURS_TARGET, OWN_TARGETS, format_table, summary_table
from pipeline import sources
from pipeline.core.benchmark import UnitSetup

KEYS = ["source", *(key for key, *_ in COLUMNS)]


def given(
    source: str,
    ms: float,
    rss: float,
    speedup: float | None,
    cpu_hours: float,
    ratio: float,
    beam: float | None = None,
) -> dict:
    """The figures ``benchmarks.report.report`` returns, with the ones the table reads set."""
    unit_frames = {"drivetrack": 597, "pstudio": 450, "adt": 300}[source]
    return {
        "source": source,
        "size": "default",
        "extrapolated": source != "drivetrack",
        "unit_frames": unit_frames,
        "ms_per_frame": ms,
        "peak_rss_gib": rss,
        "speedup": speedup,
        "speedup_cpu": speedup and speedup + 0.05,
        "beam_speedup": beam,
        "cpu_hours": cpu_hours,
        "floor_ratio": ratio,
        "cpu_per_wall": 0.98,
        "full_units": 10,
        "notes": [],
    }


def test_table_judges_each_figure_and_sums_the_cpu_hours():
    figures = [
        given("drivetrack", 140.0, 1.9, 1.85, 9.5, 1.5, beam=1.82),
        given("pstudio", 120.0, 0.6, 1.7, 1.25, 2.5, beam=1.52),
        given("adt", 50.0, 0.3, None, 4.0, 1.9),
    ]
    table = summary_table(figures, "default")
    rows = {row["source"]: row for row in table["rows"]}
    assert [row["source"] for row in table["rows"]] == ["drivetrack", "pstudio", "adt", "all"]
    assert table["columns"] == KEYS
    for row in table["rows"]:
        for key in KEYS[1:]:
            assert {key, f"{key}_target", f"{key}_pass"} <= row.keys(), (row["source"], key)
    assert rows["drivetrack"]["ms_per_frame_pass"] is True  # 140 <= 150
    assert rows["pstudio"]["ms_per_frame_pass"] is False  # 120 > 100
    assert rows["adt"]["ms_per_frame_pass"] is True  # 50 <= 60
    assert rows["drivetrack"]["peak_rss_gib_pass"] is True and rows["pstudio"]["peak_rss_gib_target"] is None
    assert (rows["drivetrack"]["speedup_pass"], rows["pstudio"]["speedup_pass"]) == (True, False)
    assert rows["adt"]["speedup_pass"] is None  # not measured
    # Through Beam (--beam), judged against the same target; not run: not judged.
    assert [rows[s]["beam_speedup_pass"] for s in ("drivetrack", "pstudio", "adt")] == [True, False, None]
    assert table["targets"]["beam_speedup"] == rows["adt"]["beam_speedup_target"] == 1.8
    assert [rows[s]["floor_ratio_pass"] for s in ("drivetrack", "pstudio", "adt")] == [True, False, True]
    assert rows["all"]["cpu_hours"] == pytest.approx(14.75)
    assert (rows["all"]["cpu_hours_target"], rows["all"]["cpu_hours_pass"]) == (CPU_HOURS_TARGET, True)
    assert rows["all"]["full_units"] == 30
    lines = format_table(table)
    assert lines[0].split()[0] == "source" and lines[4].startswith("all")
    assert "120.0* <=100 FAIL" in lines[2] and "14.75* <=15 pass" in lines[4]
    assert "1.82x >=1.8 pass" in lines[1] and "1.52x >=1.8 FAIL" in lines[2]
    assert lines[5] == "the release under its rules: 14.75 CPU-hours in all, +8.75 from the goal of 6"
    assert rows["all"]["cpu_hours_gap"] == pytest.approx(8.75)
    assert "of a release unit (drivetrack 597, pstudio 450, adt 300 frames" in lines[6]
    # Without every source, the total is not judged against the whole benchmark's target.
    partial = summary_table(figures[:2], "default")["rows"][-1]
    assert partial["cpu_hours"] == pytest.approx(10.75) and partial["cpu_hours_pass"] is None


def test_every_source_has_a_benchmark_entry():
    """Each registered source's entry (``Source.bench_module``) defines the whole interface, with
    targets only for the columns an entry may judge."""
    for name in sources.names():
        module = entry(name)
        assert module.__name__ == sources.get(name).bench_module
        assert set(module.TARGETS) <= set(OWN_TARGETS) and "ms_per_frame" in module.TARGETS


def test_quick_run_prints_the_table_and_writes_it_as_json(tmp_path, capsys):
    path = tmp_path / "table.json"
    argv = ["pstudio", "--quick", "--units", "1", "--workers", "1", "--workdir", str(tmp_path)]
    assert cli.main([*argv, "--json", str(path)]) == 0
    out = capsys.readouterr().out
    data = json.loads(path.read_text())
    assert data["columns"] == KEYS and data["size"] == "quick"
    pstudio, every = data["rows"]
    assert (pstudio["source"], every["source"]) == ("pstudio", "all")
    for key in ("ms_per_frame", "peak_rss_gib", "cpu_hours", "floor_ratio", "cpu_per_wall", "unit_s"):
        assert pstudio[key] > 0, (key, pstudio[key])
    assert pstudio["unit_cpu_s"] > 0 and pstudio["floor_s"] > 0 and pstudio["floor_cpu_s"] > 0
    assert pstudio["speedup"] is None and pstudio["speedup_cpu"] is None  # one worker: no speed-up
    for key in ("beam_speedup", "beam_wall_s", "beam_serial_s", "beam_groups"):
        assert pstudio[key] is None, key  # without --beam
    # The unit under the release's rules, its variant under the refined ones (a plain run's).
    peaks = pstudio["peak_rss_gib_by_rules"]
    assert peaks.keys() == {"refined", "release"} and peaks["release"] == pstudio["peak_rss_gib"]
    assert 0.5 < peaks["refined"] / peaks["release"] < 2
    assert "  with the refined rules (rules=refined): unit work" in out
    assert pstudio["ms_per_frame_pass"] is None and pstudio["ms_per_frame_target"] == 100  # quick: not judged
    assert pstudio["tracks_written"] > 0
    assert every["cpu_hours"] == pytest.approx(pstudio["cpu_hours"])
    assert every["cpu_hours_pass"] is None  # one source of three
    assert pstudio["clips_per_cpu_hour"] == pytest.approx(156 / pstudio["cpu_hours"])  # the release's clips
    assert f"clips per CPU-hour: {pstudio['clips_per_cpu_hour']:.0f} (156 clips in those units)" in out
    summary = out[out.index("=== summary") :].splitlines()
    assert summary[1].split()[:2] == ["source", "ms/frame"]
    assert summary[2].startswith("pstudio") and summary[3].startswith("all")
    assert f"table written to {path}" in out


def test_the_functions_a_repeated_run_pays_again_are_clocked_apart(monkeypatch):
    """``FIXED_IN_WORK`` functions (ADT: opening the sequence in each of the runs) are wrapped in
    their module, so that every call adds exactly its own wall and CPU seconds to the totals the
    report takes out of the per-frame cost (a fake clock that only the wrapped call advances)."""
    clock = [0.0]
    module = types.ModuleType("fixed_in_work_probe")
    module.open_again = lambda seconds: clock.__setitem__(0, clock[0] + seconds) or seconds
    monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setattr(
        worker,
        "time",
        types.SimpleNamespace(perf_counter=lambda: clock[0], process_time=lambda: 2 * clock[0]),
    )
    totals = [0.0, 0.0]
    worker.clock_apart([(module.__name__, "open_again")], totals)
    assert module.open_again(0.25) == 0.25 and module.open_again(0.5) == 0.5
    clock[0] += 10.0  # work outside the wrapped calls is not counted
    assert totals == [0.75, 1.5]


def test_the_table_holds_the_peak_memory_of_each_rule_set():
    """The unit's peak under the rule set its settings name, each variant's under the rule set
    ``UnitSetup.rule_sets`` gives it (DriveTrack's three), the highest of each one's runs."""

    def runs_of(*gib: float) -> list[UnitRun]:
        return [UnitRun({}, 1.0, 1.0, int(peak * GIB)) for peak in gib]

    setup = UnitSetup(
        "drivetrack",
        "",
        [],
        ["rules=release"],
        1,
        [],
        1,
        "",
        variants={"refined": ["rules=refined"], "alone": ["rules=refined", "drivetrack.undistort_frames=0"]},
        rule_sets={"refined": "refined", "refined without undistorted frames": "alone"},
    )
    variants = {"refined": runs_of(2.0, 2.25), "alone": runs_of(1.75, 1.5)}
    runs = Runs(runs_of(1.0, 1.5), 2.0, [], None, None, 1, True, variants)
    assert peaks_by_rules(setup, runs) == {
        "release": 1.5,
        "refined": 2.25,
        "refined without undistorted frames": 1.75,
    }
