"""tactus_memory.memory.main."""
