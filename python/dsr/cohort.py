"""dsr.cohort: one registration per study of a cohort, on Dask distributed.

A manifest (CSV with a header) names the studies: ``study`` (an id, also its output folder's
name), ``images`` (the frames' paths separated by ``;``, relative to the manifest's folder or
absolute) and optionally ``masks`` (the same form), ``gt_poses`` (a poses file, kept with the
study's record) and ``options`` (per-study flags overriding the shared ones, e.g.
``--photometric=affine``). Each study is one ``dsr.register`` call on a Dask worker process:
an embedded ``LocalCluster`` by default, or an existing cluster (``scheduler=``; e.g. one
dask-jobqueue starts on SLURM or PBS).

Per study, ``OUT/<study>/`` receives ``poses.json`` (written atomically) and then
``record.json``, the study's outcome (``ok`` or ``failed`` with the reason), written last:
a study without a record was never finished and is done again; a study whose record matches
its inputs (file sizes and times) and options is skipped by a rerun (``force=True`` redoes
it). A worker that dies during a study (killed, out of memory) has it retried once on another
worker; a second death records the study as failed (a rerun tries it again).
``OUT/results.csv`` (and ``results.parquet`` with pyarrow installed) has one row per study,
failures first, and ``OUT/index.html`` shows it sortable, with each study's thumbnails
linking to its report.

Usage::

    python -m dsr.cohort --manifest=studies.csv --out_dir=out --workers=2 --max_iterations=50
    dsr.cohort.run("studies.csv", "out", workers=2, max_iterations=50)
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import re
import shlex
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence

__all__ = ["Study", "read_manifest", "run", "main"]

_COLUMNS = ("study", "images", "masks", "gt_poses", "options")
_STUDY_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*\Z")


@dataclass
class Study:
    """One row of a manifest, its paths made absolute."""

    study: str
    images: List[str]
    masks: List[str] = field(default_factory=list)
    gt_poses: Optional[str] = None
    options: Dict[str, str] = field(default_factory=dict)
    row: int = 0


class ManifestError(ValueError):
    """A manifest that cannot be run: one line naming the file, the row and the column."""


def _paths(text: str, folder: str, where: str) -> List[str]:
    paths = []
    for item in (part.strip() for part in text.split(";")):
        if not item:
            continue
        path = item if os.path.isabs(item) else os.path.join(folder, item)
        if not os.path.isfile(path):
            reason = "is a folder" if os.path.isdir(path) else "does not exist"
            raise ManifestError(f"{where}: {item} {reason}")
        if not os.access(path, os.R_OK):
            raise ManifestError(f"{where}: {item} is not readable")
        paths.append(os.path.abspath(path))
    return paths


def _options(text: str, where: str, known: Sequence[str]) -> Dict[str, str]:
    """"--name=value --flag --noflag" as {name: value}, each a dsr.register option."""
    options = {}
    for word in shlex.split(text):
        name, _, value = word.lstrip("-").partition("=")
        if not word.startswith("--") or not name:
            raise ManifestError(f"{where}: '{word}' is not --name=value")
        if "=" not in word:
            value, name = ("false", name[2:]) if name.startswith("no") and \
                name[2:] in known else ("true", name)
        if name not in known:
            raise ManifestError(f"{where}: --{name} is not an option of dsr.register")
        options[name] = value
    return options


def read_manifest(path: str) -> List[Study]:
    """The studies of a manifest, checked before any work: the columns, a unique id that
    names a folder, every file readable, one mask per image. ManifestError otherwise."""
    from . import options as table  # noqa: PLC0415

    known = [name for name, o in table().items() if "python:register" in o["front_ends"]]
    folder = os.path.dirname(os.path.abspath(path))
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames or []
            rows = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise ManifestError(f"{path}: cannot read the manifest ({error})") from error
    for column in ("study", "images"):
        if column not in header:
            raise ManifestError(f"{path}: no column '{column}' (the header has {header})")
    unknown = [c for c in header if c not in _COLUMNS]
    if unknown:
        raise ManifestError(f"{path}: unknown column {unknown[0]!r} (columns: {_COLUMNS})")
    studies: List[Study] = []
    for row, values in enumerate(rows, start=2):
        where = f"{path}: row {row}"
        study = (values.get("study") or "").strip()
        if not _STUDY_ID.match(study):
            raise ManifestError(f"{where}, column study: {study!r} is not an id of letters, "
                                "digits, '.', '_' or '-' (it names the output folder)")
        if any(s.study == study for s in studies):
            raise ManifestError(f"{where}, column study: {study!r} is given twice")
        images = _paths(values.get("images") or "", folder, f"{where}, column images")
        if len(images) < 2:
            raise ManifestError(f"{where}, column images: need at least 2 images, got "
                                f"{len(images)}")
        masks = _paths(values.get("masks") or "", folder, f"{where}, column masks")
        if masks and len(masks) != len(images):
            raise ManifestError(f"{where}, column masks: {len(masks)} masks for "
                                f"{len(images)} images")
        gt = _paths(values.get("gt_poses") or "", folder, f"{where}, column gt_poses")
        studies.append(Study(study, images, masks, gt[0] if gt else None,
                             _options(values.get("options") or "",
                                      f"{where}, column options", known), row))
    if not studies:
        raise ManifestError(f"{path}: no study")
    return studies


def _digest(study: Study, options: Dict[str, Any]) -> str:
    """What a study's outcome depends on: its files (path, size, time) and options."""
    files = [(p, os.stat(p).st_size, os.stat(p).st_mtime_ns)
             for p in study.images + study.masks]
    merged = {k: str(v) for k, v in {**options, **study.options}.items()}
    text = json.dumps({"files": files, "options": merged}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _write_atomically(path: str, text: str) -> None:
    folder = os.path.dirname(path)
    fd, temp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".tmp-", dir=folder)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, path)
    except BaseException:
        if os.path.exists(temp):
            os.remove(temp)
        raise


