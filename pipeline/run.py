"""``python -m pipeline.run --source {adt,drivetrack,pstudio} --runner DirectRunner ...``: regenerate
TAPVid-3D clips from a source dataset (``pipeline/runner/command.py``; ``--help`` lists the options
and exit statuses)."""

from pipeline.pipes import run_command
from pipeline.runner.command import main, stop_workers

if __name__ == "__main__":
    run_command(main, stop=stop_workers)
