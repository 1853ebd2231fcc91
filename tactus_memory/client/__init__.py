"""tactus_memory.client.main."""
