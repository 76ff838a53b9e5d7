"""Stage-2 weights shipped with the package; the model card (README.md here) says how they were trained."""

from __future__ import annotations

from pathlib import Path

WEIGHTS_DIR = Path(__file__).resolve().parent
DEFAULT_WEIGHTS_NAME = "pass3d_lite.pt"
DEFAULT_WEIGHTS = WEIGHTS_DIR / DEFAULT_WEIGHTS_NAME


def default_weights() -> Path:
    """Path of the default (`lite`) weights; a clear error when the package was installed without them."""
    path = DEFAULT_WEIGHTS
    if not path.is_file():
        raise FileNotFoundError(f"shipped stage-2 weights missing: {path} (train them with pass3d_train)")
    return path
