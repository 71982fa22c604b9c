#!/usr/bin/env bash
# Installs what fogcast needs at run time on a machine without a GPU:
# Mesa's software Vulkan driver (lavapipe). Mesa 25 from bookworm-backports
# traces shadow rays ~3.5x faster than bookworm's Mesa 22 (DESIGN.md §8).
set -euo pipefail

have_vulkan() {
  ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1 || ls /etc/vulkan/icd.d/*.json >/dev/null 2>&1
}

if have_vulkan && [ -e /usr/lib/x86_64-linux-gnu/libvulkan.so.1 ] || have_vulkan && ldconfig -p 2>/dev/null | grep -q libvulkan.so.1; then
  echo "deps: a Vulkan driver is present ($(ls /usr/share/vulkan/icd.d/ /etc/vulkan/icd.d/ 2>/dev/null | tr '\n' ' '))"
  exit 0
fi

if [ "$(id -u)" != 0 ]; then
  echo "deps: no Vulkan driver found. Install Mesa's lavapipe as root:" >&2
  echo "  sudo apt-get update && sudo apt-get install -y mesa-vulkan-drivers libvulkan1" >&2
  exit 1
fi

export DEBIAN_FRONTEND=noninteractive
src=/etc/apt/sources.list.d/debian.sources
backports=/etc/apt/sources.list.d/fogcast-backports.sources
if grep -q bookworm /etc/os-release 2>/dev/null && [ ! -f "$backports" ]; then
  uri=$(awk '/^URIs:/ {print $2; exit}' "$src" 2>/dev/null || true)
  uri=${uri:-http://deb.debian.org/debian}
  printf 'Types: deb\nURIs: %s\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' "$uri" > "$backports"
fi
echo "deps: installing Mesa's software Vulkan driver (lavapipe)"
apt-get update -qq
if [ -f "$backports" ]; then
  apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
else
  apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
fi
echo "deps: installed $(dpkg-query -W -f='${Package} ${Version}' mesa-vulkan-drivers)"
