"""Find a Vulkan device SAPIEN accepts before the first scene, and fail clearly without one.

On a machine without a GPU that is Mesa 25 lavapipe unpacked by scripts/setup-vulkan.sh into
.vk/ (or $SMSPACE_VK_DIR); with a GPU, its own driver. Must run before sapien is imported.
"""

from __future__ import annotations

import gzip
import os
from pathlib import Path

from smspace.common.errors import SmspaceError

REPO = Path(__file__).resolve().parents[3]
INSTALL_HINT = (
    "run `bash scripts/setup-vulkan.sh` (Mesa 25 lavapipe from Debian bookworm-backports; "
    "Debian 12's own Mesa 22 is rejected by SAPIEN) or install your GPU's Vulkan driver"
)
_checked = False


def lavapipe_icd() -> Path | None:
    folder = Path(os.environ.get("SMSPACE_VK_DIR", REPO / ".vk"))
    icd = folder / "lvp_icd.json"
    return icd if icd.exists() else None


def has_nvidia_gpu() -> bool:
    return Path("/proc/driver/nvidia/version").exists()


def configure_environment() -> None:
    """Point the Vulkan loader at lavapipe unless the user or a GPU decides otherwise."""
    # One raster thread per process: worker processes already use every core, and lavapipe's own
    # threads would oversubscribe them (measured here: 2 processes gave 2682–3239 renders/s with
    # LP_NUM_THREADS=0 against a median of 2355 with the default).
    os.environ.setdefault("LP_NUM_THREADS", "0")
    if "VK_ICD_FILENAMES" in os.environ or "VK_DRIVER_FILES" in os.environ or has_nvidia_gpu():
        return
    icd = lavapipe_icd()
    if icd is not None:
        os.environ["VK_ICD_FILENAMES"] = str(icd)


def require_render_device() -> None:
    """Import sapien with the right environment and check it can render; once per process."""
    global _checked
    if _checked:
        return
    configure_environment()
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "Failed to find system libvulkan": we report it below
        try:
            import sapien
        except ImportError as e:
            raise SmspaceError(f"SAPIEN is not installed ({e}); run `bash scripts/setup.sh`") from e
        try:
            sapien.render.RenderSystem()
        except RuntimeError as e:
            raise SmspaceError(f"no usable Vulkan device for SAPIEN ({e}): {INSTALL_HINT}") from e
    _checked = True


def render_provenance() -> dict[str, str]:
    """What rendered the pixels: SAPIEN, the Vulkan device, and its driver (lavapipe's Mesa
    version, or NVIDIA's kernel driver)."""
    require_render_device()
    import sapien

    summary = sapien.render.get_device_summary()
    device = next((ln.split(":", 1)[1].strip() for ln in summary.splitlines() if ln.startswith("GPU:")), "unknown")
    return {"sapien": sapien.__version__, "vulkan_device": device, "vulkan_driver": _driver()}


def _driver() -> str:
    icd = os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES") or ""
    ours = lavapipe_icd()
    if ours is not None and icd == str(ours):
        changelog = ours.parent / "tree/usr/share/doc/mesa-vulkan-drivers/changelog.Debian.gz"
        try:
            with gzip.open(changelog, "rt") as fh:
                first = fh.readline()  # mesa (25.0.7-2~bpo12+1) bookworm-backports; urgency=medium
            return f"lavapipe, Mesa {first.split('(', 1)[1].split(')', 1)[0]}"
        except (OSError, IndexError):
            return "lavapipe, Mesa (version unknown)"
    if has_nvidia_gpu():
        try:
            return Path("/proc/driver/nvidia/version").read_text().splitlines()[0].strip()
        except (OSError, IndexError):
            return "NVIDIA (version unknown)"
    return f"the system's Vulkan driver ({icd or 'found by the Vulkan loader'})"
