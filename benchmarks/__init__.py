"""Speed and memory benchmarks of the pipeline (``python -m benchmarks``), kept out of the installed
package: they import ``pipeline`` (its sources' sample worlds among it), never the other way round.

The framework, one file per job:
  cli.py         the command: ``python -m benchmarks {all,<source>} [--quick|--full] [--micro]``
  units.py       the per-unit benchmark of one source: prepare, run the scaling set and the floor
  beam.py        with --beam, the source's groups through python -m pipeline.run on Beam's
                 DirectRunner with 1 and N workers: speed-up and serial start
  worker.py      one unit (or its floor) in a fresh single-threaded pinned process
  processes.py   spawning the worker processes, reaping them (wait4), their peak memory (VmHWM)
  report.py      one source's figures: computed from its runs, printed
  table.py       the one table of every source against its targets, its lines and its JSON
  entry.py       finding a source's entry, the interface it defines, the UnitSetup it returns
  audit_page.py  the audit page's size and load time in headless Chromium
  hostile_files.py  every hostile file and fault case run as a user would: exit, peak RSS, files
                 touched outside --output, on one source's sample
                 (``python -m benchmarks.hostile_files [FOLDER] [--source NAME]``)

One entry per source, in the source's own folder (``pipeline/<source>/bench.py``), found through
the registry (``sources.get(name).bench_module``, which ``Source.bench`` names); the bench runs the
sources in ``sources.names()``'s order. An entry defines:
  TARGETS                           {table column: target}: its own targets, ``ms_per_frame`` and
                                    ``peak_rss_gib`` (the others are every source's: ``table.py``)
  RELEASE_SHAPE                     (candidates per clip, (fewest, most) frames per clip) of the
                                    release's clips: the audit page's bench draws tables that size
  FIXED_IN_WORK                     ((module, function), ...): what each repeated run pays again,
                                    clocked inside the runs and taken out of the per-frame cost
  prepare(workdir, size)            -> UnitSetup, or None (skipped): its unit's inputs, written once
                                    under ``workdir`` at ``size`` ("quick", "default" or "full")
  measure_fixed_cost(spec, config)  -> {figure: seconds}: in the unit's process, before the runs,
                                    the costs that do not scale with its frames
  floor(spec)                       -> floor_s, floor_cpu_s, floor_frames: in a process of its own,
                                    the bare reading and decoding of the unit's inputs
  unit_of(fields)                   -> the source's unit from its fields as a spec holds them (a
                                    JSON list: ``[segment, camera]``)
  micro(frames)                     prints its micro-benchmarks (``--micro``)
  beam_input(setup, folder, groups) -> the ``pipeline.run`` arguments (``--input``, settings) of
                                    an input of ``groups`` distinct groups, each the size of
                                    ``setup``'s unit, made in ``folder`` out of its input by links
                                    (``--beam``; the setup's ``overrides`` are added as ``--set``)
and may define:
  release_size_clip(spec, config)   -> a ``ClipRecord`` as long as a release unit's: its filter,
                                    encode and write stage is timed apart (``write_unit_s``), for
                                    a unit whose measured clips are shorter (ADT's excerpt)
A ``spec`` is one unit's, as ``units.py`` writes it for the worker: source, entry, input_root,
unit (a group of the source's units, JSON), overrides, output, and the setup's ``extra``.
"""
