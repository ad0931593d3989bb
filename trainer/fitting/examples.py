"""Reading a user's example point sets: files or folders of them, validated, streamed.

Accepted files (the formats ``diffsampler generate`` writes, and those most samplers write):

- ``.npy``: an array (S, n, 2) or (n, 2), read memory-mapped (never loaded whole);
- ``.csv``: a header ``set,x,y`` and rows ``i,x,y`` (sets numbered from 0 in order), or
  plain ``x,y`` rows (one set);
- ``.txt``, ``.dat``, ``.pts`` and other text: ``x y`` per line (whitespace or commas),
  sets separated by blank lines; ``#`` starts a comment (UTK's and most samplers' files).

Every set must hold n = k*k points, k >= 4, finite and in [0, 1)^2. A problem stops the
fit before any work with :class:`ExampleError`: one line naming the file, the set (and line
where there is one) and what is wrong.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

#: the smallest grid side a fit accepts (n = 16 points)
MIN_SIDE = 4
TEXT_SUFFIXES = {".txt", ".dat", ".pts", ".xy", ""}
#: bytes read to tell a text file from a binary one
SNIFF = 4096


class ExampleError(ValueError):
    """A bad example file or set (one line: the file, the set or line, what is wrong)."""


@dataclass(frozen=True)
class Source:
    """One file's (or array's) sets: all of ``n`` points, ``count`` of them."""
    name: str
    n: int
    count: int
    path: Path | None = None
    array: np.ndarray | None = None
    kind: str = "npy"

    def sets(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Sets start..stop as float64 (m, n, 2) (a memory-mapped file is read in part)."""
        stop = self.count if stop is None else stop
        if self.array is not None:
            data = self.array
        elif self.kind == "npy":
            data = np.load(self.path, mmap_mode="r")
        else:
            data = _read_text(self.path, self.kind)
        data = data.reshape((-1, self.n, 2))
        return np.array(data[start:stop], dtype=np.float64)


def _side(n: int) -> int | None:
    k = math.isqrt(n)
    return k if k * k == n else None


def _nearest_squares(n: int) -> str:
    k = math.isqrt(n)
    return f"{k * k} or {(k + 1) ** 2}" if k * k != n else str(n)


def _check_sets(sets: np.ndarray, name: str, first: int = 0) -> None:
    """ExampleError at the first set with a non-finite point or one outside [0, 1)^2."""
    bad_value = ~np.isfinite(sets).all(axis=(-2, -1))
    outside = ~((sets >= 0) & (sets < 1)).all(axis=(-2, -1))
    for mask, what in ((bad_value, "holds NaN or infinite coordinates"),
                       (outside, "has points outside [0, 1)^2")):
        if mask.any():
            i = int(np.argmax(mask))
            point = int(np.argmax(~(np.isfinite(sets[i]) & (sets[i] >= 0) & (sets[i] < 1))
                                  .all(axis=-1)))
            raise ExampleError(f"{name}: set {first + i} {what} (point {point}: "
                               f"{sets[i, point].tolist()})")


