"""``python -m baromap.cli``: the same command as ``baromap``."""

from baromap.cli.main import main

raise SystemExit(main())
