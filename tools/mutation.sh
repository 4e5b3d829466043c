#!/usr/bin/env bash
# Mutation testing of the safety- and accuracy-critical core with mutmut (not run in CI: slow).
#
# Usage: bash tools/mutation.sh [MODULE ...]
#   MODULE: a key of the table below (monitor, controller, reference_force, predictors,
#   hysteresis, delay_rig, servohydraulic, metrics); default: all of them, one after the other.
#
# For each module it copies the packages and the module's fastest relevant test files into a
# scratch folder (mutmut mutates its own copy; the working tree is never touched), runs mutmut
# on one worker (MUTATION_JOBS to change it), prints the score (killed / all mutants) and lists
# the surviving mutants with their diffs. mutmut is installed into .venv on first use; it is
# not a dependency of the project or of its test run. Never the node-graph tests.
# MUTATION_KEEP=1 keeps the scratch folder (removed at exit otherwise).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
py="$root/.venv/bin/python"
mutmut_version=3.8.1
if ! "$root/.venv/bin/mutmut" --version 2>/dev/null | grep -q "$mutmut_version"; then
    "$root/.venv/bin/pip" install -q "mutmut==$mutmut_version"
fi

# module -> "source file (package-relative)|test files (tests/-relative, space separated)"
declare -A table=(
    [monitor]='seft_ros/core/monitor.py|seft_ros/core/test_monitor.py seft_ros/core/test_findings.py'
    [controller]='seft_ros/core/controller.py|seft_ros/core/test_controller.py seft_ros/core/test_force_controllers.py seft_ros/core/test_tangent_loop_shaping.py'
    [reference_force]='seft_ros/core/reference_force.py|seft_ros/core/test_reference_force.py'
    [predictors]='seft_ros/core/predictors.py|seft_ros/core/test_predictors_closed_forms.py seft_ros/core/test_tangent_predictor.py seft_ros/core/test_hysteretic_predictor.py'
    [hysteresis]='seft_ros/core/hysteresis.py|seft_ros/core/test_hysteresis.py'
    [delay_rig]='seft_plant_sim/delay_rig.py|seft_plant_sim/test_delay_rig.py'
    [servohydraulic]='seft_plant_sim/servohydraulic.py|seft_plant_sim/test_servohydraulic.py seft_plant_sim/test_servohydraulic_loop.py'
    [metrics]='seft_ros/analysis/metrics.py|seft_ros/analysis/test_metrics.py seft_ros/analysis/test_metrics_definitions.py seft_ros/analysis/test_nonlinear_metrics.py'
)
modules=("$@")
[ ${#modules[@]} -gt 0 ] || modules=(monitor controller reference_force predictors hysteresis
                                     delay_rig servohydraulic metrics)

# one BLAS thread: with threads competing on a loaded machine scipy's expm took 34 ms a call
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
scratch="$(mktemp -d "${TMPDIR:-/tmp}/seft-mutation.XXXXXX")"
if [ -n "${MUTATION_KEEP:-}" ]; then
    echo "scratch kept: $scratch (mutmut's results; cd there and 'mutmut run NAME' reruns one)"
else
    trap 'rm -rf "$scratch"' EXIT
fi
declare -A scores
for name in "${modules[@]}"; do
    entry="${table[$name]:-}"
    [ -n "$entry" ] || { echo "unknown module '$name' (one of: ${!table[*]})" >&2; exit 2; }
    source_file="${entry%%|*}"
    read -r -a test_files <<< "${MUTATION_TESTS:-${entry#*|}}"
    work="$scratch/$name"
    mkdir -p "$work/src" "$work/tests"
    # the three packages flattened to src/<package> (mutmut imports its mutants from there,
    # ahead of the editable installs of the working tree)
    for pkg in seft_msgs_py seft_plant_sim seft_ros; do
        cp -r "$root/src/$pkg/$pkg" "$work/src/$pkg"
    done
    cp "$root/tests/conftest.py" "$work/tests/"
    selection=()
    for t in "${test_files[@]}"; do
        mkdir -p "$work/tests/$(dirname "$t")"
        cp "$root/tests/$t" "$work/tests/$t"
        selection+=("tests/$t")
    done
    {
        echo '[mutmut]'
        echo 'source_paths = src'
        echo "only_mutate = src/$source_file"
        # mutmut splits a list value at line breaks only: one test file (one argument) a line
        echo 'pytest_add_cli_args_test_selection ='
        printf '    %s\n' "${selection[@]}"
        printf 'pytest_add_cli_args =\n    -p\n    no:cacheprovider\n    -q\n'
    } > "$work/setup.cfg"
    echo "== $name: src/$source_file against ${test_files[*]}"
    (cd "$work" && "$root/.venv/bin/mutmut" run --max-children "${MUTATION_JOBS:-1}" \
        > "$work/run.log" 2>&1) || { tail -30 "$work/run.log"; exit 1; }
    (cd "$work" && "$root/.venv/bin/mutmut" results --all true > "$work/results.txt" 2>&1) || true
    total=$(grep -c ': ' "$work/results.txt" || true)
    killed=$(grep -c ': killed$' "$work/results.txt" || true)
    scores[$name]="$killed/$total"
    "$py" -c "import sys; k, n = map(int, sys.argv[1:]); print(f'score {k}/{n} = ' \
              f'{100 * k / n if n else 0:.1f} % killed')" "$killed" "$total"
    grep -v -E ': killed$' "$work/results.txt" | grep ': ' | while read -r line; do
        mutant="${line%%:*}"
        echo "-- survivor ${line}"
        # (a diff without such lines, or a failed show, must not end the listing: set -e)
        (cd "$work" && "$root/.venv/bin/mutmut" show "$mutant" 2>/dev/null \
            | grep -E '^[-+][^-+]') || true
    done
done
echo '== scores (killed/all mutants)'
for name in "${modules[@]}"; do
    echo "$name ${scores[$name]}"
done
