"""tactus_memory.export."""
