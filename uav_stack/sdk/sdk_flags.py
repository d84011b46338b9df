"""``mrswarm agent --params``: a behaviour's parameters from the command line."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

MAX_PARAMS_BYTES = 256 * 1024


def read_params(text: str) -> dict[str, Any]:
    """A JSON object, or ``@FILE`` of YAML or JSON holding a mapping; ValueError saying what is wrong."""
    if text.startswith("@"):
        path = Path(text[1:])
        try:
            if path.stat().st_size > MAX_PARAMS_BYTES:
                raise ValueError(f"{path}: larger than {MAX_PARAMS_BYTES // 1024} KiB")
            raw = path.read_text()
        except OSError as exc:
            raise ValueError(f"{path}: cannot read it: {exc.strerror or exc}") from None
        import yaml  # YAML is a superset of JSON

        try:
            data = yaml.safe_load(raw)
        except yaml.YAMLError as exc:
            raise ValueError(f"{path}: not YAML or JSON: {exc}") from None
    else:
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise ValueError(f"not a JSON object ({exc}); or give @FILE") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f"expected a mapping of the behaviour's parameters, got {type(data).__name__}")
    return data
