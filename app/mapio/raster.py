"""Pixels to cells: images read with Pillow, pixels merged into coarser cells."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
from PIL import Image, UnidentifiedImageError

from app.arrays import BoolArray
from app.mapio import MapImportError

#: images larger than this many pixels are refused (a 20,000 x 20,000 map at 5 cm is 1 km wide)
MAX_PIXELS = 400_000_000


def read_image(path: Path) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
    """The grey level (0 black .. 255 white) of every pixel, and which pixels are opaque.

    Colour is averaged to grey (as ROS map_server does); a pixel whose alpha is below 128 is
    transparent."""
    Image.MAX_IMAGE_PIXELS = MAX_PIXELS
    try:
        with Image.open(path) as img:
            img.load()
            if img.mode in ("RGBA", "LA", "PA") or (img.mode == "P" and "transparency" in img.info):
                rgba = np.asarray(img.convert("RGBA"))
                grey = rgba[..., :3].mean(axis=2).round().astype(np.uint8)
                return grey, rgba[..., 3] >= 128
            if img.mode in ("L", "1", "P", "RGB", "CMYK", "YCbCr"):
                rgb = np.asarray(img.convert("RGB"))
                grey = rgb.mean(axis=2).round().astype(np.uint8)
            else:  # 16-bit and float greys: scaled to 0..255
                values = np.asarray(img, dtype=np.float64)
                top = values.max() if values.size and values.max() > 0 else 1.0
                grey = (values * (255.0 / max(top, 255.0))).round().astype(np.uint8)
    except (UnidentifiedImageError, Image.DecompressionBombError) as exc:
        raise MapImportError(f"{path}: not an image that can be read ({exc})") from None
    except OSError as exc:
        raise MapImportError(f"{path}: cannot read the image: {exc}") from None
    if grey.ndim != 2 or grey.size == 0:
        raise MapImportError(f"{path}: the image has no pixels")
    return grey, np.ones(grey.shape, dtype=bool)


def merge_cells(free: BoolArray, blocked: BoolArray, k: int) -> BoolArray:
    """Cells of ``k`` x ``k`` pixels, aligned to the lower-left pixel (the map's origin): a
    cell is free when none of its pixels is blocked and at least half of them are free.
    Pixels beyond the image (top rows, right columns of a partial cell) count as neither."""
    if k == 1:
        return free & ~blocked
    h, w = free.shape
    rows, cols = -(-h // k), -(-w // k)
    pad = ((rows * k - h, 0), (0, cols * k - w))
    f = np.pad(free, pad).reshape(rows, k, cols, k)
    b = np.pad(blocked, pad).reshape(rows, k, cols, k)
    out: BoolArray = ~b.any(axis=(1, 3)) & (2 * f.sum(axis=(1, 3)) >= k * k)
    return out
