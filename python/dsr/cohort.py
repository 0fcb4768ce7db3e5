"""dsr.cohort: one registration per study of a cohort, on Dask distributed.

A manifest (CSV with a header) names the studies: ``study`` (an id, also its output folder's
name), ``images`` (the frames' paths separated by ``;``) and optionally ``masks`` (the same
form), ``gt_poses`` (one poses file, kept with the study's record) and ``options``
(per-study flags overriding the shared ones, e.g. ``--photometric=affine``). Relative paths,
``--init=FILE`` in ``options`` too, are relative to the manifest's folder. Each study is one
``dsr.register`` call on a Dask worker process: an embedded ``LocalCluster`` by default, or
an existing cluster (``scheduler=``; e.g. one dask-jobqueue starts on SLURM or PBS).

Every row is checked before any study runs, with dsr_register's own checks of its files and
options: a row that fails them is refused (not run, listed in the results with the reason)
and the others run; a manifest none of whose rows can run is refused as a whole
(ManifestError), and so is a manifest that is not a regular file of CSV with the columns.

Per study, ``OUT/<study>/`` receives ``poses.json`` (written atomically) and then
``record.json``, the study's outcome (``ok`` or ``failed`` with the reason), written last:
a study without a record was never finished and is done again; a study whose record matches
everything its outputs depend on (its files' paths, sizes and times, the ground truth's and
an --init file's too, and the options) is skipped by a rerun (``force=True`` redoes it). A
worker that dies during a study (killed, out of memory) has it retried once on another
worker; a second death records the study as failed (a rerun tries it again).
``OUT/results.csv`` (and ``results.parquet`` with pyarrow installed) has one row per row of
the manifest, refused and failed studies first, and ``OUT/index.html`` shows it sortable,
with each study's thumbnails linking to its report. One cohort at a time runs on an
``OUT``: it holds a lock on ``OUT/.dsr-cohort.lock`` while it runs.

Usage::

    python -m dsr.cohort --manifest=studies.csv --out_dir=out --workers=2 --max_iterations=50
    dsr.cohort.run("studies.csv", "out", workers=2, max_iterations=50)
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import datetime
import hashlib
import io
import json
import logging
import numbers
import os
import re
import shlex
import socket
import stat
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence, Tuple

__all__ = ["Study", "CohortError", "ManifestError", "read_manifest", "run", "main"]

_COLUMNS = ("study", "images", "masks", "gt_poses", "options")
_STUDY_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*\Z")
# A study id names a folder (a file name may have 255 bytes) and appears in every message
# and row about the study: 100 characters are plenty.
_MAX_ID_CHARACTERS = 100
# The cohort's own files in OUT: no study may be named like one (case ignored, as some file
# systems do).
_OWN_FILES = ("results.csv", "results.parquet", "index.html")
_LOCK_FILE = ".dsr-cohort.lock"
# The files the runner itself writes into OUT/<study> (dsr_register writes the report).
_STUDY_FILES = ("images.txt", "masks.txt", "log.txt", "record.json", "poses.json")
# A manifest of 10 000 studies of 32 frames with 100-character paths has 32 MB; a larger
# file is a mistake (or a device), and it is read into memory whole.
_MAX_MANIFEST_BYTES = 64 << 20
# A worker process holds Python, Dask and dsr (about 140 MiB) before any study: a memory
# limit below this leaves a study nothing (Dask pauses a worker at 80 % of its limit).
_MIN_MEMORY_LIMIT = 256 << 20
# An embedded cluster of more threads than this many per CPU only slows its studies down.
_MAX_THREADS_PER_CPU = 4

_LOG = logging.getLogger("dsr.cohort")


@dataclass
class Study:
    """One row of a manifest, its paths made absolute."""

    study: str
    images: List[str]
    masks: List[str] = field(default_factory=list)
    gt_poses: Optional[str] = None
    options: Dict[str, str] = field(default_factory=dict)
    row: int = 0
    digest: str = ""


class CohortError(ValueError):
    """A cohort that cannot run as asked: one line naming the file or flag."""


class ManifestError(CohortError):
    """A manifest that cannot be run: one line naming the file, the row and the column."""


class _Refused(Exception):
    """A row that cannot run: the line saying why."""


@dataclass
class _Refusal:
    study: str
    row: int
    reason: str

    def record(self) -> Dict[str, Any]:
        return {"study": self.study, "status": "refused", "reason": self.reason,
                "row": self.row}


def _shown(text: str, limit: int = 40) -> str:
    """`text` for a message: quoted, control characters escaped, a long one shortened."""
    if len(text) <= limit:
        return repr(text)
    return f"{text[:limit]!r}... ({len(text)} characters)"


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "is a folder"
    for test, name in ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return f"is {name}, not a regular file"
    return "is not a regular file"


def _file(item: str, folder: str, where: str) -> str:
    """The absolute path of the file `item` (relative to `folder`), checked: a readable
    regular file whose name a list file can hold. _Refused naming `where` otherwise."""
    if "\n" in item or "\r" in item or "\0" in item:
        what = "a NUL character" if "\0" in item else "a line break"
        raise _Refused(f"{where}: {_shown(item, 200)} has {what} in its name, which "
                       "dsr_register's list files cannot hold: rename the file")
    path = item if os.path.isabs(item) else os.path.join(folder, item)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        reason = "is a symlink to a missing file" if os.path.islink(path) else "does not exist"
        raise _Refused(f"{where}: {item} {reason}") from None
    except OSError as error:
        raise _Refused(f"{where}: {item} cannot be read ({error.strerror})") from None
    if not stat.S_ISREG(mode):
        raise _Refused(f"{where}: {item} {_kind(mode)}")
    if not os.access(path, os.R_OK):
        raise _Refused(f"{where}: {item} is not readable")
    return os.path.abspath(path)


def _paths(text: str, folder: str, where: str) -> List[str]:
    return [_file(item, folder, where) for item in (p.strip() for p in text.split(";")) if item]


def _register_options() -> List[str]:
    from . import options as table  # noqa: PLC0415

    return [name for name, o in table().items() if "python:register" in o["front_ends"]]


def _init_is_file(value: str) -> bool:
    from . import _core  # noqa: PLC0415

    return _core.init_is_file(value)


def _options(text: str, where: str, known: Sequence[str],
             folder: Optional[str] = None) -> Dict[str, str]:
    """"--name=value --flag --noflag" as {name: value}, each a dsr.register option given
    once; an --init file relative to `folder` (when given) made absolute and checked."""
    try:
        words = shlex.split(text)
    except ValueError as error:
        raise _Refused(f"{where}: {_shown(text, 80)} cannot be split into flags "
                       f"({error})") from None
    options: Dict[str, str] = {}
    for word in words:
        name, _, value = word.lstrip("-").partition("=")
        if not word.startswith("--") or not name:
            raise _Refused(f"{where}: {_shown(word)} is not --name=value")
        if "=" not in word:
            value, name = ("false", name[2:]) if name.startswith("no") and \
                name[2:] in known else ("true", name)
        if name not in known:
            raise _Refused(f"{where}: --{name} is not an option of dsr.register")
        if name in options:
            raise _Refused(f"{where}: --{name} is given twice")
        if name == "init" and folder is not None and _init_is_file(value):
            value = _file(value, folder, f"{where}: --init")
        options[name] = value
    return options


def _read_text(path: str) -> str:
    """The manifest's text: a regular file (a FIFO or device would never end) of at most
    _MAX_MANIFEST_BYTES, UTF-8 (a byte-order mark is skipped)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise ManifestError(f"{path}: no such file") from None
    except OSError as error:
        raise ManifestError(f"{path}: cannot open the manifest ({error.strerror})") from None
    status = os.fstat(fd)
    if not stat.S_ISREG(status.st_mode):
        os.close(fd)
        raise ManifestError(f"{path}: {_kind(status.st_mode)} (a manifest is a CSV file)")
    limit = f"more than the {_MAX_MANIFEST_BYTES >> 20} MiB a manifest may have"
    if status.st_size > _MAX_MANIFEST_BYTES:
        os.close(fd)
        raise ManifestError(f"{path}: {status.st_size} bytes, {limit}")
    with os.fdopen(fd, "rb") as f:
        try:
            data = f.read(_MAX_MANIFEST_BYTES + 1)
        except OSError as error:
            raise ManifestError(f"{path}: cannot read the manifest ({error.strerror})") from None
    if len(data) > _MAX_MANIFEST_BYTES:
        raise ManifestError(f"{path}: grew to {limit} while it was read")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise ManifestError(f"{path}: not UTF-8 text (byte {error.start}: "
                            f"{data[error.start:error.start + 1]!r})") from None


