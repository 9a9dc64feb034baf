"""Find a Vulkan device SAPIEN accepts before the first scene, and fail clearly without one.

On a machine without a GPU that is Mesa 25 lavapipe unpacked by scripts/setup-vulkan.sh into
.vk/ (or $SMSPACE_VK_DIR); with a GPU, its own driver. Must run before sapien is imported.
"""

from __future__ import annotations

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
