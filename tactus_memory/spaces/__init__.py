"""Embedding spaces. ``get_space(name, path=None)`` builds one by registry name."""
