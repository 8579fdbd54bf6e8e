"""An IMDF archive's files, from a folder or a .zip, read within bounds.

Only the files the reader uses are read (:data:`FILES`), each from the folder holding
``manifest.json``. Nothing is extracted to disk. A zip is refused, before anything is
decompressed:

* when its end record says it lists more than :data:`MAX_ENTRIES` members or a central
  directory over :data:`MAX_DIRECTORY_BYTES` (an IMDF archive holds some 16 files), or is a
  zip64 archive;
* when any member's name is absolute or climbs out with ``..`` (whether or not it is read);
* when a member it reads is encrypted, declares more than :data:`MAX_FILE_BYTES`, or is
  compressed more than :data:`MAX_RATIO` to 1 (past 1 MiB): a zip bomb's shape.

A member is read up to its declared size plus one byte, so a member whose data is longer than
its header says is refused too (zipfile's CRC check, or the length). In a folder, a file that is
a link to a place outside the folder is refused with one message, whether or not that place
exists.
"""

from __future__ import annotations

import lzma
import os
import posixpath
import struct
import zipfile
import zlib
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from app.mapio import MapImportError, brief, shorten

#: the files read, by their IMDF names (the rest of an archive is left alone)
FILES = (
    "manifest.json",
    "venue.geojson",
    "level.geojson",
    "unit.geojson",
    "opening.geojson",
    "relationship.geojson",
    "anchor.geojson",
    "occupant.geojson",
    "amenity.geojson",
)
REQUIRED = ("manifest.json", "venue.geojson", "level.geojson", "unit.geojson")

MAX_ENTRIES = 1000
MAX_DIRECTORY_BYTES = 1 << 20
#: the largest file read (the budget is usually smaller: :mod:`app.mapio.budget`)
MAX_FILE_BYTES = 1 << 30
MAX_RATIO = 200
_RATIO_FROM = 1 << 20

_EOCD = b"PK\x05\x06"
_EOCD_SIZE = 22


@dataclass
class Archive:
    """The files of :data:`FILES` an archive holds: their sizes, and a way to read each."""

    where: str
    sizes: dict[str, int]
    _zip: zipfile.ZipFile | None = None
    _members: dict[str, zipfile.ZipInfo] = field(default_factory=dict)
    _folder: Path | None = None

    def read(self, name: str) -> bytes:
        where = f"{self.where}: {name}"
        size = self.sizes[name]
        try:
            if self._zip is not None:
                with self._zip.open(self._members[name]) as f:
                    data = f.read(size + 1)
            else:
                assert self._folder is not None
                with (self._folder / name).open("rb") as f:
                    data = f.read(size + 1)
        except (
            zipfile.BadZipFile,
            zipfile.LargeZipFile,
            EOFError,
            zlib.error,
            lzma.LZMAError,
        ) as exc:
            raise MapImportError(f"{where}: the archive is damaged: {brief(exc)}") from None
        except (NotImplementedError, RuntimeError) as exc:  # compression method, encryption
            raise MapImportError(f"{where}: cannot be read: {brief(exc)}") from None
        except OSError as exc:
            raise MapImportError(f"{where}: cannot read: {brief(exc.strerror or exc)}") from None
        if len(data) != size:
            raise MapImportError(
                f"{where}: holds more or fewer bytes than the archive says ({size:,}): not read"
            )
        return data


@contextmanager
def open_archive(path: Path) -> Iterator[Archive]:
    """The archive at ``path``: a folder, or a zip file."""
    where = str(path)
    try:
        is_dir, is_file = path.is_dir(), path.is_file()
    except (OSError, ValueError):
        is_dir = is_file = False
    if is_dir:
        yield _folder(path)
        return
    if not is_file:
        raise MapImportError(f"{where}: no such file or folder")
    try:
        f = path.open("rb")
    except OSError as exc:
        raise MapImportError(f"{where}: cannot read: {brief(exc.strerror or exc)}") from None
    with f:
        _check_end_record(f, where)
        try:
            zf = zipfile.ZipFile(f)
        # a damaged directory: bad signatures, offsets before the file's start (EINVAL), a
        # version of the format zipfile does not read, names that are not UTF-8 as flagged
        except (zipfile.BadZipFile, NotImplementedError, EOFError, OSError, ValueError) as exc:
            text = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            raise MapImportError(f"{where}: not a zip archive ({brief(text, 80)})") from None
        with zf:
            yield _zipped(zf, where)


