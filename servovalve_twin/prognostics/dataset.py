"""A sweep's dataset: ``dataset.csv`` and ``dataset.parquet`` (one row per run),
``traces.npz`` (per-run arrays, when asked for), ``summary.json`` (detection statistics per
fault and severity) and ``signature.png`` (peak indicators against severity, per fault).

Written as the runs finish: each row is appended to ``dataset.csv`` and each run's traces to
``traces.npz`` the moment it arrives, so a sweep stopped early -- Ctrl-C, a worker process
killed, a node of the cluster lost -- keeps every run that finished: the files are then
completed from those runs, in run order, and :class:`SweepStopped` says how many of how many.
"""

from __future__ import annotations

import csv
import json
import zipfile
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ..errors import TwinError
from ..outputs import DISK_FULL, discard_directory, output_file, output_path, write_failed
from .parallel import SchedulerLost, interrupt_code


class SweepStopped(TwinError):
    """A sweep that ended before its last run; its dataset holds the runs that finished.
    ``code``: the exit code (130 interrupted, 2 a worker lost)."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


def write_dataset(out: Path, results: Iterable[Mapping[str, Any]], total: int | None = None
                  ) -> dict[str, Any]:
    """Write the dataset of ``results`` (a stream, e.g. :func:`.sweep.iter_results`: rows are
    appended and traces written as they arrive, and dropped) into ``out``, a new or empty
    directory; returns the summary. Raises :class:`SweepStopped` after writing what finished
    when the stream is interrupted (KeyboardInterrupt) or loses a worker process."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise TwinError(f'{out} exists and is not an empty directory; give a new directory '
                        '(a sweep overwrites nothing)')
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    npz = stream = writer = None
    stopped = failed = None
    # the rows and traces stream into hidden files renamed into place once whole: a sweep
    # killed outright (SIGKILL, a power cut) leaves no dataset.csv or traces.npz that is a
    # part of one (it left a traces.npz that was not a zip file)
    csv_part, npz_part = out / '.dataset.csv.part', out / '.traces.npz.part'
    try:
        for r in results:
            row = dict(r['row'])
            if writer is None:
                stream = open(csv_part, 'x', newline='', encoding='utf-8')
                writer = csv.DictWriter(stream, fieldnames=list(row))
                writer.writeheader()
            writer.writerow(row)
            stream.flush()
            rows.append(row)
            if r.get('traces'):
                if npz is None:
                    npz = zipfile.ZipFile(npz_part, 'x', zipfile.ZIP_DEFLATED)
                for k, v in r['traces'].items():
                    # the .npy members np.savez_compressed writes, one at a time
                    with npz.open(f'run{row["run_id"]}_{k}.npy', 'w', force_zip64=True) as fh:
                        np.lib.format.write_array(fh, np.asanyarray(v), allow_pickle=False)
    except KeyboardInterrupt as exc:
        # Ctrl-C, or SIGTERM / SIGHUP (:class:`.parallel.Signalled`): 128 + the signal
        code = interrupt_code(exc)
        stopped = ('interrupted' if code == 130 else f'stopped by {exc}', code)
    except BrokenProcessPool:
        stopped = ('a worker process died (killed?)', 2)
    except SchedulerLost as exc:
        stopped = (str(exc), 2)
    except OSError as exc:
        if exc.errno not in DISK_FULL:
            raise
        failed = exc
    finally:
        for f in (npz, stream):
            if f is not None:
                try:
                    f.close()
                except OSError as exc:          # a full disk fails the close too
                    failed = failed or exc
    csv_part.unlink(missing_ok=True)            # _complete writes it anew, in run order
    try:
        if failed is not None:
            raise failed
        if npz is not None:
            npz_part.replace(out / 'traces.npz')
        summary = _complete(out, rows)
    except (OSError, TwinError) as exc:
        # a dataset is whole or absent (a full disk left a .dataset.csv.part and a
        # .traces.npz.part)
        discard_directory(out, created)
        if isinstance(exc, OSError):
            raise write_failed(out, exc, 'nothing of the sweep was kept') from None
        raise TwinError(f'{exc}; nothing of the sweep was kept') from None
    if stopped:
        what, code = stopped
        raise SweepStopped(f'{what} after {len(rows)} of {total or "?"} runs; {out} holds the '
                           f'{len(rows)} that finished', code)
    return summary


