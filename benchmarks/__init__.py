"""Speed and memory benchmarks of the pipeline (``python -m benchmarks``), kept out of the installed
package: they import ``pipeline`` and ``pipeline.samples``, never the other way round.

One file per job:
  cli.py               the command: ``python -m benchmarks {all,adt,drivetrack,pstudio} [--quick|--full]``
  units.py             the per-unit benchmark of one source: prepare, run the scaling set and the floor
  worker.py            one unit in a fresh single-threaded pinned process, through ``pipeline.unit.run_group``
  floors.py            the read+decode floor of a unit: reading and decoding its inputs, nothing else
  processes.py         spawning the worker processes, reaping them (wait4), their peak memory (VmHWM)
  report.py            per-source figures, the one table against the targets, its JSON, CPU-hours
  <source>.py          one source's benchmark: ``prepare(workdir, quick[, full])``, its unit inputs (built
                       once, cached), and ``run(frames)``, its micro-benchmarks (``--micro``)
"""
