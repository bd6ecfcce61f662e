#!/usr/bin/env bash
# Sets everything up (scripts/setup.sh), installs the example estimator package, and runs the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# The example third-party estimator (examples/estimator_plugin): the tests list, run and
# benchmark it through the entry-point group thinfilm.estimators.
.venv/bin/python -m pip install -q --disable-pip-version-check --no-deps --force-reinstall \
    examples/estimator_plugin 2>&1 | grep -v -e "^WARNING: Location" || true
set +e
.venv/bin/python -m pytest -q "$@"
rc=$?
set -e
if [ "$rc" -eq 5 ]; then
    echo "no tests were collected" >&2
fi
exit "$rc"
