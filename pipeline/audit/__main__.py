"""``python -m pipeline.audit {sweep,release,compare,report} ...``: audit a run's thresholds, its verdicts
on the release's clips, or compare clips.

sweep    replay the filter stage at other thresholds from the recorded statistics
release  the verdict on every release clip of a --release run, per source and split, with reasons
compare  TAPVid-3D metrics of one folder of clips against another (e.g. the release)
report   one self-contained HTML page: the filter funnel, histograms, a slider per threshold

``python -m pipeline.audit <command> --help`` describes each.
"""

from __future__ import annotations

import importlib
import sys

from pipeline.commandline import closest
from pipeline.pipes import run_command

COMMANDS = {
    "sweep": "pipeline.audit.sweep",
    "release": "pipeline.audit.release",
    "compare": "pipeline.audit.compare",
    "report": "pipeline.audit.report_page",
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] in (["-h"], ["--help"]):
        print(__doc__)
        return 0
    if not argv:
        print(f"python -m pipeline.audit: name a command: {', '.join(COMMANDS)} (--help)", file=sys.stderr)
        return 2
    if argv[0] not in COMMANDS:
        near = closest(argv[0], COMMANDS)
        hint = f"did you mean {near}?" if near else f"the commands are {', '.join(COMMANDS)}"
        print(f"python -m pipeline.audit: unknown command {argv[0]!r}; {hint}", file=sys.stderr)
        return 2
    return importlib.import_module(COMMANDS[argv[0]]).main(argv[1:])


if __name__ == "__main__":
    run_command(main)
