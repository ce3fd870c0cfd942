"""The geometry of an OBJ file: its triangles, grouped by material, read in one pass.

Read here rather than by a mesh library: the statements a textured mesh needs (``v``, ``vt``,
``vn``, ``f``, ``usemtl``) take one pass over the lines and a few array conversions, where
importing trimesh alone took 0.7 to 1.0 s of every OBJ job on two cores. Polygons are split
into fans of triangles; points, lines, groups, objects, smoothing groups and free-form
statements are not geometry to texture and are skipped.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from geoscaler.errors import GeoscalerError

from .assemble import Part

NO_INDEX = -1
"""A corner's texture-coordinate or normal index where the face gives none."""

ELEMENTS = {"v": "vertex", "vt": "texture coordinate", "vn": "normal"}
_WIDTHS = {"v": 3, "vt": 2, "vn": 3}
"""Numbers read per element: x y z (colours after them skipped), u v (w skipped), x y z."""


def obj_parts(text: str, materials: Mapping[str, int], path: Path) -> list[Part]:
    """One :class:`Part` per material that faces use, in the order of first use.

    Parameters
    ----------
    text : str
        The OBJ file, decoded.
    materials : mapping of str to int
        The MTL libraries' materials by name, their index in the loader's list; faces before
        any ``usemtl``, or after one that names no known material, get material None.
    path : Path
        The file, the start of every message.

    Returns
    -------
    list of Part
        Per material: its corners' distinct (position, texture coordinate, normal) triples
        as vertices, the triangles over them; UVs (normals) only where every corner of the
        material's faces gives a texture coordinate (a normal), else None.

    Raises
    ------
    GeoscalerError
        An element without its numbers, a face corner that is not an index, is 0 or points
        past its list: the line and what to do.
    """
    statements = _Statements.read(text, materials, path)
    arrays = {kind: statements.numbers(kind, text, path) for kind in ELEMENTS}
    corners = statements.corner_indices(arrays, text, path)
    sizes = np.asarray(statements.sizes, dtype=np.int64)
    triangles = _fans(corners, sizes)
    group = np.repeat(np.asarray(statements.face_group, dtype=np.int64), 3 * (sizes - 2))
    return [
        _part(triangles[group == g], arrays, statements.groups[g])
        for g in dict.fromkeys(statements.face_group)
    ]


