"""The run's settings, in one place: the machinery of any settings dataclass (``fields.py``: ranges,
rule sets, ``--set`` overrides), the run's own (``run_config.py``: ``RunConfig``, whose sections are
the sources'), the sources a run may have a section for (``sections.py``), and the page that lists
them all (``doc.py``: ``python -m pipeline.settings.doc``). Each source declares its own section in
``pipeline/<source>/settings.py``.
"""
