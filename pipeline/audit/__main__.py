"""``python -m pipeline.audit {sweep,release,compare,report} ...``: audit a run's thresholds, its verdicts
on the release's clips, or compare clips. The audited run's folder is the positional ``OUT``; what a
command writes goes to ``--out``.

sweep    OUT --source S --grid KEY=V1,V2  replay the filter stage at other thresholds
release  OUT                              each release clip's verdict, per split, with reasons
compare  REF NEW                          TAPVid-3D metrics of one folder of clips against another
report   OUT --out FILE.html              one HTML page: the filter funnel, a slider per threshold

``python -m pipeline.audit <command> --help`` describes each.
"""

from __future__ import annotations

import importlib
import sys

from pipeline.commandline import closest, plain_text
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
        print(plain_text(__doc__))
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
