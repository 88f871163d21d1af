"""Speed and memory benchmarks of the pipeline (``python -m benchmarks``), kept out of the installed
package: they import ``pipeline`` and ``pipeline.samples``, never the other way round.

One file per job:
  cli.py               the command: ``python -m benchmarks {all,adt,drivetrack,pstudio} [--quick] [--micro]``
  units.py             the per-unit benchmark of one source: prepare, run the scaling set, report
  worker.py            one unit in a fresh single-threaded pinned process, through ``pipeline.unit.run_unit``
  processes.py         spawning the worker processes, reaping them (wait4), their peak memory (VmHWM)
  report.py            per-source figures, the summary table, CPU-hours
  inputs_<source>.py   ``prepare(workdir, quick)``: the inputs of one source's unit (built once, cached)
  micro_<source>.py    ``run(frames)``: the source's micro-benchmarks (``--micro``)
"""
