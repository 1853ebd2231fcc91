"""Search, over storage: the query and its transform (``query``), per-sense score calibration
(``scoring``), ranking hits (``ranking``), objects taught by example (``teaching``); the
sense registry of a store is :mod:`tactus_memory.senses.stored`. It may import ``storage``,
``spaces`` and the base modules, never ``temporal`` or the modules above
(tests/project/test_architecture.py checks it)."""