def _finished(folder: str, digest: str) -> Optional[Dict[str, Any]]:
    """The study's record when it is complete and verified for `digest`, else None."""
    try:
        with open(os.path.join(folder, "record.json")) as f:
            record = json.load(f)
    except (OSError, ValueError):
        return None
    if record.get("digest") != digest or record.get("retry"):
        return None
    if record.get("status") == "ok":
        try:
            with open(os.path.join(folder, "poses.json")) as f:
                json.load(f)
        except (OSError, ValueError):
            return None
    return record


def _flag(name: str, value: Any) -> str:
    if isinstance(value, bool):
        value = "true" if value else "false"
    return f"--{name}={value}"


def _register_study(study: Study, out_dir: str, options: Dict[str, Any],
                    digest: str) -> Dict[str, Any]:
    """On a worker: the study registered as dsr_register registers it (its poses file,
    report and transforms, byte for byte), then its record written."""
    from dsr import _core  # noqa: PLC0415 (in the worker process)

    folder = os.path.join(out_dir, study.study)
    os.makedirs(folder, exist_ok=True)
    record: Dict[str, Any] = {"study": study.study, "digest": digest, "gt_poses": study.gt_poses}
    start = time.perf_counter()
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
    except (ValueError, TypeError, OSError, MemoryError, _core.RegistrationError) as error:
        record.update(status="failed", reason=f"{type(error).__name__}: {error}")
        _write_atomically(os.path.join(folder, "log.txt"), record["reason"] + "\n")
    record["seconds"] = round(time.perf_counter() - start, 3)
    record["peak_memory_mb"] = round(_peak_memory_mb(), 1)
    _write_atomically(os.path.join(folder, "record.json"), json.dumps(record, indent=1) + "\n")
    return record


def _peak_memory_mb() -> float:
    import resource  # noqa: PLC0415

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


