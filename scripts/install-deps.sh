#!/usr/bin/env bash
# Installs the Debian 12 packages planesdf builds against (clang-14 and its runtime with
# libFuzzer for the fuzz targets of scripts/run-fuzz.sh). Idempotent: when every package is
# already present it only runs dpkg-query and exits in well under a second.
set -euo pipefail

PKGS=(
  build-essential cmake pkg-config
  libeigen3-dev
  libopencv-core-dev libopencv-imgproc-dev libopencv-imgcodecs-dev
  libceres-dev
  libmrpt-maps-dev libmrpt-obs-dev libmrpt-poses-dev
  liboctomap-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  nlohmann-json3-dev libcli11-dev
  liblzf-dev
  clang-14 libclang-rt-14-dev
)

missing=()
for p in "${PKGS[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PKGS[@]} packages present"
  exit 0
fi

echo "install-deps: installing ${missing[*]}" >&2
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
