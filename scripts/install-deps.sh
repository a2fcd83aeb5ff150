#!/usr/bin/env bash
# Installs arref's build and runtime dependencies from Debian 12 packages (run as root).
# Skips apt entirely when everything is already installed.
set -euo pipefail

PACKAGES=(
  cmake ninja-build g++ pkg-config ccache
  libeigen3-dev libspdlog-dev liburdfdom-dev libtinyxml-dev libassimp-dev libnanoflann-dev libtbb-dev
  libpcl-dev libembree-dev libopen3d-dev
  libboost-dev libprotobuf-dev protobuf-compiler libyaml-cpp-dev libsystemd-dev
  libssl-dev openssl  # TLS (server, mock headset); the tests make their throwaway CA with openssl
  libcli11-dev nlohmann-json3-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  gnuplot-nox
  libstb-dev python3-protobuf python3-numpy python3-open3d python3-pytest
  ros-core python3-rospy python3-tf2-ros python3-yaml
  clang libclang-rt-14-dev  # libFuzzer targets (scripts/fuzz.sh)
)

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]} == 0)); then
  echo "arref: all ${#PACKAGES[@]} Debian packages already installed"
  exit 0
fi

SUDO=""
if [[ $(id -u) -ne 0 ]]; then
  command -v sudo >/dev/null || { echo "arref: installing ${missing[*]} needs root (or sudo)" >&2; exit 1; }
  SUDO=sudo
fi
echo "arref: installing ${#missing[@]} Debian packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
