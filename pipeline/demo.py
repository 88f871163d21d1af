"""``python -m pipeline.demo``: every registered source's sample run as a release run of the samples'
splits file, then ``pipeline.validate`` over its clips and ``pipeline.audit release`` (what ``make
demo`` runs). Each source runs on its sample world, or on what its ``Source.demo_args`` names (ADT:
the shared excerpt, read in place); a source that cannot run here is skipped with its reason. Each
command is printed, then run in a process of its own, as a user would type it."""

from __future__ import annotations

import shlex
import subprocess
import sys

from pipeline import sources
from pipeline.commandline import StrictParser
from pipeline.pipes import run_command
from pipeline.runner.splits import SAMPLE_RELEASE


def commands(output: str, release: str) -> list[list[str]]:
    """The demo's commands (each a ``python -m`` argument list), the skipped sources said on stderr."""
    runs = []
    for name in sources.names():
        demo_args = sources.get(name).demo_args
        try:
            extra = demo_args() if demo_args else []
        except sources.NoSample as why:
            print(f"demo: {name} skipped: {why}", file=sys.stderr)
            continue
        runs.append(
            [
                "pipeline.run",
                "--source",
                name,
                "--runner",
                "DirectRunner",
                "--output",
                output,
                "--release",
                release,
                *extra,
            ]
        )
    return [*runs, ["pipeline.validate", output], ["pipeline.audit", "release", output]]


def main(argv: list[str] | None = None) -> int:
    parser = StrictParser(prog="python -m pipeline.demo", description=__doc__)
    parser.add_argument("--output", default="out/demo", help="the run's folder (default %(default)s)")
    parser.add_argument("--release", default=SAMPLE_RELEASE, help="the splits file (default: the samples')")
    args = parser.parse_args(argv)
    for command in commands(args.output, args.release):
        print(f"$ python -m {shlex.join(command)}", flush=True)
        status = subprocess.call([sys.executable, "-m", *command])
        if status:
            return status
    return 0


if __name__ == "__main__":
    run_command(main)