def _rows(path: str) -> Tuple[List[str], List[Tuple[int, List[str]]]]:
    """The header (checked: every column known, once) and the rows that are not blank, each
    with the line it starts on."""
    reader = csv.reader(io.StringIO(_read_text(path), newline=""))
    rows = []
    try:
        header = [cell.strip() for cell in next(reader, [])]
        line = reader.line_num
        for cells in reader:
            start, line = line + 1, reader.line_num
            if any(cell.strip() for cell in cells):
                rows.append((start, cells))
    except csv.Error as error:
        raise ManifestError(f"{path}: line {reader.line_num}: not CSV ({error})") from None
    if not any(header):
        raise ManifestError(f"{path}: no header (its first line names the columns: "
                            f"{','.join(_COLUMNS)})")
    for i, column in enumerate(header):
        if not column:
            raise ManifestError(f"{path}: column {i + 1} of the header has no name")
        if column in header[:i]:
            raise ManifestError(f"{path}: column {column!r} is given twice in the header "
                                f"(columns {header.index(column) + 1} and {i + 1})")
    for column in ("study", "images"):
        if column not in header:
            raise ManifestError(f"{path}: no column '{column}' (the header has {header})")
    unknown = [c for c in header if c not in _COLUMNS]
    if unknown:
        raise ManifestError(f"{path}: unknown column {unknown[0]!r} (columns: {_COLUMNS})")
    if not rows:
        raise ManifestError(f"{path}: no study")
    return header, rows


def _study_id(text: str, where: str) -> str:
    study = text.strip()
    where = f"{where}, column study"
    if not study:
        raise _Refused(f"{where}: no study id")
    if len(study) > _MAX_ID_CHARACTERS:
        raise _Refused(f"{where}: {_shown(study)} is longer than {_MAX_ID_CHARACTERS} "
                       "characters (it names the output folder)")
    if not _STUDY_ID.match(study):
        raise _Refused(f"{where}: {_shown(study)} is not an id of letters, digits, '.', '_' "
                       "or '-' starting with a letter or digit (it names the output folder)")
    if study.lower() in _OWN_FILES:
        raise _Refused(f"{where}: {study!r} is the name of a file the cohort writes in "
                       f"--out_dir ({', '.join(_OWN_FILES)}); name the study otherwise")
    return study


def _study(header: List[str], cells: List[str], row: int, path: str, folder: str,
           known: Sequence[str]) -> Study:
    """One row as a Study, its own checks made (not those between rows). _Refused else."""
    where = f"{path}: row {row}"
    if len(cells) > len(header):
        raise _Refused(f"{where}: {len(cells)} cells, but the header has {len(header)} "
                       "columns (a cell that holds a comma is quoted: \"--phases=0,2\")")
    values = dict(zip(header, cells))
    study = _study_id(values.get("study", ""), where)
    images = _paths(values.get("images", ""), folder, f"{where}, column images")
    if len(images) < 2:
        raise _Refused(f"{where}, column images: need at least 2 images, got {len(images)}")
    masks = _paths(values.get("masks", ""), folder, f"{where}, column masks")
    if masks and len(masks) != len(images):
        raise _Refused(f"{where}, column masks: {len(masks)} masks for {len(images)} images")
    gt = _paths(values.get("gt_poses", ""), folder, f"{where}, column gt_poses")
    if len(gt) > 1:
        raise _Refused(f"{where}, column gt_poses: {len(gt)} files; a study has one "
                       "ground-truth poses file")
    options = _options(values.get("options", ""), f"{where}, column options", known, folder)
    return Study(study, images, masks, gt[0] if gt else None, options, row)


