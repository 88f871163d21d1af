"""``python -m benchmarks.compare_server`` at a toy size: it prints clips per second for each --jobs
value with the most requests the server answered at once, and how a compare against a server
answering 503 stopped."""

from __future__ import annotations

import re

from benchmarks import compare_server
from tests.support.cli import call_main


def test_the_compare_bench_prints_its_rates_and_the_dead_servers_stop(tmp_path):
    argv = ["--clips", "4", "--latency-ms", "0", "--jobs", "1,2", "--dead", "--workdir", str(tmp_path)]
    argv += ["--set", "http.retries=0", "--set", "max_failures_in_a_row=2"]
    result = call_main(compare_server.main, argv)
    assert result.returncode == 0, result.stderr
    one, two, dead = result.stdout.strip().splitlines()
    for line, jobs in ((one, 1), (two, 2)):
        found = re.match(
            rf"--jobs {jobs}: 4 clips in [\d.]+ s, ([\d.]+) clips/s at 0 ms a request \(at most {jobs} at "
            r"once; exit 0\); a release-size compare \(4,569 clips\): ([\d.]+) minutes",
            line,
        )
        assert found, line
        assert float(found[1]) > 0 and float(found[2]) > 0
    assert dead.startswith("a server answering 503: stopped after ")
    assert "(exit 4): stopped: the last 2 clips failed alike (" in dead
