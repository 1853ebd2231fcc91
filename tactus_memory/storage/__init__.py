"""Storage, the bottom layer: the LanceDB store and its tables (``store``, ``tables``,
``indexes``, ``codes``: the sense codes the ANN index partitions by, ``connect``,
``integrity``, ``maintenance``), filters (``where``), vector helpers (``vectors``), poses and
their placing (``places``, ``posestore``) and the rows a write becomes (``rows``). It may
import the package's base modules (``errors``, ``limits``, ``results``, ``settings``,
``senses``, ``plugins``, ``hashing``) and nothing of ``search``, ``temporal`` or the modules
above them (tests/project/test_architecture.py checks it)."""