def _read(path: str, known: Sequence[str]) -> Tuple[List[Study], List[_Refusal]]:
    """The manifest's studies and its refused rows (each row's own checks and a unique id;
    ManifestError for the manifest as a whole)."""
    header, rows = _rows(path)
    folder = os.path.dirname(os.path.abspath(path))
    column = header.index("study")
    ids = [cells[column].strip() if len(cells) > column else "" for _, cells in rows]
    # An id given twice: which row is meant is not known, so none of them runs. Case is
    # ignored (ids that differ only in it are one folder on some file systems).
    same: Dict[str, List[int]] = {}
    for i, study in enumerate(ids):
        if study:
            same.setdefault(study.lower(), []).append(i)
    studies: List[Study] = []
    refused: List[_Refusal] = []
    for i, (row, cells) in enumerate(rows):
        group = same.get(ids[i].lower(), [])
        try:
            if len(group) > 1:
                given = " and ".join(str(rows[g][0]) for g in group)
                cases = "" if len({ids[g] for g in group}) == 1 else \
                    ", as " + " and ".join(repr(ids[g]) for g in group) + \
                    ": ids that differ only in case name one folder where case is ignored"
                raise _Refused(f"{path}: row {row}, column study: {_shown(ids[i])} is given "
                               f"twice (rows {given}{cases})")
            studies.append(_study(header, cells, row, path, folder, known))
        except _Refused as why:
            refused.append(_Refusal(ids[i], row, str(why)))
    return studies, refused


def _summary(refused: List[_Refusal], running: int) -> str:
    """One line for the refused rows: the first's reason, the others' rows."""
    first, others = refused[0], [r.row for r in refused[1:]]
    text = first.reason
    if others:
        shown = ", ".join(map(str, others[:8])) + (", ..." if len(others) > 8 else "")
        text += f"; {len(others)} more {'row' if len(others) == 1 else 'rows'} refused " \
                f"({'row' if len(others) == 1 else 'rows'} {shown})"
    if running:
        text += f"; the other {running} {'study runs' if running == 1 else 'studies run'} " \
                "(the refused rows are in results.csv with their reasons)"
    return text


class _ListFiles:
    """--images/--masks values for dsr_register's checks: the paths joined by commas, or,
    when one holds a comma, an @LIST file in a temporary folder."""

    def __init__(self) -> None:
        self._folder: Optional[tempfile.TemporaryDirectory] = None
        self._count = 0

    def value(self, paths: List[str]) -> str:
        if not any("," in p for p in paths):
            return ",".join(paths)
        if self._folder is None:
            self._folder = tempfile.TemporaryDirectory(prefix="dsr-cohort-")
        self._count += 1
        listing = os.path.join(self._folder.name, f"list_{self._count}.txt")
        with open(listing, "w", encoding="utf-8") as f:
            f.write("\n".join(paths) + "\n")
        return "@" + listing

    def close(self) -> None:
        if self._folder is not None:
            self._folder.cleanup()


def _files_of(study: Study, options: Dict[str, str]) -> List[str]:
    """Every file a study reads: its frames and masks, its ground truth, an --init file."""
    init = {**options, **study.options}.get("init")
    return study.images + study.masks + ([study.gt_poses] if study.gt_poses else []) + \
        ([init] if init and _init_is_file(init) else [])


def _identity(path: str) -> Optional[Tuple[int, int]]:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def _check_study(study: Study, out_dir: Optional[str], options: Dict[str, str],
                 manifest: str, lists: _ListFiles) -> None:
    """What would refuse `study` once running, checked before any study runs: its folder in
    OUT (a folder of its own, no symlink out of OUT), dsr_register's checks of its options
    and files (and its outputs, with `out_dir`), its poses files' contents, and no output of
    the runner on an input. _Refused naming the manifest's row otherwise."""
    from . import _core  # noqa: PLC0415

    where = f"{manifest}: row {study.row}"
    folder = os.path.join(out_dir or "", study.study)
    if out_dir is not None:
        for path in (folder, os.path.join(folder, "report")):
            if os.path.islink(path):
                raise _Refused(f"{where}: {path} is a symlink (to {os.readlink(path)}); a "
                               "study's outputs stay in --out_dir: remove the symlink")
        if os.path.lexists(folder) and not os.path.isdir(folder):
            raise _Refused(f"{where}: {folder} exists and is not a folder (it is kept): move "
                           "it away or name the study otherwise")
    merged = {**options, **study.options}
    try:
        _core.check_register_options(list(merged.items()))
    except ValueError as error:
        raise _Refused(f"{where}, column options: {error}") from None
    flags = [("images", lists.value(study.images))]
    if out_dir is not None:
        flags.append(("report_dir", os.path.join(folder, "report")))
    if study.masks:
        flags.append(("masks", lists.value(study.masks)))
    if study.gt_poses:
        flags.append(("gt_poses", study.gt_poses))
    if out_dir is not None and os.path.isdir(folder):  # (the plan needs its folder)
        flags.append(("out_poses", os.path.join(folder, "poses.json")))
    try:
        _core.check_register_files(flags + list(merged.items()))
    except ValueError as error:
        raise _Refused(f"{where}: {error}") from None
    init = merged.get("init")
    for flag, poses in (("gt_poses", study.gt_poses),
                        ("init", init if init and _init_is_file(init) else None)):
        if poses:
            try:
                _core.read_poses(poses, len(study.images))
            except ValueError as error:
                raise _Refused(f"{where}: --{flag}={poses}: {error}") from None
    inputs = {_identity(p): p for p in _files_of(study, options)}
    for name in _STUDY_FILES if out_dir is not None else ():
        output = os.path.join(folder, name)
        if _identity(output) in inputs and _identity(output) is not None:
            raise _Refused(f"{where}: {output}, which the cohort writes, is the input "
                           f"{inputs[_identity(output)]}: inputs are never overwritten")


