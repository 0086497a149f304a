"""Scoring against truth and real data: floor detection and maps, on simulated and real runs.

It sits above ``sim``, ``floors`` and ``mapping`` because its harnesses generate simulated
runs and score the detectors and the mapper on them; no lower layer imports it.
"""
