"""The repository's root conftest: loads the hardware tests' options plugin (``pytest_baromap``).

The package's ``pytest11`` entry point loads it first where baromap is installed with its
metadata; this covers an environment installed before the entry point existed.
"""

pytest_plugins = ["pytest_baromap"]
