#!/usr/bin/env bash
# Installs the Debian packages lfi-bridge needs, when they are missing (Debian 12 and later).
# Safe to run repeatedly: it only calls apt-get when something is absent.
set -euo pipefail

need=()
pkg-config --exists opencv4 2>/dev/null || need+=(libopencv-dev)
command -v clang >/dev/null 2>&1 || need+=(clang)
# The opencv crate's binding generator loads libclang at build time.
ls /usr/lib/llvm-*/lib/libclang.so* >/dev/null 2>&1 || ls /usr/lib/x86_64-linux-gnu/libclang-*.so* >/dev/null 2>&1 || need+=(libclang-dev)
command -v pkg-config >/dev/null 2>&1 || need+=(pkg-config)
# GigE Vision / USB3 Vision cameras; Debian's aravis-0.8.pc requires libusb-1.0's .pc, which
# libaravis-dev does not pull in. aravis-tools has the fake GigE camera the tests talk to.
pkg-config --exists aravis-0.8 2>/dev/null || need+=(libaravis-dev libusb-1.0-0-dev)
command -v arv-fake-gv-camera-0.8 >/dev/null 2>&1 || need+=(aravis-tools)
command -v arv-tool-0.8 >/dev/null 2>&1 || need+=(aravis-tools-cli)
# Python's venv, for asyncua (PyPI), the independent OPC UA client of the tests.
if [ "${LFI_WITH_PYTHON:-0}" = 1 ]; then
  command -v python3 >/dev/null 2>&1 || need+=(python3)
  python3 -c "import ensurepip, venv" >/dev/null 2>&1 || need+=(python3-venv)
fi
if [ "${LFI_WITH_BROWSER:-0}" = 1 ]; then
  command -v chromium >/dev/null 2>&1 || need+=(chromium)
  command -v chromedriver >/dev/null 2>&1 || need+=(chromium-driver)
fi

if [ ${#need[@]} -gt 0 ]; then
  echo "installing system packages: ${need[*]}" >&2
  sudo=""
  [ "$(id -u)" = 0 ] || sudo="sudo"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${need[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "cargo not found: install Rust (https://rustup.rs) and run this again" >&2
  exit 1
fi