def _digest(study: Study, options: Dict[str, str]) -> str:
    """What a study's outputs depend on: its files (path, size, time; the ground truth and
    an --init file too) and options."""
    files = []
    for path in _files_of(study, options):
        st = os.stat(path)
        files.append((path, st.st_size, st.st_mtime_ns))
    merged = {**options, **study.options}
    text = json.dumps({"files": files, "options": merged}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def read_manifest(path: str) -> List[Study]:
    """The studies of a manifest, every row checked as run() checks it before any work (the
    columns, a unique id that names a folder, every file a readable regular file, one mask
    per image, dsr_register's checks of the row's files and options): ManifestError naming
    the first bad row (and how many others there are) unless every row is good."""
    known = _register_options()
    studies, refused = _read(path, known)
    lists = _ListFiles()
    try:
        for s in studies:
            try:
                _check_study(s, None, {}, path, lists)
            except _Refused as why:
                refused.append(_Refusal(s.study, s.row, str(why)))
    finally:
        lists.close()
    if refused:
        raise ManifestError(_summary(sorted(refused, key=lambda r: r.row), 0))
    return studies


def _read_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _read_umask()  # once, at import (os.umask sets it too: not from threads)


def _temporary(path: str) -> Tuple[int, str]:
    """A new hidden temporary file beside `path`, with the permissions a new file gets
    (mkstemp's are the owner's alone)."""
    fd, temp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".tmp-",
                                dir=os.path.dirname(path))
    os.fchmod(fd, 0o666 & ~_UMASK)
    return fd, temp


def _write_atomically(path: str, text: str) -> None:
    fd, temp = _temporary(path)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, path)
    except BaseException:
        if os.path.exists(temp):
            os.remove(temp)
        raise


class _Reserved:
    """Space for a file of the cohort, taken before the studies run so that the file can be
    written when they have filled the disk: a hidden temporary file of `size` bytes beside
    `path` (posix_fallocate), written over and renamed into place at the end. Without the
    space (a full disk, a file system without fallocate) the file is written as usual."""

    def __init__(self, path: str, size: int) -> None:
        self.path = path
        self.temp: Optional[str] = None
        try:
            fd, temp = _temporary(path)
        except OSError:
            return
        try:
            os.posix_fallocate(fd, 0, size)
            self.temp = temp
        except (OSError, AttributeError):
            os.remove(temp)
        finally:
            os.close(fd)

    def write(self, text: str) -> None:
        if self.temp is None:
            return _write_atomically(self.path, text)
        data = text.encode("utf-8")
        with open(self.temp, "r+b") as f:
            f.write(data)
            f.truncate(len(data))
            f.flush()
            os.fsync(f.fileno())
        os.replace(self.temp, self.path)
        self.temp = None
        return None

    def discard(self) -> None:
        if self.temp is not None and os.path.exists(self.temp):
            os.remove(self.temp)
        self.temp = None


def _finished(folder: str, study: str, digest: str) -> Optional[Dict[str, Any]]:
    """The study's record when it is complete and verified for `digest`, else None."""
    try:
        with open(os.path.join(folder, "record.json"), encoding="utf-8") as f:
            record = json.load(f)
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("study") != study or \
            record.get("digest") != digest or record.get("retry"):
        return None
    if record.get("status") == "ok":
        try:
            with open(os.path.join(folder, "poses.json"), encoding="utf-8") as f:
                json.load(f)
        except (OSError, ValueError):
            return None
    return record


def _flag(name: str, value: Any) -> str:
    if isinstance(value, bool):
        value = "true" if value else "false"
    return f"--{name}={value}"


def _study_folder(out_dir: str, study: str) -> str:
    """OUT/<study>, made; OSError when it or its report folder is a symlink (a study's
    outputs stay in OUT) or it is not a folder."""
    folder = os.path.join(out_dir, study)
    os.makedirs(folder, exist_ok=True)
    for path in (folder, os.path.join(folder, "report")):
        if os.path.islink(path):
            raise OSError(f"{path} is a symlink; a study's outputs stay in --out_dir")
    return folder