@dataclass
class _Statements:
    """The statements of an OBJ file that hold geometry, as read: element numbers as words,
    face corners as words, and per face its corner count, material group and how many
    elements of each kind came before it."""

    elements: dict[str, list[list[str]]] = field(default_factory=dict)
    words: list[str] = field(default_factory=list)
    sizes: list[int] = field(default_factory=list)
    face_group: list[int] = field(default_factory=list)
    seen: list[tuple[int, int, int]] = field(default_factory=list)
    groups: list[int | None] = field(default_factory=list)

    @classmethod
    def read(cls, text: str, materials: Mapping[str, int], path: Path) -> _Statements:
        read = cls({k: [] for k in ELEMENTS})
        group = read.group_of(None)
        for number, line in enumerate(text.splitlines(), 1):
            words = line.split()
            if not words:
                continue
            head = words[0]
            if head in read.elements:
                read.add_element(head, words, number, path)
            elif head == "f" and len(words) >= 4:
                read.words += words[1:]
                read.sizes.append(len(words) - 1)
                read.face_group.append(group)
                read.seen.append(tuple(len(read.elements[k]) for k in ELEMENTS))
            elif head == "usemtl":
                name = line.split(None, 1)[1].strip() if len(words) > 1 else ""
                group = read.group_of(materials.get(name))
        return read

    def group_of(self, material: int | None) -> int:
        if material not in self.groups:
            self.groups.append(material)
        return self.groups.index(material)

    def add_element(self, head: str, words: list[str], number: int, path: Path) -> None:
        given = _number_words(words)
        if len(given) < _WIDTHS[head]:
            raise _needs_numbers(words, path, number)
        self.elements[head].append(given)

    def numbers(self, kind: str, text: str, path: Path) -> np.ndarray:
        """``(n, width)`` float64 numbers of every ``kind`` element; one that is not a number
        raises with its line (found in ``text`` only then)."""
        try:
            return np.asarray(self.elements[kind], dtype=np.float64).reshape(-1, _WIDTHS[kind])
        except ValueError:
            for number, line in enumerate(text.splitlines(), 1):
                words = line.split()
                if words[:1] == [kind]:
                    given = _number_words(words)
                    try:
                        [float(word) for word in given]
                    except ValueError:
                        raise _needs_numbers([kind, *given], path, number) from None
            raise

    def corner_indices(self, arrays: Mapping[str, np.ndarray], text: str, path: Path) -> np.ndarray:
        """``(K, 3)`` int64 0-based (position, texture coordinate, normal) index of every
        face corner, :data:`NO_INDEX` where the corner gives none; a bad index raises with its
        line (:func:`check_face_indices`)."""
        seen = np.repeat(np.asarray(self.seen, dtype=np.int64).reshape(-1, 3), self.sizes, axis=0)
        try:
            given = _corner_numbers(self.words)
        except (ValueError, OverflowError):  # not an index, or none that fits: named below
            given = None
        if given is not None:
            totals = np.array([len(arrays[k]) for k in ELEMENTS])
            absent = given == _ABSENT
            given[absent] = 0
            resolved = np.where(given > 0, given - 1, seen + given)
            bad = ~absent & ((given == 0) | (given > totals) | (resolved < 0))  # 0: not an index
            bad[:, 0] |= absent[:, 0]
            if not bad.any():
                return np.where(absent, NO_INDEX, resolved)
        check_face_indices(text, path)
        raise GeoscalerError(f"{path}: a face corner could not be read; repair the file")


_ABSENT = np.iinfo(np.int64).min
"""What :func:`_corner_numbers` writes where a corner gives no index."""

_COLUMNS = {0: [0], 1: [0, 1], 2: [0, 1, 2], 5: [0, 2]}
"""The indices a corner gives, by its form (slashes + 3 x double slashes): ``v``, ``v/vt``,
``v/vt/vn``, ``v//vn``."""


def _corner_numbers(words: list[str]) -> np.ndarray:
    """``(K, 3)`` int64 indices as written (:data:`_ABSENT`: not given) of face corners;
    one conversion where every corner has one form and every number, else corner by corner.
    Raises ``ValueError`` for a word that is not an index, ``OverflowError`` for one past
    int64."""
    given = np.full((len(words), 3), _ABSENT, dtype=np.int64)
    if not words:
        return given
    written = np.asarray(words)
    forms = np.char.count(written, "/") + 3 * np.char.count(written, "//")
    columns = _COLUMNS.get(int(forms[0]))
    if columns is not None and (forms == forms[0]).all():
        numbers = np.asarray(" ".join(words).replace("/", " ").split(), dtype=np.int64)
        if numbers.size == len(words) * len(columns):  # else some corner leaves a number out
            given[:, columns] = numbers.reshape(len(words), len(columns))
            return given
    for row, word in enumerate(words):
        for column, part in enumerate(word.split("/")[:3]):
            if part:
                given[row, column] = int(part)
    return given


def check_face_indices(text: str, path: Path) -> None:
    """Refuse a face corner without a vertex index, or whose index is not one, is 0 or
    points past its list.

    OBJ indices start at 1; negative ones count back from the last element defined before
    the face. Unchecked, an index of 0 or past the end would read another element, or fail
    with no line to show.
    """
    lines = text.splitlines()
    totals = dict.fromkeys(ELEMENTS, 0)
    for line in lines:
        head = line.split(None, 1)[:1]
        if head and head[0] in totals:
            totals[head[0]] += 1
    seen = dict.fromkeys(ELEMENTS, 0)
    for number, line in enumerate(lines, 1):
        words = line.split()
        if not words:
            continue
        if words[0] in seen:
            seen[words[0]] += 1
        elif words[0] == "f":
            for corner in words[1:]:
                _check_corner(corner, seen, totals, path, number)


