#!/usr/bin/env bash
# Idempotent set-up: a Python 3.11 venv at .venv/ with the pinned dependencies
# (constraints.txt) and the three seft packages installed in development mode.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
py="${SEFT_PYTHON:-python3.11}"
if ! command -v "$py" >/dev/null 2>&1; then
  echo "setup: $py not found; install Python 3.11 or set SEFT_PYTHON" >&2
  exit 2
fi
stamp=.venv/.seft-setup-stamp
want="$(cat constraints.txt requirements.txt src/*/setup.py | sha256sum | cut -d' ' -f1)"
if [ -x .venv/bin/python ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  exit 0
fi
echo "setup: creating/updating .venv (pinned by constraints.txt)" >&2
[ -x .venv/bin/python ] || "$py" -m venv .venv
.venv/bin/python -m pip install -q --upgrade-strategy only-if-needed -c constraints.txt \
  -r requirements.txt
.venv/bin/python -m pip install -q --no-deps --no-build-isolation \
  -e src/seft_msgs_py -e src/seft_plant_sim -e src/seft_ros
# ament_python installs executables under lib/<package> (the `ros2 run` layout); the CLI is
# also put on the venv's PATH as .venv/bin/seft.
ln -sf ../lib/seft_ros/seft .venv/bin/seft
echo "$want" > "$stamp"