_RESULT_COLUMNS = ("study", "status", "reason", "seconds", "iterations", "recoveries",
                   "peak_memory_mb", "predicted_tre_mm", "tre_mean_mm", "tre_max_mm", "gt_poses",
                   "report")


def _write_results(out_dir: str, records: List[Dict[str, Any]]) -> None:
    rows = sorted(records, key=lambda r: (r.get("status") != "failed", r["study"]))
    lines = [",".join(_RESULT_COLUMNS)]
    for record in rows:
        cells = ["" if record.get(c) is None else str(record.get(c)) for c in _RESULT_COLUMNS]
        lines.append(",".join('"' + c.replace('"', '""') + '"' if any(x in c for x in ',"\n')
                              else c for c in cells))
    _write_atomically(os.path.join(out_dir, "results.csv"), "\n".join(lines) + "\n")
    try:  # Parquet too, when pyarrow is installed
        import pyarrow  # noqa: PLC0415
        import pyarrow.parquet  # noqa: PLC0415
    except ImportError:
        return
    table = pyarrow.table({c: [None if r.get(c) is None else str(r.get(c)) for r in rows]
                           for c in _RESULT_COLUMNS})
    fd, temp = tempfile.mkstemp(prefix=".results.parquet.tmp-", dir=out_dir)
    os.close(fd)
    pyarrow.parquet.write_table(table, temp)
    os.replace(temp, os.path.join(out_dir, "results.parquet"))


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


def _write_index(out_dir: str, records: List[Dict[str, Any]]) -> None:
    """OUT/index.html: the results, failures first, sortable by any column (click its
    header), each study with thumbnails of its report's panorama and pair overlay."""
    import html  # noqa: PLC0415

    columns = ("study", "status", "reason", "seconds", "iterations", "predicted_tre_mm",
               "tre_mean_mm", "peak_memory_mb")
    def text(value: Any) -> str:
        if value is None:
            return ""
        return f"{value:.4g}" if isinstance(value, float) else str(value)

    rows = []
    for r in sorted(records, key=lambda r: (r.get("status") != "failed", r["study"])):
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
    page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>dsr cohort</title>"
            "<style>body{font-family:sans-serif}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:4px}th{cursor:pointer}"
            "tr.failed{background:#fdd}td.pictures{white-space:nowrap}</style></head><body>"
            f"<h1>dsr cohort: {len(records)} studies, {failed} failed</h1>"
            "<table><thead><tr>" + "".join(f"<th>{c}</th>" for c in columns) +
            "<th>pictures</th></tr></thead><tbody>\n" + "\n".join(rows) +
            f"\n</tbody></table><script>{_SORT_SCRIPT}</script></body></html>\n")
    _write_atomically(os.path.join(out_dir, "index.html"), page)


def _client(workers: int, threads_per_worker: int, memory_limit: Any, scheduler: Optional[str]):
    import dask  # noqa: PLC0415
    from distributed import Client, LocalCluster  # noqa: PLC0415

    # A study whose worker dies is retried once on another worker, then recorded as failed.
    dask.config.set({"distributed.scheduler.allowed-failures": 1})
    if scheduler:
        return Client(scheduler)
    # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which makes glibc map and
    # unmap the solver's per-iteration buffers: 5x the page faults and studies 10-20% slower
    # (bench/cohort.py). The workers of the embedded cluster keep glibc's default.
    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    dask.config.set({"distributed.nanny.pre-spawn-environ": environ})
    cluster = LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker,
                           processes=True, memory_limit=memory_limit, dashboard_address=":0")
    return Client(cluster)


