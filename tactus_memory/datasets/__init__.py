"""tactus_memory.datasets."""
