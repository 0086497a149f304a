"""baromap: map multi-floor buildings with one robot, a laser scanner and a barometer."""

__version__ = "0.1.0"
