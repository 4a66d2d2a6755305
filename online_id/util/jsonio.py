"""Strict JSON for every file and string online-id writes (``--json``, the API's ``to_json``, batch)."""

from __future__ import annotations

import json
import math


def json_text(data) -> str:
    """Strict JSON (RFC 8259) of ``data``, NaN and ±inf as null: a partial result (an interrupted run)
    may hold values never computed, and a strict reader must still load the file. numpy scalars and
    arrays become numbers and lists; anything else json cannot write raises TypeError."""
    def clean(x):
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        if hasattr(x, "tolist") and type(x).__module__ == "numpy":  # numpy scalars and arrays
            return clean(x.tolist())
        return x

    return json.dumps(clean(data), indent=2, allow_nan=False) + "\n"
