"""Temporal questions, over search: ``last``, ``first``, ``count``, ``before``, ``after``,
``timeline`` and moments (``operators.Temporal``), grasps (``grasps``), episodes
(``episodes``) and clock offsets (``clocks``). It may import ``search``, ``storage``,
``spaces`` and the base modules, never the memory facade above it (``memory``, ``writes``,
``spatial``; tests/project/test_architecture.py checks it)."""
