"""The sense contract and its two registries, each module named for what it holds:

- :mod:`~tactus_memory.senses.base`: ``Sense``, what a sense adapter implements (validate,
  embed, its query transform, its record);
- :mod:`~tactus_memory.senses.plugins`: the plug-in registry, classes by name
  (``@register("touch")``; spaces register there too), what a store's record names;
- :mod:`~tactus_memory.senses.stored`: ``SenseRegistry``, the senses one store knows (live
  or recorded), their calibration and row counts: the write and search paths ask it.

The adapters (``tactus_memory.adapters``) implement the contract.
"""
