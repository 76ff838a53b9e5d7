"""Stage-2 weights shipped with the package; the model card (README.md here) says how they were trained."""

from __future__ import annotations

from pathlib import Path

WEIGHTS_DIR = Path(__file__).resolve().parent
DEFAULT_WEIGHTS_NAME = "pass3d_lite.pt"
DEFAULT_WEIGHTS = WEIGHTS_DIR / DEFAULT_WEIGHTS_NAME

