#!/usr/bin/env bash
# The demo: installs missing system packages, builds, and runs the appliance on the built-in
# simulated camera (config/demo.toml): PLC registers on 127.0.0.1:1502 until Ctrl-C.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/deps.sh
cargo build --bin lfi-bridge
cat >&2 <<'HINT'
lfi-bridge demo: a simulated camera behind Modbus/TCP on 127.0.0.1:1502 (unit id 1).
From another terminal (Debian package mbpoll; register numbers are 1-based, address + 1):
  mbpoll -m tcp -p 1502 -a 1 -r 101 -c 10 -1 127.0.0.1      # STATUS .. TYPES_ENROLLED
  mbpoll -m tcp -p 1502 -a 1 -r 1 -1 127.0.0.1 1            # TRIGGER = 1
  mbpoll -m tcp -p 1502 -a 1 -r 201 -c 19 -1 127.0.0.1      # the result block
  mbpoll -m tcp -p 1502 -a 1 -r 1 -1 127.0.0.1 0            # TRIGGER = 0
  mbpoll -m tcp -p 1502 -a 1 -r 2 -1 127.0.0.1 <RESULT_SEQ> # RESULT_ACK: next result
Operator view: http://127.0.0.1:8080/ ; its controls and enrolment take the token "demo-token"
(config/demo.toml, [http] token), typed into the page's token field.
HINT
exec target/debug/lfi-bridge run --config config/demo.toml "$@"