def run(manifest: str, out_dir: str, *, workers: int = 2, threads_per_worker: int = 1,
        memory_limit: Any = "auto", scheduler: Optional[str] = None, force: bool = False,
        progress: bool = True, _on_start=None, **options: Any) -> List[Dict[str, Any]]:
    """Registers every study of `manifest` into `out_dir` (see the module's docstring);
    `options` are dsr.register's for every study. Returns the records, one per study, as
    written to OUT/results.csv. ManifestError before any work for a bad manifest.
    `_on_start(client)` (for tests) is called once the studies are submitted."""
    from distributed import as_completed  # noqa: PLC0415
    from distributed.scheduler import KilledWorker  # noqa: PLC0415

    studies = read_manifest(manifest)
    os.makedirs(out_dir, exist_ok=True)
    options = {"num_threads": threads_per_worker, **options}
    digests = {s.study: _digest(s, options) for s in studies}
    records = {}
    for s in studies:
        done = None if force else _finished(os.path.join(out_dir, s.study), digests[s.study])
        if done is not None:
            records[s.study] = done
    todo = [s for s in studies if s.study not in records]
    if todo:
        with _client(workers, threads_per_worker, memory_limit, scheduler) as client:
            futures = {client.submit(_register_study, s, out_dir, options, digests[s.study],
                                     key=f"dsr-study-{s.study}-{digests[s.study][:8]}",
                                     pure=False): s for s in todo}
            if _on_start is not None:
                _on_start(client)
            bar = _progress_bar(len(studies), len(records)) if progress else None
            running = len(todo)
            for future in as_completed(futures):
                running -= 1
                study = futures[future]
                try:
                    records[study.study] = future.result()
                except KilledWorker:
                    records[study.study] = _record_failure(
                        out_dir, study, digests[study.study],
                        "the worker process running it died twice (killed or out of memory)")
                if bar is not None:
                    failed = sum(r.get("status") == "failed" for r in records.values())
                    bar.set_postfix(failed=failed, running=running)
                    bar.update(1)
            if bar is not None:
                bar.close()
    ordered = [records[s.study] for s in studies]
    _write_results(out_dir, ordered)
    _write_index(out_dir, ordered)
    return ordered


def _record_failure(out_dir: str, study: Study, digest: str, reason: str) -> Dict[str, Any]:
    """A study whose workers died: recorded as failed, and done again by a rerun (the cause
    was the machine, not the study)."""
    folder = os.path.join(out_dir, study.study)
    os.makedirs(folder, exist_ok=True)
    record = {"study": study.study, "digest": digest, "status": "failed", "reason": reason,
              "gt_poses": study.gt_poses, "retry": True}
    _write_atomically(os.path.join(folder, "record.json"), json.dumps(record, indent=1) + "\n")
    return record


def _progress_bar(total: int, done: int):
    try:
        from tqdm.auto import tqdm  # noqa: PLC0415
    except ImportError:
        return None
    return tqdm(total=total, initial=done, unit="study", desc="dsr cohort")


def main(argv: Optional[List[str]] = None) -> int:
    """python -m dsr.cohort --manifest=FILE --out_dir=DIR [--workers=N] [--force] [--flags]"""
    parser = argparse.ArgumentParser(prog="python -m dsr.cohort",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--manifest", required=True)
    parser.add_argument("--out_dir", required=True)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--threads_per_worker", type=int, default=1)
    parser.add_argument("--memory_limit", default="auto")
    parser.add_argument("--scheduler", default=None)
    parser.add_argument("--force", action="store_true")
    parser.add_argument("--no_progress", action="store_true")
    args, rest = parser.parse_known_args(argv)
    try:
        shared = _options(" ".join(shlex.quote(r) for r in rest), "options",
                          [n for n, o in __import__("dsr").options().items()
                           if "python:register" in o["front_ends"]])
        records = run(args.manifest, args.out_dir, workers=args.workers,
                      threads_per_worker=args.threads_per_worker,
                      memory_limit=args.memory_limit, scheduler=args.scheduler,
                      force=args.force, progress=not args.no_progress, **shared)
    except ManifestError as error:
        print(f"dsr.cohort: error: {error}", file=sys.stderr)
        return 2
    failed = [r for r in records if r.get("status") != "ok"]
    print(f"dsr.cohort: {len(records) - len(failed)} studies registered, {len(failed)} failed; "
          f"results in {os.path.join(args.out_dir, 'results.csv')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
