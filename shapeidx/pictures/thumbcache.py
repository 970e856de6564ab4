"""Thumbnails of part files, cached on disk by the file's content.

The cache is a plain folder of PNG files named by the SHA-256 of the part file, the picture
size and :data:`~shapeidx.pictures.render.RENDER_VERSION`:

* in a store ``S``: ``S/thumbs/`` (:func:`cache_dir_of_store`), a folder of its own beside
  the HDF5 files, so nothing the cache does can make a store unreadable, and copying the
  store copies its pictures;
* otherwise ``$XDG_CACHE_HOME/shapeidx/thumbs`` (``~/.cache/shapeidx/thumbs``).

A sub-part ``FILE#n`` of a store built with ``--parts`` is drawn itself, in its own frame
(:func:`~shapeidx.pictures.render.render_sub_part_png`), cached by its file's SHA-256, its
number and :data:`~shapeidx.io.parts.PARTS_VERSION` (the rules that numbered it).

A changed file has another hash, so it gets a new picture; a thumbnail is written under a
temporary name and renamed into place, so a reader never sees half a PNG. A cache folder that
cannot be written is not an error: the picture is rendered and returned all the same.

For an entry of a store the hash recorded by the build is used when the file's size and
modification time still match the entry (no need to read the file); otherwise the file is
hashed again.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..io.base import file_hash, read_regular
from .render import DEFAULT_SIZE, RENDER_VERSION, render_file_png, render_solid_png, render_sub_part_png


def cache_dir_of_store(store: str | os.PathLike) -> Path:
    """The thumbnail folder that belongs to a store: ``STORE/thumbs`` inside it."""
    from ..store.files import thumbs_dir

    return thumbs_dir(Path(store))


def default_cache_dir() -> Path:
    """The per-user thumbnail folder, for parts that are not entries of a store."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "shapeidx" / "thumbs"


class ThumbnailCache:
    """PNG thumbnails of part files, rendered once per file content.

    Parameters
    ----------
    folder : where the PNG files go (created when first needed)
    size : picture side in pixels
    """

    def __init__(self, folder: str | os.PathLike, size: int = DEFAULT_SIZE):
        self.folder = Path(folder)
        self.size = size
        self.rendered = 0  # pictures rendered (cache misses) by this object, for benchmarks and tests

    def key_path(self, digest: str, part: int | None = None) -> Path:
        """Where the thumbnail of a file with SHA-256 ``digest`` is kept (of its sub-part
        number ``part``, when given)."""
        if part is not None:
            from ..io.parts import PARTS_VERSION

            return self.folder / f"{digest}-part{int(part)}-s{PARTS_VERSION}-{self.size}px-v{RENDER_VERSION}.png"
        return self.folder / f"{digest}-{self.size}px-v{RENDER_VERSION}.png"

    def png(self, path: str | os.PathLike, digest: str | None = None, solid=None) -> bytes:
        """The PNG bytes of the thumbnail of part file ``path``.

        ``digest`` is the file's SHA-256 when already known (a store entry whose file did not
        change); otherwise the file is hashed. ``solid``, when the caller has loaded the part
        already, spares loading it again. Raises :class:`~shapeidx.errors.LoadError`
        when the part cannot be read (no picture is cached then).
        """
        from ..errors import LoadError

        try:
            digest = digest or file_hash(os.fspath(path))
        except OSError as exc:
            raise LoadError(path, f"cannot read the file ({exc.strerror or exc})") from None
        target = self.key_path(digest)
        try:
            return read_regular(target, 64 << 20)  # a FIFO or a device in the cache is a miss, never a hang
        except OSError:
            pass
        data = render_solid_png(solid, self.size) if solid is not None else render_file_png(path, self.size)
        self.rendered += 1
        self._write(target, data)
        return data

    def part_png(self, path: str | os.PathLike, number: int, digest: str | None = None, count: int | None = None,
                 title: str | None = None) -> bytes:
        """The PNG bytes of the thumbnail of sub-part ``number`` of part file ``path``
        (``FILE#number``; ``count`` and ``title`` as the store has them: see
        :func:`~shapeidx.pictures.render.render_sub_part_png`). Raises LoadError."""
        from ..errors import LoadError

        try:
            digest = digest or file_hash(os.fspath(path))
        except OSError as exc:
            raise LoadError(path, f"cannot read the file ({exc.strerror or exc})") from None
        target = self.key_path(digest, number)
        try:
            return read_regular(target, 64 << 20)
        except OSError:
            pass
        data = render_sub_part_png(path, number, self.size, count, title)
        self.rendered += 1
        self._write(target, data)
        return data

    def _write(self, target: Path, data: bytes) -> None:
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd, temporary = tempfile.mkstemp(prefix=".tmp-", suffix=".png", dir=self.folder)
        except OSError:
            return  # a cache that cannot be written only costs time
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(temporary, target)
        except OSError:
            try:
                os.unlink(temporary)
            except OSError:
                pass


