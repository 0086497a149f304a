"""Errors of the mapping pipeline, rooted in :class:`baromap.errors.BaromapError`."""

from baromap.errors import BaromapError


class MappingError(BaromapError):
    """A run cannot be mapped as given (no scan on any floor, a graph edge to no node)."""
