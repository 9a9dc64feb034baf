#!/usr/bin/env bash
# A Vulkan device SAPIEN 3 accepts on a machine without a GPU: Mesa 25 lavapipe from Debian's
# bookworm-backports, unpacked into .vk/ (project-owned; nothing system-wide changes beyond the
# base packages). Debian 12's own Mesa 22 lavapipe lacks descriptorBindingPartiallyBound and SAPIEN
# rejects it with a bare "failed to find a rendering device". The lavapipe package is unpacked, not installed, so the system Mesa stays as it is.
# Writes .vk/env.sh, which smspace reads to find the driver. Idempotent.
# Usage: bash scripts/setup-vulkan.sh      (as root, or with sudo available)
set -euo pipefail
cd "$(dirname "$0")/.."
VK="$(pwd)/.vk"

if [ -f "$VK/lvp_icd.json" ] && [ -f "$VK/tree/usr/lib/x86_64-linux-gnu/libvulkan_lvp.so" ]; then
  echo "lavapipe already in $VK"; exit 0
fi
if [ -e /proc/driver/nvidia/version ] && [ -z "${SMSPACE_FORCE_LAVAPIPE:-}" ]; then
  echo "an NVIDIA driver is present: SAPIEN will use it (set SMSPACE_FORCE_LAVAPIPE=1 to unpack lavapipe anyway)"; exit 0
fi
SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"

# Base packages: the Vulkan loader and every shared library lavapipe links against.
if ! dpkg -s libvulkan1 mesa-vulkan-drivers >/dev/null 2>&1; then
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends libvulkan1 mesa-vulkan-drivers >/dev/null
fi

mkdir -p "$VK/apt/lists/partial" "$VK/apt/cache/archives/partial" "$VK/debs"
MIRROR=$(awk '/^URIs:/{print $2; exit}' /etc/apt/sources.list.d/debian.sources 2>/dev/null || true)
MIRROR=${MIRROR:-http://deb.debian.org/debian}
echo "deb $MIRROR bookworm-backports main" > "$VK/apt/sources.list"
APT=(-o "Dir::Etc::SourceList=$VK/apt/sources.list" -o Dir::Etc::SourceParts=/nonexistent
     -o "Dir::State::Lists=$VK/apt/lists" -o "Dir::Cache=$VK/apt/cache" -o APT::Sandbox::User=root)
apt-get "${APT[@]}" update -qq
(cd "$VK/debs" && apt-get "${APT[@]}" download -qq mesa-vulkan-drivers libdrm2 libdrm-amdgpu1)
rm -rf "$VK/tree"
for d in "$VK"/debs/*.deb; do dpkg-deb -x "$d" "$VK/tree"; done
LIB="$VK/tree/usr/lib/x86_64-linux-gnu"
cat > "$VK/lvp_icd.json" <<JSON
{"file_format_version": "1.0.1",
 "ICD": {"library_path": "$LIB/libvulkan_lvp.so", "library_arch": "64", "api_version": "1.4.305"}}
JSON
rm -rf "$VK/apt" "$VK/debs"
echo "Mesa lavapipe from bookworm-backports unpacked in $VK"
