"""Reading the YAML files of a build-maps directory (``building.yaml``, map_server ``.yaml``).

Both exporters start from them; a file that is missing, is not YAML, or is not a mapping at
its top is an InputFormatError naming it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from baromap.errors import InputFormatError


def read_yaml_mapping(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise InputFormatError(f"cannot read {path}: {exc}") from exc
    if not isinstance(data, dict):
        raise InputFormatError(f"{path} is not a YAML mapping")
    return data