def _is_binary(path: Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(SNIFF)
    return b"\0" in head


def _read_text(path: Path, kind: str) -> np.ndarray:
    """A text file's sets as (S, n, 2) (ExampleError on a bad line or ragged sets)."""
    sets: list[list[tuple[float, float]]] = [[]]
    labels: list[int] = []
    with open(path, encoding="utf-8", errors="strict") as fh:
        try:
            lines = fh.readlines()
        except UnicodeDecodeError:
            raise ExampleError(f"{path}: not a text file of points (undecodable bytes)") from None
    header = kind == "csv" and lines and lines[0].strip().lower().replace(" ", "") == "set,x,y"
    for number, line in enumerate(lines[1:] if header else lines, start=2 if header else 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            if not header and sets[-1]:
                sets.append([])
            continue
        parts = text.replace(",", " ").replace(";", " ").split()
        want = 3 if header else 2
        if len(parts) != want:
            raise ExampleError(f"{path}: line {number} has {len(parts)} columns, expected "
                               f"{want} ({'set,x,y' if header else 'x y'}): {text[:60]!r}")
        try:
            values = [float(v) for v in parts]
        except ValueError:
            raise ExampleError(f"{path}: line {number} is not numbers: {text[:60]!r}") from None
        if header:
            label = values[0]
            if not label.is_integer():
                raise ExampleError(f"{path}: line {number}: set number {parts[0]!r} is not "
                                   "an integer")
            if labels and label != labels[-1]:
                if label != labels[-1] + 1:
                    raise ExampleError(f"{path}: line {number}: set {int(label)} follows set "
                                       f"{labels[-1]} (sets must be numbered 0, 1, 2, ...)")
                sets.append([])
            elif not labels and label != 0:
                raise ExampleError(f"{path}: line {number}: the first set must be set 0")
            labels.append(int(label))
            values = values[1:]
        sets[-1].append((values[0], values[1]))
    sets = [s for s in sets if s]
    if not sets:
        raise ExampleError(f"{path}: holds no points")
    sizes = sorted({len(s) for s in sets})
    if len(sizes) > 1:
        i = next(i for i, s in enumerate(sets) if len(s) != len(sets[0]))
        raise ExampleError(f"{path}: sets of different sizes in one file (set 0 has "
                           f"{len(sets[0])} points, set {i} {len(sets[i])}); put each size in "
                           "its own file")
    return np.asarray(sets, dtype=np.float64)


def _npy_source(path: Path) -> Source:
    try:
        data = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise ExampleError(f"{path}: not a readable .npy array ({str(exc).splitlines()[0]})") \
            from None
    if not np.issubdtype(data.dtype, np.number) or np.issubdtype(data.dtype, np.complexfloating):
        raise ExampleError(f"{path}: holds {data.dtype} values, not real numbers")
    if data.ndim == 2:
        data = data[None]
    if data.ndim != 3 or data.shape[-1] != 2:
        raise ExampleError(f"{path}: array of shape {data.shape}; expected (sets, n, 2) or "
                           "(n, 2)")
    if data.shape[0] == 0 or data.shape[1] == 0:
        raise ExampleError(f"{path}: holds no points (shape {data.shape})")
    return Source(str(path), data.shape[1], data.shape[0], path=path, kind="npy")


def _text_source(path: Path) -> Source:
    if _is_binary(path):
        raise ExampleError(f"{path}: a binary file, not text points or a .npy array")
    kind = "csv" if path.suffix.lower() == ".csv" else "text"
    data = _read_text(path, kind)
    return Source(str(path), data.shape[1], data.shape[0], path=path, kind=kind)


def _files(paths: Sequence[str | os.PathLike]) -> list[Path]:
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(f for f in p.rglob("*") if f.is_file() and not f.name.startswith("."))
            if not found:
                raise ExampleError(f"{p}: folder holds no files")
            out += found
        elif p.is_file():
            out.append(p)
        else:
            raise ExampleError(f"{p}: no such file or folder")
    return out


def _source(path: Path) -> Source:
    if path.stat().st_size == 0:
        raise ExampleError(f"{path}: empty file")
    return _npy_source(path) if path.suffix.lower() == ".npy" else _text_source(path)


def _array_sources(arrays: Sequence[np.ndarray]) -> list[Source]:
    out = []
    for i, a in enumerate(arrays):
        a = np.asarray(a)
        if a.ndim == 2:
            a = a[None]
        if a.ndim != 3 or a.shape[-1] != 2 or a.shape[1] == 0:
            raise ExampleError(f"array {i}: shape {a.shape}; expected (sets, n, 2) or (n, 2)")
        out.append(Source(f"array {i}", a.shape[1], a.shape[0], array=a.astype(np.float64)))
    return out


@dataclass
class Examples:
    """A user's example sets, by size: the sources of each n (in the order given)."""
    sources: dict[int, list[Source]]

    @property
    def sizes(self) -> list[int]:
        return sorted(self.sources)

    def count(self, n: int) -> int:
        return sum(s.count for s in self.sources[n])

    def iter_sets(self, n: int, chunk: int = 256) -> Iterator[np.ndarray]:
        """The sets of n points, a chunk at a time (never all in memory at once)."""
        for src in self.sources[n]:
            for start in range(0, src.count, chunk):
                yield src.sets(start, min(src.count, start + chunk))

    def take(self, n: int, index: np.ndarray) -> np.ndarray:
        """The sets of n points at the given positions (in the order of the sources)."""
        out = np.empty((len(index), n, 2))
        offsets = np.cumsum([0] + [s.count for s in self.sources[n]])
        for j, src in enumerate(self.sources[n]):
            mine = np.flatnonzero((index >= offsets[j]) & (index < offsets[j + 1]))
            if len(mine):
                local = index[mine] - offsets[j]
                if src.array is not None or src.kind == "npy":
                    data = src.array if src.array is not None else np.load(src.path,
                                                                            mmap_mode="r")
                    out[mine] = data.reshape((-1, n, 2))[np.sort(local)][np.argsort(
                        np.argsort(local))]
                else:
                    out[mine] = src.sets()[local]
        return out


def read_examples(examples: Sequence[str | os.PathLike | np.ndarray] | str | os.PathLike
                  ) -> Examples:
    """Files, folders (read recursively) or arrays -> :class:`Examples`, every set checked
    (ExampleError, one line, at the first problem)."""
    if isinstance(examples, (str, os.PathLike, np.ndarray)):
        examples = [examples]
    if not examples:
        raise ExampleError("no examples given")
    arrays = [e for e in examples if isinstance(e, np.ndarray)]
    paths = [e for e in examples if not isinstance(e, np.ndarray)]
    sources = _array_sources(arrays) + [_source(f) for f in _files(paths)]
    by_size: dict[int, list[Source]] = {}
    for src in sources:
        by_size.setdefault(src.n, []).append(src)
    bad = [n for n in by_size if _side(n) is None or _side(n) < MIN_SIDE]
    if bad:
        found = ", ".join(f"{n} ({by_size[n][0].name})" for n in sorted(bad))
        hint = "; ".join(f"{n}: nearest squares {_nearest_squares(n)}" for n in sorted(bad))
        raise ExampleError(f"example sets must hold n = k*k points with k >= {MIN_SIDE}; "
                           f"found n = {found} ({hint})")
    out = Examples({n: by_size[n] for n in sorted(by_size)})
    for n in out.sizes:
        for src in out.sources[n]:
            for start in range(0, src.count, 1024):
                _check_sets(src.sets(start, min(src.count, start + 1024)), src.name, start)
    return out