def _register_study(study: Study, out_dir: str, options: Dict[str, Any],
                    digest: str) -> Dict[str, Any]:
    """On a worker: the study registered as dsr_register registers it (its poses file,
    report and transforms, byte for byte), then its record written. A record that cannot
    be written (a full disk) is returned failed: the study is done again by a rerun."""
    from dsr import _core  # noqa: PLC0415 (in the worker process)

    record: Dict[str, Any] = {"study": study.study, "digest": digest, "gt_poses": study.gt_poses}
    start = time.perf_counter()
    try:
        folder = _study_folder(out_dir, study.study)
    except OSError as error:
        return _unwritten(record, error)
    _remove_temporaries(folder)
    try:
        # The frames as @LIST files (a path may contain a comma), kept with the outputs.
        flags = []
        for kind, paths in (("images", study.images), ("masks", study.masks)):
            if paths:
                listing = os.path.join(folder, f"{kind}.txt")
                _write_atomically(listing, "\n".join(paths) + "\n")
                flags.append(_flag(kind, "@" + listing))
        flags += [_flag("out_poses", os.path.join(folder, "poses.json")),
                  _flag("report_dir", os.path.join(folder, "report")), "--progress=false"]
        if study.gt_poses:
            flags.append(_flag("gt_poses", study.gt_poses))
        flags += [_flag(k, v) for k, v in {**options, **study.options}.items()]
        out = _core.register_files([tuple(f[2:].split("=", 1)) for f in flags])
        tre = out.get("predicted_tre_mm", [])[1:]
        record.update(status="ok", reason="", iterations=out["iterations"],
                      recoveries=out["recoveries"], tre_mean_mm=out.get("tre_mean_mm"),
                      tre_max_mm=out.get("tre_max_mm"),
                      predicted_tre_mm=sum(tre) / len(tre) if tre else None,
                      report=os.path.relpath(out["report_index"], out_dir))
        _write_atomically(os.path.join(folder, "log.txt"), "\n".join(out["lines"]) + "\n")
    except OSError as error:  # an output not written (dsr_register's or the runner's)
        _unwritten(record, error)
    except (ValueError, TypeError, MemoryError, _core.RegistrationError) as error:
        record.update(status="failed", reason=f"{type(error).__name__}: {error}")
        with contextlib.suppress(OSError):  # (the record says why)
            _write_atomically(os.path.join(folder, "log.txt"), record["reason"] + "\n")
    record["seconds"] = round(time.perf_counter() - start, 3)
    record["peak_memory_mb"] = round(_peak_memory_mb(), 1)
    if record.get("output_error"):
        return record  # (no record.json: a rerun does the study again)
    try:
        _write_atomically(os.path.join(folder, "record.json"),
                          json.dumps(record, indent=1) + "\n")
    except OSError as error:
        _unwritten(record, error)
    return record


def _unwritten(record: Dict[str, Any], error: OSError) -> Dict[str, Any]:
    """`record` as a study that could not write its outputs (a full disk): failed, never
    ok, and done again by a rerun (it has no record.json)."""
    why = f"{error.strerror}: {error.filename}" if error.strerror and error.filename else \
        str(error.strerror or error)
    record.update(status="failed", retry=True, output_error=True,
                  reason=f"could not write its outputs ({why}); a rerun does it again")
    return record


def _peak_memory_mb() -> float:
    import resource  # noqa: PLC0415

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


_RESULT_COLUMNS = ("study", "status", "reason", "seconds", "iterations", "recoveries",
                   "peak_memory_mb", "predicted_tre_mm", "tre_mean_mm", "tre_max_mm", "gt_poses",
                   "report")
_ORDER = {"refused": 0, "failed": 1}


def _sorted(records: List[Dict[str, Any]]) -> List[Dict[str, Any]]:
    """Refused rows first, then failed studies, then the others; by id within each."""
    return sorted(records, key=lambda r: (_ORDER.get(r.get("status"), 2), str(r["study"]),
                                          r.get("row", 0)))


def _results_text(records: List[Dict[str, Any]]) -> str:
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(_RESULT_COLUMNS)
    for record in _sorted(records):
        writer.writerow(["" if record.get(c) is None else str(record.get(c))
                         for c in _RESULT_COLUMNS])
    return text.getvalue()


def _write_parquet(out_dir: str, records: List[Dict[str, Any]]) -> None:
    try:  # Parquet too, when pyarrow is installed
        import pyarrow  # noqa: PLC0415
        import pyarrow.parquet  # noqa: PLC0415
    except ImportError:
        return
    rows = _sorted(records)
    table = pyarrow.table({c: [None if r.get(c) is None else str(r.get(c)) for r in rows]
                           for c in _RESULT_COLUMNS})
    fd, temp = _temporary(os.path.join(out_dir, "results.parquet"))
    os.close(fd)
    try:
        pyarrow.parquet.write_table(table, temp)
        os.replace(temp, os.path.join(out_dir, "results.parquet"))
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(temp)
        raise


_SORT_SCRIPT = """
for (const th of document.querySelectorAll('th')) th.addEventListener('click', () => {
  const table = th.closest('table'), i = [...th.parentNode.children].indexOf(th);
  const rows = [...table.tBodies[0].rows], up = th.dataset.up !== '1';
  const key = r => { const t = r.cells[i].dataset.v ?? r.cells[i].textContent;
                     return isNaN(parseFloat(t)) ? t : parseFloat(t); };
  rows.sort((a, b) => (key(a) > key(b) ? 1 : key(a) < key(b) ? -1 : 0) * (up ? 1 : -1));
  th.dataset.up = up ? '1' : '0';
  rows.forEach(r => table.tBodies[0].appendChild(r));
});
"""


def _index_text(out_dir: str, records: List[Dict[str, Any]]) -> str:
    """OUT/index.html: the results, refused and failed studies first, sortable by any
    column (click its header), each study with thumbnails of its report's panorama and pair
    overlay."""
    import html  # noqa: PLC0415

    columns = ("study", "status", "reason", "seconds", "iterations", "predicted_tre_mm",
               "tre_mean_mm", "peak_memory_mb")
    def text(value: Any) -> str:
        if value is None:
            return ""
        return f"{value:.4g}" if isinstance(value, float) else str(value)

    rows = []
    for r in _sorted(records):
        cells = [f"<td>{html.escape(text(r.get(c)))}</td>" for c in columns]
        pictures = ""
        report = r.get("report")
        if report:
            folder = os.path.dirname(report)
            pictures = "".join(
                f'<a href="{html.escape(report)}"><img src="{html.escape(folder + "/" + p)}" '
                f'height="96" alt="{p}"></a>'
                for p in ("panorama_slices.png", "pair_00_01.png")
                if os.path.exists(os.path.join(out_dir, folder, p)))
        rows.append(f'<tr class="{html.escape(str(r.get("status")))}">' + "".join(cells) +
                    f'<td class="pictures">{pictures}</td></tr>')
    failed = sum(r.get("status") == "failed" for r in records)
    refused = sum(r.get("status") == "refused" for r in records)
    title = f"{len(records)} studies, {failed} failed" + (f", {refused} refused" if refused
                                                          else "")
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>dsr cohort</title>"
            "<style>body{font-family:sans-serif}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:4px}th{cursor:pointer}"
            "tr.failed,tr.refused{background:#fdd}td.pictures{white-space:nowrap}</style>"
            f"</head><body><h1>dsr cohort: {title}</h1>"
            "<table><thead><tr>" + "".join(f"<th>{c}</th>" for c in columns) +
            "<th>pictures</th></tr></thead><tbody>\n" + "\n".join(rows) +
            f"\n</tbody></table><script>{_SORT_SCRIPT}</script></body></html>\n")


