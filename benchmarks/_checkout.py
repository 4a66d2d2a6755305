"""Put the checkout these benchmarks sit in first on ``sys.path``.

A benchmark run as ``python benchmarks/bench_x.py`` would otherwise import online-id from the venv's
site-packages, which ``scripts/test.sh`` fills with a non-editable copy (``pip install .``) that goes
stale as soon as the working tree changes: the figures would be an older version's. Each benchmark
imports this module before online_id.
"""

import sys
from pathlib import Path

ROOT = str(Path(__file__).resolve().parents[1])
if sys.path[:1] != [ROOT]:
    sys.path.insert(0, ROOT)
