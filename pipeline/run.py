"""``python -m pipeline.run --source {adt,drivetrack,pstudio} --runner DirectRunner ...``: regenerate
TAPVid-3D clips from a source dataset (``pipeline/runner/command.py``; ``--help`` lists the options
and exit statuses)."""

import time

STARTED = time.monotonic()  # the command's start for its "finished in": the imports below count too

from pipeline.pipes import run_command  # noqa: E402
from pipeline.runner.command import main, stop_workers  # noqa: E402

if __name__ == "__main__":
    run_command(lambda: main(started=STARTED), stop=stop_workers)
