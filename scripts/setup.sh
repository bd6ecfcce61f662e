#!/usr/bin/env bash
# Sets up thinfilm on a fresh Debian machine (run as root from the repository root):
# Debian's libllvm19 for Mitsuba's llvm_* variants, a virtual environment in .venv, and the
# package with all its extras ([all]: cluster, import, docs and test; see pyproject.toml).
# Safe to run again: it only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! ls /usr/lib/*/libLLVM*.so.19* /usr/lib/*/libLLVM-19.so >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq libllvm19 >/dev/null
fi

if [ ! -x .venv/bin/python ]; then
    if ! python3 -m venv --help >/dev/null 2>&1; then
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
    fi
    python3 -m venv .venv
fi
.venv/bin/python -m pip install -q --disable-pip-version-check -e '.[all]' 2>&1 \
    | grep -v -e "^WARNING: Location" || true
.venv/bin/python -c "import thinfilm.bsdf, mitsuba as mi; mi.set_variant('llvm_ad_mono_polarized'); import drjit as dr; dr.eval(dr.llvm.Float([1.0]) + 1)" \
    || { echo "setup: Mitsuba's llvm variants do not run (is libllvm19 installed?)" >&2; exit 1; }
echo "setup: ready (.venv)"
