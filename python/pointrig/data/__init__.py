"""Bundled sample data."""

from __future__ import annotations

from pathlib import Path

__all__ = ["demo_path"]


def demo_path() -> Path:
    """Folder of the bundled demo sequence (``frames/`` and ``gt.npz``)."""
    return Path(__file__).resolve().parent / "demo"
