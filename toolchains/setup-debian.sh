#!/usr/bin/env bash
# Installs every build and test dependency of octofuse from Debian's archive (Debian 12).
# Idempotent: when every package is already installed, apt is not touched at all.
set -euo pipefail

packages=(
  # host toolchain and build tools
  build-essential cmake ninja-build pkg-config ccache git
  # library and test dependencies
  libeigen3-dev catch2
  # port dependencies (replay: libpng; live cameras: OpenNI2, libcamera, V4L2)
  libpng-dev libopenni2-dev libcamera-dev libv4l-dev
  # robot recordings (MCAP chunks) and the independent bag writer the tests use
  libzstd-dev liblz4-dev python3-zstandard python3-lz4
  # ROS 1 bags (bz2 chunks) and ROS 1's own bag writer, which the tests make fixtures with
  libbz2-dev python3-rosbag python3-roslz4
  # cross compilers for ARM boards and qemu-user to run the tests
  g++-aarch64-linux-gnu g++-arm-linux-gnueabihf
  libgcc-12-dev-arm64-cross libgcc-12-dev-armhf-cross
  qemu-user
  # fuzzing (libFuzzer from clang 14) and memory checks
  clang lld libclang-rt-14-dev valgrind
  # the live view's check in a real headless browser (test/checks/live_view_browser.sh)
  chromium
)

missing=()
for package in "${packages[@]}"; do
  status=$(dpkg-query -W -f='${Status}' "${package}" 2>/dev/null || true)
  if [[ "${status}" != "install ok installed" ]]; then
    missing+=("${package}")
  fi
done

if [[ ${#missing[@]} -eq 0 ]]; then
  echo "setup-debian: all ${#packages[@]} packages already installed"
  exit 0
fi

sudo_cmd=()
if [[ $(id -u) -ne 0 ]]; then
  sudo_cmd=(sudo)
fi

echo "setup-debian: installing ${missing[*]}"
"${sudo_cmd[@]}" apt-get update
"${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
  "${missing[@]}"
