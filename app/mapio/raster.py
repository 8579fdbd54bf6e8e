"""Pixels to cells: images read with Pillow, pixels merged into coarser cells.

An image is opened (Pillow reads only its header: size and mode), its import's memory checked
against the budget (:mod:`app.mapio.budget`), and only then decoded, one band of rows at a time
into grey levels.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import cast

import numpy as np
from PIL import Image, UnidentifiedImageError

from app.arrays import BoolArray, ByteArray
from app.mapio import MapImportError, brief
from app.mapio.budget import BAND_PIXELS, MemoryBudget

#: Pillow's readers for the formats a map comes in (.png, .pgm/.ppm/.pbm, .bmp, .gif, .jpg,
#: .tif); no other is tried, whatever the file's name
PILLOW_FORMATS = ("PNG", "PPM", "BMP", "GIF", "JPEG", "TIFF")
#: modes read as 8-bit colour or grey (averaged to grey), with transparency, and as numbers
_PLAIN = ("1", "L", "P", "RGB", "CMYK", "YCbCr")
_ALPHA = ("RGBA", "LA", "PA")
_NUMERIC = ("I", "F", "I;16", "I;16L", "I;16B", "I;16N")


@contextmanager
def _pillow_limit(pixels: int | None) -> Iterator[None]:
    """Pillow's decompression-bomb limit set to ``pixels`` (``None``: off), its warning an
    error, put back afterwards."""
    saved = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = pixels
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            yield
    finally:
        Image.MAX_IMAGE_PIXELS = saved


def has_alpha(img: Image.Image) -> bool:
    return img.mode in _ALPHA or (img.mode == "P" and "transparency" in img.info)


def read_image(
    path: Path, budget: MemoryBudget, merge: int = 1
) -> tuple[ByteArray, BoolArray | None]:
    """The grey level (0 black .. 255 white) of every pixel, and which pixels are opaque
    (``None``: all of them).

    Colour is averaged to grey (as ROS map_server does); a pixel whose alpha is below 128 is
    transparent; 16-bit and float greys are scaled to 0..255. The image is refused before it is
    decoded if importing it at ``merge`` pixels a cell would take more than ``budget``."""
    try:
        # Only the header is read here; the budget, stricter than Pillow's limit and naming
        # the size, is checked before anything is decoded.
        with _pillow_limit(None):
            img = Image.open(path, formats=PILLOW_FORMATS)
    except UnidentifiedImageError:
        raise MapImportError(
            f"{path}: not an image that can be read (PNG, PGM/PPM, BMP, GIF, JPEG or TIFF)"
        ) from None
    except OSError as exc:
        raise MapImportError(f"{path}: cannot read the image: {brief(exc)}") from None
    except MemoryError:
        raise
    except Exception as exc:  # a header a reader chokes on: not an image we can read
        raise MapImportError(f"{path}: not an image that can be read ({brief(exc)})") from None
    with img:
        width, height = img.size
        mode = img.mode
        if mode not in _PLAIN + _ALPHA + _NUMERIC:
            raise MapImportError(
                f"{path}: image mode {mode!r} cannot be read as grey levels: save it as a "
                "grey, palette or RGB image"
            )
        if width < 1 or height < 1:
            raise MapImportError(f"{path}: the image has no pixels")
        alpha = has_alpha(img)
        budget.check_image(str(path), width, height, mode, merge, alpha)
        try:
            with _pillow_limit(budget.max_pixels):
                img.load()
                return _grey(img, alpha)
        except MemoryError:
            raise
        except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
            raise MapImportError(
                f"{path}: the image holds a frame larger than the memory budget of "
                f"{budget.limit >> 20} MiB allows ({brief(exc)}): raise it with --max-memory MIB"
            ) from None
        except Exception as exc:  # truncated or corrupt data, whatever the reader raises
            raise MapImportError(f"{path}: cannot decode the image: {brief(exc)}") from None


def _bands(img: Image.Image) -> Iterator[tuple[int, int, Image.Image]]:
    """Bands of whole rows, about :data:`BAND_PIXELS` pixels each: (first row, end, image)."""
    width, height = img.size
    rows = max(1, BAND_PIXELS // width)
    for top in range(0, height, rows):
        end = min(height, top + rows)
        yield top, end, img.crop((0, top, width, end))


def _grey(img: Image.Image, alpha: bool) -> tuple[ByteArray, BoolArray | None]:
    width, height = img.size
    grey = np.empty((height, width), dtype=np.uint8)
    opaque = np.empty((height, width), dtype=bool) if alpha else None
    if img.mode in _NUMERIC:  # 16-bit and float greys: scaled to 0..255
        high = float(cast(float, img.getextrema()[1]))  # one band: (lowest, highest)
        top = high if high > 0 else 1.0
        scale = 255.0 / max(top, 255.0)
        for a, b, band in _bands(img):
            values = np.asarray(band, dtype=np.float64) * scale
            grey[a:b] = np.clip(np.nan_to_num(values.round(), nan=0.0), 0, 255)
        return grey, None
    for a, b, band in _bands(img):
        if band.mode == "L":
            grey[a:b] = np.asarray(band)
            continue
        if band.mode == "1":
            grey[a:b] = np.asarray(band.convert("L"))
            continue
        rgb = np.asarray(band.convert("RGBA" if alpha else "RGB"))
        # the mean of three levels, rounded: (sum + 1) // 3 (a third is never a half)
        total = rgb[..., :3].sum(axis=2, dtype=np.uint16)
        grey[a:b] = (total + 1) // 3
        if opaque is not None:
            opaque[a:b] = rgb[..., 3] >= 128
    return grey, opaque


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
