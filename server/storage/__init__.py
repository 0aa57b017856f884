"""Storage: the only package that knows collection names, indexes and query shapes."""

from server.storage.driver import Collection, Store, open_store

__all__ = ["Collection", "Store", "open_store"]