@contextlib.contextmanager
def _client(workers: int, threads_per_worker: int, memory_limit: Any,
            scheduler: Optional[str]) -> Iterator[Any]:
    """A client of the cluster at `scheduler`, or of an embedded LocalCluster (closed with
    it). CohortError when it cannot be had (within Dask's connect timeout)."""
    import dask  # noqa: PLC0415
    from distributed import Client, LocalCluster  # noqa: PLC0415

    # A study whose worker dies is retried once on another worker, then recorded as failed.
    dask.config.set({"distributed.scheduler.allowed-failures": 1})
    if scheduler:
        try:
            client = Client(scheduler)
        except (OSError, TimeoutError, ValueError, TypeError) as error:
            raise CohortError(f"--scheduler={scheduler}: cannot connect ({error})") from None
        with client:
            yield client
        return
    # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which makes glibc map and
    # unmap the solver's per-iteration buffers: 5x the page faults and studies 10-20% slower
    # (bench/cohort.py). The workers of the embedded cluster keep glibc's default.
    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    dask.config.set({"distributed.nanny.pre-spawn-environ": environ})
    try:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker,
                               processes=True, memory_limit=memory_limit, dashboard_address=":0")
    except (OSError, TimeoutError, RuntimeError, ValueError) as error:
        raise CohortError(f"cannot start a local cluster of {workers} workers "
                          f"({type(error).__name__}: {error})") from None
    with cluster, Client(cluster) as client:
        yield client


