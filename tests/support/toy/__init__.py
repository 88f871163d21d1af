"""A toy source in a folder of its own, as a plug-in would be: ``source.py`` (its units, annotation,
sample and ``SOURCE``, its settings section included) and ``bench.py`` (its benchmark entry).
Registered by naming ``tests.support.toy.source`` in ``TAPVID3D_SOURCES``, or by the tests
(``sources.register(TOY)``)."""
