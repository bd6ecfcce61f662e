#!/usr/bin/env bash
# Sets everything up (scripts/setup.sh), installs the example estimator package, and runs the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# Debian's chromium and its driver for the test of the HTML benchmark report in a real browser
# (tests/test_report_html.py, skipped without them)
if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    { apt-get update -qq && apt-get install -y -qq chromium chromium-driver >/dev/null; } \
        || echo "test: could not install chromium and chromium-driver; the browser test will be skipped" >&2
fi
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
