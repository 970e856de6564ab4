"""Finding the part files of a tree.

Walking follows symbolic links that stay inside the tree but enters each real directory
once (no loops, no file indexed twice through two links), skips hidden folders and files,
and keeps the files :func:`shapeidx.io.format_of` knows (also gzipped). A link that leads out
of the tree (to ``/etc/passwd``, to another share) is not followed unless asked
(``follow_outside_links``): a build reads only the tree it was given.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from stat import S_ISREG

from ..io import format_of


@dataclass(frozen=True)
class FoundFile:
    path: str  # relative to the root, '/'-separated
    absolute: str
    size: int
    mtime_ns: int
    #: Its format's name (:func:`shapeidx.io.format_of`, found by the walk anyway); None: not known.
    format: str | None = None


@dataclass
class Walk:
    """What :func:`walk_parts` found: part files, and what it could not look at."""

    files: list = field(default_factory=list)
    #: Relative folders that could not be listed, and links not followed: their entries must
    #: not be taken as removed.
    unlisted: list = field(default_factory=list)
    warnings: list = field(default_factory=list)


def walk_parts(root: Path, follow_outside_links: bool = False) -> Walk:
    """Every part file under ``root`` (see the module docstring for the rules), sorted by path.

    Real folders are walked before symbolically linked ones, so that a file reachable both
    ways is indexed under its real path; each real folder is entered once.
    """
    found = Walk()
    real_root = os.path.realpath(root)
    seen: set = set()
    folders, linked = [Path(root)], []
    while folders or linked:
        folder = folders.pop() if folders else linked.pop(0)
        try:
            stat = folder.stat()
            if (stat.st_dev, stat.st_ino) in seen:
                continue  # a loop, or a second way to a folder already walked
            seen.add((stat.st_dev, stat.st_ino))
            children = sorted(os.scandir(folder), key=lambda e: e.name)
            # the folder's paths as strings, once: pathlib per file costs more than its stat
            folder_text, folder_rel = str(folder), folder.relative_to(root).as_posix()
        except OSError as exc:
            rel = folder.relative_to(root).as_posix()
            found.unlisted.append(rel)
            found.warnings.append(f"cannot list {rel}: {exc.strerror or exc}")
            continue
        for child in children:
            if child.name.startswith("."):
                continue
            if not follow_outside_links and child.is_symlink() and not _inside(child.path, real_root):
                if _is_folder(child) or format_of(child.name) is not None:
                    rel = Path(child.path).relative_to(root).as_posix()
                    found.unlisted.append(rel)  # not looked at: its entries, if any, are not removed
                    found.warnings.append(f"skipped {_printable(rel)}: a symbolic link out of the indexed folder"
                                          " (not followed; --follow-outside-links follows it)")
                continue
            if _is_folder(child):
                (linked if child.is_symlink() else folders).append(Path(child.path))
            elif (fmt := format_of(child.name)) is not None:
                _add_file(found, child.name if folder_rel == "." else f"{folder_rel}/{child.name}",
                          child.name if folder_text == "." else os.path.join(folder_text, child.name), fmt)
    found.files.sort(key=lambda f: f.path)
    return found


def _inside(path: str, real_root: str) -> bool:
    """Whether ``path``, with every link resolved, lies in ``real_root``."""
    real = os.path.realpath(path)
    return real == real_root or real.startswith(real_root.rstrip(os.sep) + os.sep)


def _printable(name: str) -> str:
    from ..errors import printable

    return printable(name)


def _is_folder(entry: os.DirEntry) -> bool:
    try:
        return entry.is_dir()
    except OSError:
        return False


def _add_file(found: Walk, rel: str, absolute: str, fmt: str | None = None) -> None:
    """``rel``: the path relative to the root, '/'-separated; ``absolute``: as ``str(Path(...))``
    gives it; ``fmt``: its format's name."""
    try:
        rel.encode("utf-8")
    except UnicodeEncodeError:
        found.warnings.append(f"skipped {rel!r}: its name is not valid UTF-8")
        return
    try:
        stat = os.stat(absolute)
    except OSError as exc:
        found.warnings.append(f"skipped {rel}: {exc.strerror or exc} (a broken link?)")
        return
    if not S_ISREG(stat.st_mode):  # what Path.is_file() asks, from the same stat: one system call a file
        return
    found.files.append(FoundFile(rel, absolute, stat.st_size, stat.st_mtime_ns, fmt))
