#!/usr/bin/env bash
# The test command: installs missing system packages, then runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."
# The operator view's end-to-end test runs in Debian's headless Chromium.
LFI_WITH_BROWSER=1 LFI_WITH_PYTHON=1 scripts/deps.sh
# Python's asyncua (PyPI), the independent OPC UA client tests/opcua.rs drives, in a venv beside
# the build. Without the network the interop test says "NOT RUN" instead of failing the suite.
venv="${CARGO_TARGET_DIR:-target}/asyncua-venv"
if ! "$venv/bin/python" -c "import asyncua" >/dev/null 2>&1; then
  mkdir -p "$(dirname "$venv")"
  (python3 -m venv "$venv" && timeout 300 "$venv/bin/pip" install -q --disable-pip-version-check "asyncua==2.1.0") >/dev/null 2>&1 ||
    echo "asyncua could not be installed in $venv: the OPC UA interop test will not run" >&2
fi
if "$venv/bin/python" -c "import asyncua" >/dev/null 2>&1; then
  LFI_ASYNCUA_PYTHON="$(cd "$venv" && pwd)/bin/python"
  export LFI_ASYNCUA_PYTHON
fi
cargo test --all-targets "$@"