def _count(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise CohortError(f"--{name}={value}: must be a whole number >= 1")
    return int(value)


def _memory_limit(value: Any) -> Any:
    """Dask's memory limit per worker: "auto" (the machine's memory shared evenly), or a
    size (parsed by dask.utils.parse_bytes: "4GB", "1.5GiB"; a bare number is bytes) of at
    least _MIN_MEMORY_LIMIT."""
    from dask.utils import format_bytes, parse_bytes  # noqa: PLC0415

    if value == "auto":
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        size = int(value)
    else:
        try:
            size = parse_bytes(str(value))
        except (ValueError, TypeError):
            raise CohortError(f"--memory_limit={value}: not a size (e.g. 4GB, 1.5GiB) or "
                              "auto") from None
    if size < _MIN_MEMORY_LIMIT:
        raise CohortError(
            f"--memory_limit={value}: {format_bytes(max(size, 0))} per worker is less than "
            f"{format_bytes(_MIN_MEMORY_LIMIT)}, which a worker process needs before any "
            "study (Python, Dask and dsr take about 140 MiB)")
    return size


def _usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def _shared_options(options: Dict[str, Any], known: Sequence[str],
                    threads_per_worker: int) -> Dict[str, str]:
    """The options for every study as text; an --init file relative to the working folder
    made absolute and checked. CohortError for one dsr.register does not take."""
    from . import _flag_value  # noqa: PLC0415

    shared = {"num_threads": str(threads_per_worker)}
    for name, value in options.items():
        if name not in known:
            raise CohortError(f"options: --{name} is not an option of dsr.register")
        shared[name] = _flag_value(value)
    init = shared.get("init")
    if init and _init_is_file(init):
        try:
            shared["init"] = _file(init, os.getcwd(), "options: --init")
        except _Refused as why:
            raise CohortError(str(why)) from None
    try:
        from . import _core  # noqa: PLC0415

        _core.check_register_options(list(shared.items()))
    except ValueError as error:
        raise CohortError(f"options: {error}") from None
    return shared


def _check_out_dir(out_dir: str, manifest: str) -> None:
    """OUT: a folder (or one to make) where this process may write, not the manifest."""
    if os.path.lexists(out_dir) and not os.path.exists(out_dir):
        raise CohortError(f"--out_dir={out_dir}: is a symlink to a missing folder "
                          f"({os.readlink(out_dir)})")
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        same = os.path.exists(manifest) and os.path.samefile(out_dir, manifest)
        raise CohortError(f"--out_dir={out_dir}: " + (
            "is the manifest itself" if same else "is a file, not a folder") +
            "; give a folder for the outputs")
    existing = os.path.abspath(out_dir)
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise CohortError(f"--out_dir={out_dir}: cannot be made ({existing} is not a folder)")
    if not os.access(existing, os.W_OK | os.X_OK):
        read_only = os.statvfs(existing).f_flag & os.ST_RDONLY
        what = "is on a read-only file system" if read_only else "is not writable"
        raise CohortError(f"--out_dir={out_dir}: " + (
            what if existing == os.path.abspath(out_dir) else f"cannot be made ({existing} "
            f"{what})"))
    for name in _OWN_FILES + (_LOCK_FILE,):
        output = os.path.join(out_dir, name)
        if os.path.exists(output) and os.path.samefile(output, manifest):
            raise CohortError(f"--manifest={manifest} is {output}, which the cohort writes: "
                              "inputs are never overwritten; copy it elsewhere")


@contextlib.contextmanager
def _locked(out_dir: str, manifest: str) -> Iterator[None]:
    """OUT's lock (flock on OUT/.dsr-cohort.lock) for the cohort's run, its holder named in
    the file. CohortError when another process holds it."""
    import fcntl  # noqa: PLC0415

    path = os.path.join(out_dir, _LOCK_FILE)
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    except OSError as error:
        raise CohortError(f"--out_dir={out_dir}: cannot write its lock file {_LOCK_FILE} "
                          f"({error.strerror})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 1000, 0).decode("utf-8", "replace").strip()
            raise CohortError(f"--out_dir={out_dir}: another dsr.cohort runs on this folder ("
                              f"{holder or 'it has just started'}); wait for it to end or give "
                              "another --out_dir") from None
        except OSError as error:
            raise CohortError(f"--out_dir={out_dir}: cannot lock {_LOCK_FILE} "
                              f"({error.strerror})") from None
        holder = (f"pid {os.getpid()} on {socket.gethostname()}, since "
                  f"{datetime.datetime.now().isoformat(timespec='seconds')}, "
                  f"--manifest={os.path.abspath(manifest)}")
        with contextlib.suppress(OSError):  # a full disk: the lock holds all the same
            os.ftruncate(fd, 0)
            os.pwrite(fd, (holder + "\n").encode("utf-8"), 0)
        yield
    finally:
        os.close(fd)  # (the lock ends with its file descriptor)


def _remove_temporaries(folder: str, owners: Optional[Tuple[str, ...]] = None) -> None:
    """The hidden temporary files (".name.tmp-...", the runner's writes and dsr_register's)
    that a killed run left in `folder`; with `owners`, only those of these files. OUT's own
    (the lock is held), and a study's before it runs again and when it is recorded as
    failed: one worker runs a study at a time (Dask retries it only once the worker running
    it has died) and the cohort's lock keeps other cohorts out."""
    with contextlib.suppress(OSError):
        with os.scandir(folder) as entries:
            for entry in entries:
                name = entry.name
                ours = any(name.startswith(f".{own}.tmp-") for own in owners) if owners else \
                    name.startswith(".") and ".tmp-" in name
                if ours and entry.is_file(follow_symlinks=False):
                    with contextlib.suppress(OSError):
                        os.remove(entry.path)


def run(manifest: str, out_dir: str, *, workers: int = 2, threads_per_worker: int = 1,
        memory_limit: Any = "auto", scheduler: Optional[str] = None, force: bool = False,
        progress: bool = True, _on_start: Optional[Callable[[Any], Any]] = None,
        **options: Any) -> List[Dict[str, Any]]:
    """Registers every study of `manifest` into `out_dir` (see the module's docstring);
    `options` are dsr.register's for every study. Returns the records, one per row of the
    manifest in its order (a refused row's with status "refused" and the reason), as written
    to OUT/results.csv; the refused rows are logged (logger "dsr.cohort") before any study
    runs. Before any work: CohortError for bad arguments or an OUT that cannot be used
    (another cohort runs on it), ManifestError for a manifest none of whose rows can run.
    OSError when results.csv or index.html cannot be written (the studies' records are in
    their folders). `_on_start(client)` (for tests) is called once the studies are
    submitted."""
    import distributed  # noqa: F401,PLC0415 (needed: an ImportError before any work)

    workers = _count("workers", workers)
    threads_per_worker = _count("threads_per_worker", threads_per_worker)
    cpus = _usable_cpus()
    if scheduler is None and workers * threads_per_worker > _MAX_THREADS_PER_CPU * cpus:
        raise CohortError(f"--workers={workers} --threads_per_worker={threads_per_worker}: "
                          f"more than {_MAX_THREADS_PER_CPU} threads for each of the {cpus} "
                          "CPUs here, which only slows the studies down")
    memory_limit = _memory_limit(memory_limit)
    known = _register_options()
    shared = _shared_options(options, known, threads_per_worker)
    _check_out_dir(out_dir, manifest)
    out = os.path.abspath(out_dir)
    studies, refused = _read(manifest, known)
    good: List[Study] = []
    lists = _ListFiles()
    try:
        for s in studies:
            try:
                _check_study(s, out, shared, manifest, lists)
                s.digest = _digest(s, shared)
                good.append(s)
            except (_Refused, OSError) as why:
                refused.append(_Refusal(s.study, s.row, str(why)))
    finally:
        lists.close()
    refused.sort(key=lambda r: r.row)
    if not good:
        raise ManifestError(_summary(refused, 0))
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as error:
        raise CohortError(f"--out_dir={out_dir}: cannot make the folder "
                          f"({error.strerror})") from None
    with _locked(out, manifest):
        if refused:
            _LOG.error(_summary(refused, len(good)))
        _remove_temporaries(out, _OWN_FILES)
        # Room for the results (a reason or path can be long) before the studies fill it.
        size = 16384 + 1024 * (len(good) + len(refused))
        reserved = {name: _Reserved(os.path.join(out, name), size)
                    for name in ("results.csv", "index.html")}
        try:
            records = _run(good, out, shared, workers, threads_per_worker, memory_limit,
                           scheduler, force, progress, _on_start, len(refused))
            return _finish(out_dir, out, reserved, good, refused, records)
        finally:
            for r in reserved.values():
                r.discard()


def _run(studies: List[Study], out: str, options: Dict[str, str], workers: int,
         threads_per_worker: int, memory_limit: Any, scheduler: Optional[str], force: bool,
         progress: bool, on_start: Optional[Callable[[Any], Any]],
         refused: int) -> Dict[str, Dict[str, Any]]:
    """The records of `studies`: the finished ones as they are, the others run."""
    from distributed import as_completed  # noqa: PLC0415
    from distributed.scheduler import KilledWorker  # noqa: PLC0415

    records: Dict[str, Dict[str, Any]] = {}
    for s in studies:
        done = None if force else _finished(os.path.join(out, s.study), s.study, s.digest)
        if done is not None:
            records[s.study] = done
    todo = [s for s in studies if s.study not in records]
    if not todo:
        return records
    with _client(workers, threads_per_worker, memory_limit, scheduler) as client:
        futures = {client.submit(_register_study, s, out, options, s.digest,
                                 key=f"dsr-study-{s.study}-{s.digest[:8]}", pure=False): s
                   for s in todo}
        if on_start is not None:
            on_start(client)
        bar = _progress_bar(len(studies), len(records)) if progress else None
        running = len(todo)
        for future in as_completed(futures):
            running -= 1
            study = futures[future]
            try:
                records[study.study] = future.result()
            except KilledWorker:
                records[study.study] = _record_failure(
                    out, study, "the worker process running it died twice (killed or out of "
                    "memory)")
            except Exception as error:  # a study's, never the cohort's end
                records[study.study] = _record_failure(
                    out, study, f"{type(error).__name__}: {error}")
            if bar is not None:
                failed = sum(r.get("status") == "failed" for r in records.values())
                bar.set_postfix(failed=failed, refused=refused, running=running)
                bar.update(1)
        if bar is not None:
            bar.close()
    return records


def _finish(out_dir: str, out: str, reserved: Dict[str, _Reserved], studies: List[Study],
            refused: List[_Refusal], records: Dict[str, Dict[str, Any]]
            ) -> List[Dict[str, Any]]:
    """The records in the manifest's order, written to results.csv, index.html (and
    results.parquet); OSError naming the first that could not be written."""
    rows = sorted([(s.row, records[s.study]) for s in studies] +
                  [(r.row, r.record()) for r in refused], key=lambda pair: pair[0])
    ordered = [record for _, record in rows]
    written, failure = [], None
    for name, write in (("results.csv", lambda: reserved["results.csv"].write(
                            _results_text(ordered))),
                        ("index.html", lambda: reserved["index.html"].write(
                            _index_text(out, ordered))),
                        ("results.parquet", lambda: _write_parquet(out, ordered))):
        try:
            write()
            written.append(name)
        except OSError as error:
            failure = failure or (name, error)
    if failure is not None:
        name, error = failure
        raise OSError(error.errno, f"{os.path.join(out_dir, name)}: cannot write it "
                      f"({error.strerror or error}); " + (
                          f"{' and '.join(written)} written" if written else "nothing written") +
                      "; every study's record.json is in its folder")
    return ordered


def _record_failure(out_dir: str, study: Study, reason: str) -> Dict[str, Any]:
    """A study whose workers died (or whose task failed): recorded as failed, and done again
    by a rerun (the cause was the machine, not the study)."""
    record = {"study": study.study, "digest": study.digest, "status": "failed",
              "reason": reason, "gt_poses": study.gt_poses, "retry": True}
    with contextlib.suppress(OSError):  # (a full disk: no record, so a rerun does it again)
        folder = _study_folder(out_dir, study.study)
        _remove_temporaries(folder)
        _write_atomically(os.path.join(folder, "record.json"),
                          json.dumps(record, indent=1) + "\n")
    return record


def _progress_bar(total: int, done: int):
    try:
        from tqdm.auto import tqdm  # noqa: PLC0415
    except ImportError:
        return None
    return tqdm(total=total, initial=done, unit="study", desc="dsr cohort")


class _Parser(argparse.ArgumentParser):
    """argparse's parser, its errors one line (CohortError) rather than usage and exit."""

    def error(self, message: str):  # type: ignore[override]
        raise CohortError(message)


def main(argv: Optional[List[str]] = None) -> int:
    """python -m dsr.cohort --manifest=FILE --out_dir=DIR [--workers=N] [--force] [--flags]

    Exit status: 0 when every row ran (studies may have failed: see results.csv), 2 for bad
    arguments, a manifest that cannot run or refused rows (the others ran), 1 when studies
    could not write their outputs or the results could not be written (a full disk)."""
    parser = _Parser(prog="python -m dsr.cohort", description=__doc__.split("\n\n")[0])
    parser.add_argument("--manifest", required=True)
    parser.add_argument("--out_dir", required=True)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--threads_per_worker", type=int, default=1)
    parser.add_argument("--memory_limit", default="auto")
    parser.add_argument("--scheduler", default=None)
    parser.add_argument("--force", action="store_true")
    parser.add_argument("--no_progress", action="store_true")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("dsr.cohort: error: %(message)s"))
    _LOG.addHandler(handler)
    _LOG.propagate = False
    try:
        args, rest = parser.parse_known_args(argv)
        try:
            shared = _options(" ".join(shlex.quote(r) for r in rest), "options",
                              _register_options())
        except _Refused as why:
            raise CohortError(str(why)) from None
        records = run(args.manifest, args.out_dir, workers=args.workers,
                      threads_per_worker=args.threads_per_worker,
                      memory_limit=args.memory_limit, scheduler=args.scheduler,
                      force=args.force, progress=not args.no_progress, **shared)
    except CohortError as error:
        print(f"dsr.cohort: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        print(f"dsr.cohort: error: {error.strerror or error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("dsr.cohort: interrupted (finished studies keep their records; a rerun does "
              "the others)", file=sys.stderr)
        return 130
    finally:
        _LOG.removeHandler(handler)
        _LOG.propagate = True
    refused = sum(r.get("status") == "refused" for r in records)
    failed = sum(r.get("status") == "failed" for r in records)
    print(f"dsr.cohort: {len(records) - failed - refused} studies registered, {failed} failed"
          + (f", {refused} rows refused" if refused else "") +
          f"; results in {os.path.join(args.out_dir, 'results.csv')}")
    unwritten = [r for r in records if r.get("output_error")]
    if unwritten:
        print(f"dsr.cohort: error: {len(unwritten)} "
              f"{'study' if len(unwritten) == 1 else 'studies'} could not write their outputs "
              f"(first {unwritten[0]['study']}: {unwritten[0]['reason']})", file=sys.stderr)
        return 1
    return 2 if refused else 0


if __name__ == "__main__":
    sys.exit(main())
