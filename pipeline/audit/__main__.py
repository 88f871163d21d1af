"""``python -m pipeline.audit {sweep,release,compare} ...``: audit a run's thresholds, its verdicts on
the release's clips, or compare clips.

sweep    replay the filter stage at other thresholds from the recorded statistics
release  the verdict on every release clip of a --release run, per source and split, with reasons
compare  TAPVid-3D metrics of one folder of clips against another (e.g. the release)
"""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in ("sweep", "release", "compare"):
        print(__doc__, file=sys.stderr)
        return 2
    if argv[0] == "sweep":
        from pipeline.audit.sweep import main as command
    elif argv[0] == "release":
        from pipeline.audit.release import main as command
    else:
        from pipeline.audit.compare import main as command
    return command(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
