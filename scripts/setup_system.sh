#!/usr/bin/env bash
# Install the Debian packages jointseg needs (open3d's shared libraries; chromium for the browser
# tests of web/, Debian's own build: never a downloaded browser). Safe to run again: it installs
# only what is missing.
set -euo pipefail
packages=(libusb-1.0-0 libgl1 libegl1 libgomp1 libglib2.0-0 chromium)
missing=()
for p in "${packages[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ "${#missing[@]}" -eq 0 ]; then
  exit 0
fi
sudo_cmd=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "need root to install: ${missing[*]}" >&2; exit 1; }
  sudo_cmd="sudo"
fi
echo "installing system packages: ${missing[*]}"
$sudo_cmd apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}"
