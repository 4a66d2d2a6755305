#!/usr/bin/env bash
# The README's test command, and what .ci/run runs: install what the tests need, make the venv,
# run the whole suite. Usage: scripts/test.sh [PYTEST ARGS...]
# pytest's exit status passes through unchanged: a failure, and "no tests collected" (5), fail.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-test-deps.sh
python3 -m venv .venv
.venv/bin/pip install -q ".[test,docs]"
exec .venv/bin/python -m pytest "$@"
