#!/usr/bin/env bash
# System packages on a CPU-only Debian 12 (bookworm) machine:
# - the simulator: SAPIEN renders through Vulkan, and bookworm's own lavapipe (Mesa 22) lacks
#   descriptorBindingPartiallyBound, so Mesa 25's lavapipe comes from Debian's bookworm-backports suite, added to
#   the machine's existing Debian apt source (its mirror is kept);
# - Meta-World's cameras: MuJoCo renders through headless OpenGL, Mesa's EGL (llvmpipe), from the same Mesa;
# - RealSense cameras: pyrealsense2 loads libusb-1.0 (Debian's libusb-1.0-0);
# - video decoding: torchcodec, LeRobot's default decoder (stock tools such as lerobot-dataset-viz use it), loads
#   FFmpeg's shared libraries (bookworm's FFmpeg 5.1).
# Idempotent; run as root (or with sudo available).
set -euo pipefail

SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
SOURCES=/etc/apt/sources.list.d/debian.sources

lavapipe_ok() {
    # Mesa >= 24's lavapipe ICD installed?
    local version
    version=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
    [ -n "$version" ] && dpkg --compare-versions "$version" ge 24 && dpkg-query -W libvulkan1 >/dev/null 2>&1
}

installed() {
    local package
    for package in "$@"; do
        dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" || return 1
    done
}

FFMPEG_LIBS="libavutil57 libavcodec59 libavformat59 libavdevice59 libavfilter8 libswscale6 libswresample4"

EGL_PACKAGES="libegl1 libegl-mesa0 libgl1-mesa-dri"

if lavapipe_ok && installed $EGL_PACKAGES libusb-1.0-0 $FFMPEG_LIBS; then
    echo "setup_system: Mesa lavapipe $(dpkg-query -W -f='${Version}' mesa-vulkan-drivers), Mesa's EGL, libusb-1.0-0 and FFmpeg's libraries already installed"
    exit 0
fi
export DEBIAN_FRONTEND=noninteractive

if ! lavapipe_ok || ! installed $EGL_PACKAGES; then
    if [ ! -f "$SOURCES" ]; then
        echo "setup_system: $SOURCES not found. Add Debian's bookworm-backports suite to your apt sources, then run:" >&2
        echo "  apt-get update && apt-get install -y -t bookworm-backports mesa-vulkan-drivers libvulkan1 $EGL_PACKAGES" >&2
        exit 1
    fi
    if ! grep -q "bookworm-backports" "$SOURCES"; then
        # Append the suite to the Suites line of the main Debian entry (the one listing bookworm-updates).
        $SUDO sed -i '0,/^Suites:.*bookworm-updates.*$/s//& bookworm-backports/' "$SOURCES"
    fi
    $SUDO apt-get update -qq
    # shellcheck disable=SC2086
    $SUDO apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 $EGL_PACKAGES >/dev/null
    echo "setup_system: installed Mesa lavapipe and EGL $(dpkg-query -W -f='${Version}' mesa-vulkan-drivers)"
fi
if ! installed libusb-1.0-0 $FFMPEG_LIBS; then
    $SUDO apt-get update -qq
    # shellcheck disable=SC2086
    $SUDO apt-get install -y -qq libusb-1.0-0 $FFMPEG_LIBS >/dev/null
    echo "setup_system: installed libusb-1.0-0 and FFmpeg's libraries"
fi
