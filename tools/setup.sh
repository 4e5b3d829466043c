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
# The live view's browser test (tests/seft_ros/test_live_view.py) drives Debian's headless
# Chromium: installed where it runs (CI=true, or SEFT_BROWSER=1 on a developer's machine),
# once; elsewhere that test is skipped. Playwright's own browser download cannot work here.
if [ "${CI:-}" = true ] || [ "${SEFT_BROWSER:-}" = 1 ]; then
  if [ ! -x /usr/bin/chromium ]; then
    echo "setup: installing Debian's chromium for the browser test" >&2
    if [ "$(id -u)" = 0 ]; then
      apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    else
      sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    fi
  fi
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
