"""``python -m benchmarks pstudio --quick``: the per-unit benchmark runs end to end and prints
every figure (no timing assertions: only that each figure is there and positive)."""

from __future__ import annotations

import re

from benchmarks import cli


def test_quick_unit_bench_prints_every_figure(tmp_path, capsys):
    assert cli.main(["pstudio", "--quick", "--units", "2", "--workdir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for phrase in (
        "unit work (read inputs + annotate + filter + encode/write)",
        "per frame",
        "max RSS",
        "speed-up",
        "CPU-hours, full benchmark",
    ):
        assert phrase in out, f"{phrase!r} missing from:\n{out}"
    (line,) = [line for line in out.splitlines() if line.startswith("RESULT ")]
    figures = dict(item.split("=", 1) for item in line.split()[1:])
    assert figures["source"] == "pstudio"
    for key in ("unit_s", "unit_cpu_s", "per_frame_ms", "max_rss_gib", "speedup", "cpu_hours"):
        assert float(figures[key]) > 0, (key, line)
    assert re.search(r"written, [1-9]\d* tracks", out), out