def _check_end_record(f: BinaryIO, where: str) -> None:
    """Refuse a zip whose end record lists too many members or too long a directory."""
    size = f.seek(0, os.SEEK_END)
    tail_len = min(size, _EOCD_SIZE + 0xFFFF)
    f.seek(size - tail_len)
    tail = f.read(tail_len)
    at = tail.rfind(_EOCD)
    if at < 0 or len(tail) - at < _EOCD_SIZE:
        raise MapImportError(f"{where}: not a zip archive (no end of central directory record)")
    _, _, _, _, entries, cd_size, _, _ = struct.unpack("<4s4H2LH", tail[at : at + _EOCD_SIZE])
    if entries == 0xFFFF or cd_size == 0xFFFFFFFF:
        raise MapImportError(f"{where}: a zip64 archive: an IMDF archive is a few small files")
    if entries > MAX_ENTRIES or cd_size > MAX_DIRECTORY_BYTES:
        raise MapImportError(
            f"{where}: the zip lists {entries:,} members in {cd_size:,} bytes: an IMDF archive "
            f"holds a few files (at most {MAX_ENTRIES:,} members, "
            f"{MAX_DIRECTORY_BYTES >> 20} MiB of directory are read)"
        )
    f.seek(0)


def _leaves(name: str) -> bool:
    """A member name that is absolute or climbs out of the archive with ``..``."""
    if "\0" in name or name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":"):
        return True
    return ".." in name.replace("\\", "/").split("/")


def _zipped(zf: zipfile.ZipFile, where: str) -> Archive:
    infos = zf.infolist()
    for info in infos:
        if not info.filename:
            raise MapImportError(f"{where}: a member has no name: the archive is damaged")
        if _leaves(info.filename):
            raise MapImportError(
                f"{where}: member {shorten(info.filename)} is an absolute path or climbs out "
                "with '..': the archive is not read"
            )
    named = [
        i
        for i in infos
        if not i.is_dir()
        and posixpath.basename(i.filename) == "manifest.json"
        and not i.filename.startswith("__MACOSX/")
    ]
    if not named:
        raise MapImportError(f"{where}: no manifest.json in the archive: not an IMDF archive")
    if len(named) > 1:
        folders = ", ".join(shorten(posixpath.dirname(i.filename) or ".", 40) for i in named[:4])
        raise MapImportError(
            f"{where}: {len(named)} manifest.json files (in {folders}): give one venue's archive"
        )
    folder = posixpath.dirname(named[0].filename)
    members: dict[str, zipfile.ZipInfo] = {}
    for name in FILES:
        full = posixpath.join(folder, name) if folder else name
        try:
            info = zf.getinfo(full)
        except KeyError:
            continue
        _check_member(info, f"{where}: {name}")
        members[name] = info
    _check_required(members, where)
    return Archive(where, {n: i.file_size for n, i in members.items()}, zf, members)


def _check_member(info: zipfile.ZipInfo, where: str) -> None:
    if info.flag_bits & 0x1:
        raise MapImportError(f"{where}: encrypted: only plain archives are read")
    if info.file_size > MAX_FILE_BYTES:
        raise MapImportError(
            f"{where}: declares {info.file_size:,} bytes, more than the "
            f"{MAX_FILE_BYTES >> 20:,} MiB a file of an IMDF archive may have"
        )
    ratio = info.file_size / max(1, info.compress_size)
    if info.file_size > _RATIO_FROM and ratio > MAX_RATIO:
        raise MapImportError(
            f"{where}: {info.compress_size:,} bytes that expand to {info.file_size:,} "
            f"({ratio:,.0f} to 1, more than {MAX_RATIO} to 1): looks like a zip bomb, not read"
        )


def _check_required(present: Collection[str], where: str) -> None:
    missing = [n for n in REQUIRED if n not in present]
    if missing:
        raise MapImportError(
            f"{where}: no {', '.join(missing)} in the archive: an IMDF archive needs "
            f"{', '.join(REQUIRED)}"
        )


def _folder(path: Path) -> Archive:
    where = str(path)
    folder = os.path.abspath(path)
    real_folder = os.path.realpath(folder)
    sizes: dict[str, int] = {}
    for name in FILES:
        full = os.path.join(folder, name)
        if not os.path.lexists(full):
            continue
        real = os.path.realpath(full)
        if os.path.commonpath([real, real_folder]) != real_folder:
            raise MapImportError(
                f"{where}: {name} is a link to a place outside the folder: only files in the "
                "folder are read"
            )
        if not os.path.isfile(real):
            raise MapImportError(f"{where}: {name} is not a file")
        try:
            size = os.stat(real).st_size
        except OSError as exc:
            raise MapImportError(f"{where}: {name}: cannot read: {exc.strerror}") from None
        if size > MAX_FILE_BYTES:
            raise MapImportError(
                f"{where}: {name}: {size:,} bytes, more than the {MAX_FILE_BYTES >> 20:,} MiB "
                "a file of an IMDF archive may have"
            )
        sizes[name] = size
    _check_required(sizes, where)
    return Archive(where, sizes, _folder=Path(real_folder))
