"""The run's orchestration, above the sources: the command (``command.py``), the checks before any
work (``prepare.py``), the Beam shell (``graph.py``), one unit's stages in plain Python
(``stages.py``), the progress lines (``monitor.py``), unit checkpoints (``checkpoint.py``, read,
checked and written by ``ledger.py``) and resume (``resume.py``), the release's splits and verdicts
(``splits.py``, ``verdicts.py``) and the run's end (``finish.py``).
"""