def _check_corner(corner: str, seen: dict, totals: dict, path: Path, number: int) -> None:
    for kind, part in zip(ELEMENTS, corner.split("/"), strict=False):
        if not part and kind != "v":
            continue
        try:
            index = int(part)
        except ValueError:
            index = None
        if index is not None and 0 < index <= totals[kind]:
            continue  # the common case, checked before any message is made
        where = f"{path}: line {number}: face corner {corner!r}"
        if index is None or index == 0:
            raise GeoscalerError(
                f"{where} is not a {ELEMENTS[kind]} index (OBJ indices start at 1); "
                "repair the file or re-export it"
            )
        count = totals[kind] if index > 0 else seen[kind]
        if abs(index) > count:
            raise GeoscalerError(
                f"{where} refers to {ELEMENTS[kind]} {index}, but the file defines "
                f"{count}{'' if index > 0 else ' before it'}; repair the file or re-export it"
            )


def _number_words(words: list[str]) -> list[str]:
    """The words of an element statement ``words`` (its head first) that hold its numbers:
    as many as its kind reads, fewer where the line has fewer."""
    given = words[1 : _WIDTHS[words[0]] + 1]
    if words[0] == "vt" and len(given) == 1:
        given.append("0")  # a missing v is 0, as the format says
    return given


def _needs_numbers(words: list[str], path: Path, number: int) -> GeoscalerError:
    width = _WIDTHS[words[0]]
    return GeoscalerError(
        f"{path}: line {number}: {' '.join(words)!r} needs {width} numbers after {words[0]!r}; "
        "repair the file or re-export it"
    )


def _fans(corners: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """``(T * 3, 3)`` corners of the triangles of polygons of ``sizes`` corners laid end to
    end in ``corners``: polygon ``a b c d ...`` gives ``a b c``, ``a c d``, ..."""
    starts = np.repeat(np.cumsum(sizes) - sizes, sizes - 2)
    step = np.arange(len(starts)) - np.repeat(np.cumsum(sizes - 2) - (sizes - 2), sizes - 2)
    picks = np.stack([starts, starts + step + 1, starts + step + 2], axis=1)
    return corners[picks.reshape(-1)]


def _part(corners: np.ndarray, arrays: Mapping[str, np.ndarray], material: int | None) -> Part:
    """The part of one material from its ``(3 F, 3)`` corner triples."""
    triples, inverse = _distinct_rows(corners)
    faces = inverse.reshape(-1, 3)
    uvs = normals = None
    if (triples[:, 1] != NO_INDEX).all():
        uvs = arrays["vt"][triples[:, 1]]
    if (triples[:, 2] != NO_INDEX).all():
        normals = arrays["vn"][triples[:, 2]]
    return Part(arrays["v"][triples[:, 0]], faces, uvs, normals, material)


def _distinct_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(rows, axis=0, return_inverse=True)`` of ``(K, 3)`` int64 rows of values
    >= -1, through one int64 key per row where the key fits (several times faster)."""
    shifted = rows + 1
    spans = [int(span) + 1 for span in shifted.max(axis=0)] if len(rows) else [1, 1, 1]
    if spans[0] * spans[1] * spans[2] >= 2**63:
        return np.unique(rows, axis=0, return_inverse=True)
    key = (shifted[:, 0] * spans[1] + shifted[:, 1]) * spans[2] + shifted[:, 2]
    keys, inverse = np.unique(key, return_inverse=True)
    distinct = np.stack(
        [keys // (spans[1] * spans[2]), keys // spans[2] % spans[1], keys % spans[2]]
    )
    return distinct.T - 1, inverse.reshape(-1)
