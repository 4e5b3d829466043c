#!/usr/bin/env bash
# Set up (idempotent), lint as ROS does (ament_flake8 rules via ruff), run the test suite.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/tools/setup.sh"
cd "$root"
.venv/bin/ruff check src tests benchmarks tools
bash tools/docs.sh    # the docs, warnings as errors: a broken reference or docstring fails
# two workers (this machine's cores); the node-graph tests on one of them (tests/conftest.py)
exec .venv/bin/python -m pytest tests -q -p no:cacheprovider -n 2 --dist loadgroup "$@"
