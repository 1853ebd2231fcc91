"""The HTTP service over the memory, installed as ``tactus_memory.service``."""
