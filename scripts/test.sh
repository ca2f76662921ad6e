#!/usr/bin/env bash
# The test command: installs missing system packages, then runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."
# The operator view's end-to-end test runs in Debian's headless Chromium.
LFI_WITH_BROWSER=1 scripts/deps.sh
cargo test --all-targets "$@"
