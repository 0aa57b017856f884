"""Storage: the only package that knows collection names, indexes and query shapes."""

from server.storage.backends import Collection, Doc, Duplicate, Rejected, Store, open_store

__all__ = ["Collection", "Doc", "Duplicate", "Rejected", "Store", "open_store"]
