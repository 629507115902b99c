#!/usr/bin/env bash
# Set up reneus-mi on a fresh Debian/Ubuntu machine, then run the main job or the tests.
#
#   bash setup.sh          install, then reconstruct the embedded demo (a few minutes on a CPU)
#   bash setup.sh test     install, then run the test suite
#
# Dr.Jit's CPU backend needs libLLVM >= 16 (Debian 12 ships 14/15, with which
# every kernel aborts with "LLVM ERROR: Cannot select ... fminimum").
set -euo pipefail
cd "$(dirname "$0")"

have_llvm() {
  ldconfig -p 2>/dev/null | grep -qE 'libLLVM(-|\.so\.)(1[6-9]|[2-9][0-9])'
}
if ! have_llvm; then
  sudo=""; [ "$(id -u)" = 0 ] || sudo="sudo"
  echo "installing libllvm19 (Dr.Jit's CPU backend needs libLLVM >= 16)"
  $sudo apt-get update -qq
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
fi
python3 -m pip install -q --disable-pip-version-check -e '.[test]'

case "${1:-demo}" in
  demo) shift || true; exec python3 -m reneus_mi.optimize --demo "$@" ;;
  test) shift; exec python3 -m pytest -q "$@" ;;
  *) echo "usage: bash setup.sh [demo|test] [options]" >&2; exit 2 ;;
esac
