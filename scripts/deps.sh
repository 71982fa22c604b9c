#!/usr/bin/env bash
# Installs what fogcast needs on a machine without a GPU.
#   deps.sh runtime   Mesa's software Vulkan driver (lavapipe) and DejaVu Sans (plot
#                     labels): enough to render, evaluate and serve.
#   deps.sh [all]     runtime + Debian's Chromium and ChromeDriver for the browser test.
# Mesa 25 from bookworm-backports traces shadow rays ~3.5x faster than bookworm's
# Mesa 22 (DESIGN.md §8).
set -euo pipefail

what=${1:-all}
case "$what" in
  runtime | all) ;;
  *)
    echo "usage: $0 [runtime|all]" >&2
    exit 2
    ;;
esac

have_vulkan() {
  { ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1 || ls /etc/vulkan/icd.d/*.json >/dev/null 2>&1; } &&
    { [ -e /usr/lib/x86_64-linux-gnu/libvulkan.so.1 ] || ldconfig -p 2>/dev/null | grep -q libvulkan.so.1; }
}

have_chromium() {
  command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1
}

apt_updated=0
apt_update() {
  if [ "$apt_updated" = 0 ]; then
    apt-get update -qq
    apt_updated=1
  fi
}

install_vulkan() {
  if have_vulkan; then
    echo "deps: a Vulkan driver is present ($(ls /usr/share/vulkan/icd.d/ /etc/vulkan/icd.d/ 2>/dev/null | tr '\n' ' '))"
    return 0
  fi
  if [ "$(id -u)" != 0 ]; then
    echo "deps: no Vulkan driver found. Install Mesa's lavapipe as root:" >&2
    echo "  sudo apt-get update && sudo apt-get install -y mesa-vulkan-drivers libvulkan1" >&2
    return 1
  fi
  export DEBIAN_FRONTEND=noninteractive
  local src=/etc/apt/sources.list.d/debian.sources
  local backports=/etc/apt/sources.list.d/fogcast-backports.sources
  if grep -q bookworm /etc/os-release 2>/dev/null && [ ! -f "$backports" ]; then
    local uri
    uri=$(awk '/^URIs:/ {print $2; exit}' "$src" 2>/dev/null || true)
    uri=${uri:-http://deb.debian.org/debian}
    printf 'Types: deb\nURIs: %s\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' "$uri" >"$backports"
  fi
  echo "deps: installing Mesa's software Vulkan driver (lavapipe)"
  apt_update
  if [ -f "$backports" ]; then
    apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
  else
    apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
  fi
  echo "deps: installed $(dpkg-query -W -f='${Package} ${Version}' mesa-vulkan-drivers)"
}

# The browser test (tests/browser_client.rs) drives Debian's Chromium headless.
install_chromium() {
  if have_chromium; then
    echo "deps: $(chromium --version 2>/dev/null | head -n1) and chromedriver are present"
    return 0
  fi
  if [ "$(id -u)" != 0 ]; then
    echo "deps: Chromium is missing (needed by the browser test). Install it as root:" >&2
    echo "  sudo apt-get update && sudo apt-get install -y chromium chromium-driver" >&2
    return 1
  fi
  export DEBIAN_FRONTEND=noninteractive
  echo "deps: installing Debian's chromium and chromium-driver"
  apt_update
  apt-get install -y -qq chromium chromium-driver >/dev/null
  echo "deps: installed $(dpkg-query -W -f='${Package} ${Version}' chromium)"
}

# Plot labels (fogcast eval/bench) are drawn with DejaVu Sans loaded at run time.
install_fonts() {
  if [ -e /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ]; then
    echo "deps: DejaVu Sans is present"
    return 0
  fi
  if [ "$(id -u)" != 0 ]; then
    echo "deps: DejaVu Sans is missing (plot labels). Install it as root:" >&2
    echo "  sudo apt-get update && sudo apt-get install -y fonts-dejavu-core" >&2
    return 1
  fi
  export DEBIAN_FRONTEND=noninteractive
  echo "deps: installing fonts-dejavu-core"
  apt_update
  apt-get install -y -qq fonts-dejavu-core >/dev/null
}

install_vulkan
install_fonts
if [ "$what" = all ]; then
  install_chromium
fi
