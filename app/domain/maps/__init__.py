"""Shipped maps. ``default.txt`` is 30x30, start lower-left, 8 goals, loops (braid 0.2):
made by ``python -m app maze generate --rows 30 --cols 30 --braid 0.2 --seed 0``."""

from pathlib import Path

MAPS_DIR = Path(__file__).resolve().parent
DEFAULT_MAP = MAPS_DIR / "default.txt"
