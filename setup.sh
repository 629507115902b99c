#!/usr/bin/env bash
# Set up reneus-mi on a fresh Debian/Ubuntu machine, then run the main job or the tests.
#
#   bash setup.sh [options]       install, then reconstruct the embedded demo (options go to
#                                 python -m reneus_mi.optimize, e.g. --iterations 100)
#   bash setup.sh test [options]  install (and Chromium and the glTF Validator, for the package's
#                                 tests), then run the test suite (options go to pytest)
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

mode=demo
case "${1:-}" in demo|test) mode=$1; shift ;; esac
if [ "$mode" = test ]; then
  # The report page is tested in a real browser (tests/commands/test_export.py).
  if ! command -v chromium >/dev/null 2>&1; then
    sudo=""; [ "$(id -u)" = 0 ] || sudo="sudo"
    echo "installing chromium (the report page's browser test)"
    $sudo apt-get update -qq
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  fi
  # The package's GLB files are checked by Khronos' glTF Validator (its npm build).
  if ! command -v npm >/dev/null 2>&1; then
    sudo=""; [ "$(id -u)" = 0 ] || sudo="sudo"
    echo "installing node (the glTF Validator's runtime)"
    $sudo apt-get update -qq
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq nodejs npm >/dev/null
  fi
  if [ ! -d .cache/gltf-validator/node_modules/gltf-validator ]; then
    echo "installing the glTF Validator into .cache/gltf-validator"
    npm install --silent --no-audit --no-fund --prefix .cache/gltf-validator gltf-validator@2.0.0-dev.3.10 >/dev/null
  fi
  exec python3 -m pytest -q "$@"
fi
exec python3 -m reneus_mi.optimize --demo "$@"