def _complete(out: Path, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The dataset in run order (the rows came in as the runs finished), as CSV and Parquet,
    its summary and signature plot."""
    rows.sort(key=lambda r: r['run_id'])
    if not rows:
        return summarize(rows)
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    with output_file(out / 'dataset.csv', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow(r)
    # the same table as Parquet (typed columns, quick to load into pandas or polars)
    import pyarrow as pa
    import pyarrow.parquet as pq
    with output_path(out / 'dataset.parquet') as tmp:
        pq.write_table(pa.table({c: [r.get(c) for r in rows] for c in cols}), str(tmp))
    summary = summarize(rows)
    with output_file(out / 'summary.json') as fh:
        fh.write(json.dumps(summary, indent=2) + '\n')
    with output_path(out / 'signature.png') as tmp:
        plot_signature(rows, tmp)
    return summary


def summarize(rows: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    rows = list(rows)
    nominal = [r for r in rows if not r['faulty']]
    out: dict[str, Any] = dict(
        runs=len(rows), nominal_runs=len(nominal),
        false_alarms=sum(r['alarm'] for r in nominal),
        false_alarm_rate=(sum(r['alarm'] for r in nominal) / len(nominal)) if nominal else None,
        faults={})
    by: dict[tuple[str, float], list] = {}
    for r in rows:
        if r['faulty']:
            by.setdefault((r['fault'], round(r['severity'], 9)), []).append(r)
    for (fault, sev), rs in sorted(by.items()):
        delays = [r['detection_delay'] for r in rs if r['alarm'] and not
                  np.isnan(r['detection_delay'])]
        out['faults'].setdefault(fault, []).append(dict(
            severity=sev, runs=len(rs), detection_rate=len(delays) / len(rs),
            alarms_before_onset=sum(r['alarm_before_onset'] for r in rs),
            mean_delay=float(np.mean(delays)) if delays else None,
            max_delay=float(np.max(delays)) if delays else None))
    return out


def plot_signature(rows: Sequence[Mapping[str, Any]], path: Path) -> None:
    """Fault signatures: each fault's peak residual indicators (XJ, DXJ, P12) against severity,
    nominal runs as the grey band -- which residual a fault moves, and how early."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    faults = sorted({r['fault'] for r in rows if r['faulty']})
    feats = (('peak_rms_xj', 'XJ [mm]', 1e3), ('peak_rms_dxj', 'DXJ [mm/s]', 1e3),
             ('peak_rms_p12', 'P12 [MPa]', 1e-6))
    if rows and 'peak_rms_xj' not in rows[0]:           # a user's algorithm: its outputs
        feats = tuple((k, k[len('peak_'):], 1.0) for k in rows[0] if k.startswith('peak_'))
    # (one fault made a 270 px figure whose title was cut at both edges)
    fig, axes = plt.subplots(len(feats), max(1, len(faults)),
                             figsize=(max(6.5, 3.0 * max(1, len(faults))), 7.0), squeeze=False)
    nominal = [r for r in rows if not r['faulty']]
    for j, fault in enumerate(faults):
        rs = [r for r in rows if r['fault'] == fault]
        for i, (key, label, k) in enumerate(feats):
            ax = axes[i][j]
            if nominal:
                # the nominal runs' range from 0 (peaks are >= 0), its top as a dashed line:
                # a band of a few micrometres was invisible under an axis starting higher
                vals = [r[key] * k for r in nominal]
                ax.axhspan(min(0.0, min(vals)), max(vals), color='0.85', zorder=0)
                ax.axhline(max(vals), color='0.4', lw=0.8, ls='--', zorder=1)
            ax.scatter([r['severity'] for r in rs], [r[key] * k for r in rs], s=12,
                       c=['C3' if r['alarm'] else 'C0' for r in rs], zorder=3)
            if nominal:
                ax.set_ylim(bottom=min(0.0, min(vals)))
            if i == 0:
                ax.set_title(fault, fontsize=8)
            if j == 0:
                ax.set_ylabel(f'peak {label}' if 'peak_rms_xj' not in rows[0] else
                              f'peak moving RMS\nresidual {label}', fontsize=8)
            if i == len(feats) - 1:
                ax.set_xlabel('severity', fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(True, lw=0.3)
    fig.suptitle('Fault signatures: red, alarm raised; grey band to the dashed line, the '
                 'nominal runs', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
