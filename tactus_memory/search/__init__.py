"""Search, over storage: the query and its transform (``query``), per-sense score calibration
(``scoring``), the sense registry of a store (``registry``), ranking hits (``ranking``) and the
match bar (``matching``). It may import ``storage``, ``spaces`` and the base modules, never
``temporal`` or the modules above (tests/project/test_architecture.py checks it)."""
