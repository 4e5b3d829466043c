#!/usr/bin/env bash
# Build the documentation into docs/_build/html (self-contained HTML, offline): set up
# (idempotent), then sphinx-build from a fresh environment with warnings as errors, so that a
# broken cross-reference or a docstring numpydoc cannot parse fails. The figures are made by
# the project's own commands (docs/conf.py: FIGURES), again only when the sources changed;
# the README's figure is copied from there.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/tools/setup.sh"
cd "$root"
.venv/bin/sphinx-build -E -q -W --keep-going -j auto -b html docs docs/_build/html "$@"
mkdir -p docs/figures
cp docs/_generated/main/time_histories.png docs/figures/main_job.png
echo "docs: $root/docs/_build/html/index.html"