class StoreThumbnails:
    """Thumbnails of a store's entries, in the store's own cache folder ``STORE/thumbs/``.

    Parameters
    ----------
    searcher : an open :class:`~shapeidx.search.Searcher` (its entries are found by path,
        one at a time: a sheet of ten hits of a store of a million reads ten rows)
    size : picture side in pixels
    folder : the cache folder (default ``STORE/thumbs``)
    """

    def __init__(self, searcher, size: int = DEFAULT_SIZE, folder: str | os.PathLike | None = None):
        self.searcher = searcher
        self.root = Path(searcher.root or ".")
        self.cache = ThumbnailCache(folder or cache_dir_of_store(searcher.store), size)

    def file_of(self, entry: str) -> Path:
        """The absolute path of an entry's part file."""
        return self.root / entry

    def png(self, entry: str, record: str | None = None) -> bytes:
        """The thumbnail of the entry with relative path ``entry`` (LoadError if unreadable);
        ``record``: the entry whose stored hash is the file's (a sub-entry ``FILE#n`` of ``entry``)."""
        absolute = self.file_of(entry)
        return self.cache.png(absolute, self._digest(record or entry, absolute))

    def sub_part_png(self, entry: str) -> bytes:
        """The thumbnail of sub-entry ``FILE#n`` itself (``searcher`` opened with
        ``parts=True``), drawn in its own frame; a file that is one part (its ``FILE#1`` alone,
        once) shows the whole file's picture, shared with the whole-file thumbnails. Raises
        LoadError (also for an entry the store does not have)."""
        from ..errors import LoadError

        facts = self.searcher.sub_part_of(entry)
        if facts is None:
            raise LoadError(entry, "is not a sub-part of the store")
        absolute = self.file_of(facts["parent"])
        digest = self._digest(entry, absolute)
        if facts["whole"]:
            return self.cache.png(absolute, digest)  # one part: the whole file
        return self.cache.part_png(absolute, int(entry.rsplit("#", 1)[1]), digest, facts["count"], facts["title"])

    def is_whole_file(self, entry: str) -> bool:
        """Whether sub-entry ``entry`` is the whole file (a file that is one part), whose
        picture is the file's."""
        facts = self.searcher.sub_part_of(entry)
        return facts is not None and facts["whole"]

    def _digest(self, entry: str, absolute: Path) -> str | None:
        """The entry's stored SHA-256 when its file is unchanged since the build (else None: hash it)."""
        view = getattr(self.searcher, "view", None)  # a sharded store's rows are in its shards: hash the file
        found = view.find(entry) if view is not None else None
        if found is None:
            return None
        try:
            stat = os.stat(absolute)
        except OSError:
            return None
        source, row = self.searcher.view.sources[found[0]], found[1]
        digest = source.value_at("entries/hash", row)
        digest = digest.decode() if isinstance(digest, bytes) else str(digest)
        size, mtime = int(source.value_at("entries/size", row)), int(source.value_at("entries/mtime_ns", row))
        if stat.st_size == size and stat.st_mtime_ns == mtime and len(digest) == 64:
            return digest
        return None  # changed since the build (or touched by a later segment): hash it again
