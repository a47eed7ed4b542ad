"""Reports of gaze-HMI trial blocks: one run (per-location table, trials, hand paths), and a study over many runs.

Tables follow the thesis layouts: per location (Tables 6.2-6.4, 6.7, 6.8: locations as rows, each condition's
hit percentage and mean execution time as columns, then Mean, SD, SEM and n rows) and per subject (Table 6.10:
subjects as rows). They come from :class:`wamctl.analysis.hmi_results.HmiResults` (``summarise_trials``), so the
numbers and the ANOVA are those of the analysis module. ``mean_time_s`` is the mean over the attempts with a
recorded time: hits and misses (a grasp away from the object), not time-outs.

For a study over several ``hmi_block`` runs (subjects x conditions), :func:`results_from_runs` turns the run
directories into one :class:`~wamctl.analysis.hmi_results.HmiResults` and :func:`study_report` writes the
per-location and per-subject tables, the ANOVA and the bar charts (thesis Figures 6.28-6.29).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from wamctl.analysis.hmi_results import TRIAL_COLUMNS, HmiResults, summarise_trials
from wamctl.errors import DataFormatError
from wamctl.report.document import Document
from wamctl.runs.store import open_run

logger = logging.getLogger(__name__)

__all__ = ["read_trials", "trials_from_runs", "results_from_runs", "location_table", "subject_table", "report",
           "study_report"]


def read_trials(run_path: str | Path) -> pd.DataFrame:
    """The ``trials`` table of one ``hmi_block`` run directory (empty frame if no trial finished).

    Raises
    ------
    DataFormatError
        Not a run directory, or not an ``hmi_block`` run.
    """
    run_path = Path(run_path)
    manifest, _ = open_run(run_path)
    if manifest.get("kind") != "hmi_block":
        raise DataFormatError(f"{run_path}: not an hmi_block run (kind {manifest.get('kind')!r})")
    path = run_path / "trials.csv"
    if not path.is_file():
        return pd.DataFrame(columns=list(TRIAL_COLUMNS))
    df = pd.read_csv(path, dtype={"subject": str, "condition": str, "location": str})
    missing = [c for c in TRIAL_COLUMNS if c not in df.columns]
    if missing:
        raise DataFormatError(f"{path}: missing column(s) {missing}")
    return df


def trials_from_runs(run_dirs: Sequence[str | Path]) -> pd.DataFrame:
    """All trials of many ``hmi_block`` runs in one frame, with a ``run`` column (the directory name).

    A (subject, condition, location, attempt) found in two runs (the same block run twice) keeps the later run's
    trial and logs a warning.
    """
    frames = []
    for rd in run_dirs:
        df = read_trials(rd)
        if len(df):
            frames.append(df.assign(run=Path(rd).name))
    if not frames:
        raise DataFormatError("no trials in " + ", ".join(str(r) for r in run_dirs))
    out = pd.concat(frames, ignore_index=True)
    key = ["subject", "condition", "location", "attempt"]
    dup = out.duplicated(key, keep="last")
    if dup.any():
        logger.warning("%d trial(s) appear in several runs; keeping the later run's", int(dup.sum()))
        out = out[~dup].reset_index(drop=True)
    return out


def results_from_runs(run_dirs: Sequence[str | Path], unit: str | None = None) -> HmiResults:
    """One :class:`HmiResults` from many ``hmi_block`` runs (subjects x conditions).

    Parameters
    ----------
    run_dirs : sequence of paths
        ``hmi_block`` run directories.
    unit : {"subject", "location"} or None
        Summarise per subject (Table 6.10 layout) or per location pooled over subjects (Tables 6.2-6.4). Default:
        ``subject`` when the runs hold more than one subject, else ``location``.
    """
    trials = trials_from_runs(run_dirs)
    if unit is None:
        unit = "subject" if trials["subject"].nunique() > 1 else "location"
    return summarise_trials(trials[list(TRIAL_COLUMNS)], unit=unit, source=f"{len(run_dirs)} hmi_block runs")


def _combined_table(results: HmiResults) -> pd.DataFrame:
    """Hits (%) then mean time (s) per condition, side by side (the thesis' two-part tables)."""
    hits = results.table("hit_pct")
    times = results.table("mean_time_s")
    single = len(results.conditions) == 1
    hits.columns = ["hit_pct" if single else f"hit_pct {c}" for c in hits.columns]
    times.columns = ["mean_time_s" if single else f"mean_time_s {c}" for c in times.columns]
    out = pd.concat([hits, times], axis=1)
    out.index.name = results.unit_kind
    return out


def location_table(trials: pd.DataFrame) -> pd.DataFrame:
    """Per-location hits (%) and mean execution time (s) for each condition, pooled over subjects, with Mean, SD,
    SEM and n rows (Tables 6.2-6.4 layout)."""
    return _combined_table(summarise_trials(trials[list(TRIAL_COLUMNS)], unit="location"))


def subject_table(trials: pd.DataFrame) -> pd.DataFrame:
    """Per-subject hits (%) and mean execution time (s) for each condition (Table 6.10 layout)."""
    return _combined_table(summarise_trials(trials[list(TRIAL_COLUMNS)], unit="subject"))


def _trajectory_figure(run_path: Path, trials: pd.DataFrame, spec: dict, out_dir: Path) -> Path | None:
    from wamctl.report.figures import plt, save
    from wamctl.runs.store import read_table

    try:
        traj = read_table(run_path, "trajectory")
    except DataFormatError:
        return None
    if not len(traj):
        return None
    h = spec.get("hmi") or {}
    fig, ax = plt.subplots(figsize=(7.0, 6.0))
    ws = h.get("workspace") or {}
    if ws:
        (x0, x1), (y0, y1) = ws["x_m"], ws["y_m"]
        ax.plot([y0, y1, y1, y0, y0], [x0, x0, x1, x1, x0], color="0.6", lw=0.8, label="workspace")
    radius = float(h.get("hit_radius_m", 0.03))
    for loc, (x, y) in (h.get("targets_m") or {}).items():
        ax.add_patch(plt.Circle((y, x), radius, fill=False, color="tab:green", lw=1.0))
        ax.annotate(loc, (y, x), textcoords="offset points", xytext=(6, 6), fontsize=9)
    if h.get("start_m"):
        ax.plot(h["start_m"][1], h["start_m"][0], "k+", ms=12, mew=2, label="start")
    outcome = dict(zip(trials["trial"], trials["outcome"])) if len(trials) else {}
    colours = {"hit": "tab:blue", "miss": "tab:red", "timeout": "tab:orange"}
    for n, g in traj.groupby("trial"):
        ax.plot(g["hand_y_m"], g["hand_x_m"], lw=0.9, color=colours.get(outcome.get(int(n)), "0.5"), alpha=0.8)
    for k, c in colours.items():
        ax.plot([], [], color=c, label=k)
    ax.set_xlabel("y (m), the arm's left")
    ax.set_ylabel("x (m), forward")
    ax.invert_xaxis()
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("Hand paths on the table (grasp centre), hit circles")
    return save(fig, out_dir / "hmi_paths.png")


def report(run_path: Path, manifest: dict, spec: dict, out_dir: Path | None = None) -> Document:
    """Report of one ``hmi_block`` run: per-location table, the trials, hand paths."""
    run_path = Path(run_path)
    out_dir = Path(out_dir or run_path)
    trials = read_trials(run_path)
    h = spec.get("hmi") or {}
    info = manifest.get("hmi") or {}
    doc = Document(f"Gaze HMI block: {manifest.get('name', run_path.name)}")
    doc.text(f"Run {run_path.name}: status {manifest.get('status')}; subject {info.get('subject', '?')}, condition "
             f"{info.get('condition', '?')} ({info.get('strategy', '?')} control, filter {info.get('filter', '?')}, "
             f"{info.get('profile', '?')} profile), {info.get('source', '?')} gaze source; "
             f"{len(trials)} of {info.get('trials_planned', '?')} trials done"
             + (f"; session ended: {info['session_end']}" if info.get("session_end") not in (None, "completed")
                else "") + ".")
    if manifest.get("reason"):
        doc.text(f"Reason: {manifest['reason']}.")
    gaze_stream_section(doc, run_path)
    if not len(trials):
        doc.text("No trial finished.")
        return doc
    n = len(trials)
    hits = int(trials["hit"].sum())
    times = trials["time_s"].dropna()
    hit_times = trials.loc[trials["hit"] == 1, "time_s"].dropna()
    doc.data["hmi"] = {"trials": n, "hits": hits, "hit_pct": 100.0 * hits / n,
                       "mean_time_s": float(times.mean()) if len(times) else None,
                       "mean_hit_time_s": float(hit_times.mean()) if len(hit_times) else None,
                       "timeouts": int((trials["outcome"] == "timeout").sum())}
    doc.text(f"{hits} hits in {n} trials ({100.0 * hits / n:.1f} %); mean execution time "
             f"{times.mean():.2f} s over the grasps ({len(times)}), "
             f"{hit_times.mean() if len(hit_times) else math.nan:.2f} s "
             f"over the hits; {int((trials['outcome'] == 'timeout').sum())} time-out(s). Hit: the hand closed with "
             f"its grasp centre within {1e3 * float(h.get('hit_radius_m', 0.03)):.0f} mm of the object before "
             f"{float(h.get('timeout_s', 60)):g} s; execution time: from the trial start to the hand closed.")
    doc.heading("Per location (thesis Tables 6.2-6.4 layout)")
    doc.table("by_location", location_table(trials),
              "hit_pct: hits (%); mean_time_s: mean execution time of the grasps (s). Mean, SD (ddof 1), SEM and "
              "n over the locations (the thesis' rows labelled SEM hold the SD).", digits=2)
    if trials["subject"].nunique() > 1:
        doc.heading("Per subject (thesis Table 6.10 layout)")
        doc.table("by_subject", subject_table(trials), digits=2)
    doc.heading("Trials")
    cols = ["trial", "location", "attempt", "outcome", "hit", "time_s", "error_m", "path_m", "n_blinks",
            "n_voluntary_blinks", "n_stalls", "max_tilt_deg"]
    t = trials[cols].copy()
    t["error_mm"] = 1e3 * t.pop("error_m")
    doc.table("trials", t.set_index("trial"), "error_mm: grasp centre to object when the hand closed (at the "
              "time-out for a time-out); path_m: length of the hand's path; max_tilt_deg: largest deviation of the "
              "palm from facing down.", digits=3)
    fig = _trajectory_figure(run_path, trials, spec, out_dir)
    if fig is not None:
        doc.figure(fig, "hand paths (blue hit, red miss, orange time-out), seen from above with x forward")
    return doc


#: What each error count of the gaze stream means, for the report.
_STREAM_ROWS = (
    ("bytes", "bytes received"), ("samples", "samples decoded"), ("valid", "valid gaze points"),
    ("blink", "blink samples"), ("out_of_range", "outside the image"), ("corrupt", "corrupt (unreadable) samples"),
    ("garbage_bytes", "bytes outside any frame"), ("cut_frames", "frames cut short (bytes lost)"),
    ("bad_frames", "frames of the right length that break the format"),
    ("dropped_frames", "frames the tracker's counter says never arrived"),
    ("clock_adjusts", "frame counter restarts or jumps"),
)


def gaze_stream_section(doc: Document, run_path: Path) -> None:
    """The gaze stream's diagnostics (``gaze_stream.json``, written when a decoded stream closes): what was
    received, the framing and decode errors with their first examples in hex, and where the raw bytes are."""
    path = Path(run_path) / "gaze_stream.json"
    if not path.is_file():
        return
    try:
        info = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        doc.text(f"gaze_stream.json is not readable ({exc}).")
        return
    stats = info.get("stats") or {}
    doc.heading("Gaze stream")
    settings = info.get("settings") or {}
    where = (f" from {settings.get('url')} at {settings.get('baudrate')} Bd {settings.get('bytesize')}"
             f"{settings.get('parity')}{settings.get('stopbits')}" if settings else "")
    rate = f", {info['bytes_per_s']:g} B/s" if info.get("bytes_per_s") else ""
    doc.text(f"{info.get('source')} source{where}, format {info.get('format')}{rate}; "
             f"{info.get('errors', 0)} framing/decode error(s). Every decoded frame is in "
             f"{info.get('samples_file', 'gaze_samples.csv')} (arrival time, sample time, gaze, flags, raw fields)"
             + (f"; the raw bytes of every read are in {info['capture_file']} (replay them with a `replay-raw` "
                f"source, or check them with `wamctl gaze-check --from-capture {info['capture_file']}`)"
                if info.get("capture_file") else "") + ".")
    rows = [(what, stats[k]) for k, what in _STREAM_ROWS if k in stats]
    if rows:
        doc.table("gaze_stream", pd.DataFrame(rows, columns=["count", "n"]).set_index("count"), digits=0)
    doc.data["gaze_stream"] = {k: stats.get(k) for k, _ in _STREAM_ROWS} | {"errors": info.get("errors")}
    frames = max(int(stats.get("frames") or 0), 1)
    if stats.get("garbage_bytes", 0) >= frames and stats.get("frames"):
        doc.text(f"{stats['garbage_bytes'] / frames:.1f} bytes outside frames per frame: the configured format or "
                 f"items may not match the tracker's (check the capture with gaze-check).")
    examples = [(kind, e) for kind, es in (stats.get("examples") or {}).items() for e in es]
    if examples:
        doc.table("gaze_stream_examples", pd.DataFrame(examples, columns=["kind", "first examples (hex)"])
                  .set_index("kind"), "The first examples of each kind of error, bytes in hex.")
    for k, earlier in enumerate(info.get("earlier_sessions") or [], start=1):
        es = earlier.get("stats") or {}
        doc.text(f"Earlier session {k} (before a resume): {es.get('samples', 0)} samples, "
                 f"{earlier.get('errors', 0)} error(s), {es.get('garbage_bytes', 0)} bytes outside frames.")


def study_report(run_dirs: Sequence[str | Path], out_dir: str | Path | None = None,
                 doc: Document | None = None) -> Document:
    """Per-location and per-subject tables, ANOVA and bar charts over several ``hmi_block`` runs.

    Parameters
    ----------
    run_dirs : sequence of paths
        ``hmi_block`` run directories (e.g. subjects x conditions); other kinds are skipped.
    out_dir : path or None
        Where the bar charts go (no figure if None).
    doc : Document or None
        Append to this document (e.g. the combined report) instead of a new one.
    """
    hmi_runs = []
    for rd in run_dirs:
        try:
            m, _ = open_run(rd)
        except DataFormatError:
            continue
        if m.get("kind") == "hmi_block":
            hmi_runs.append(Path(rd))
    doc = doc if doc is not None else Document(f"Gaze HMI study over {len(hmi_runs)} runs")
    if not hmi_runs:
        return doc
    trials = trials_from_runs(hmi_runs)
    subjects = list(pd.unique(trials["subject"]))
    conditions = list(pd.unique(trials["condition"]))
    doc.heading("Gaze HMI study")
    doc.text(f"{len(trials)} trials from {len(hmi_runs)} hmi_block runs: {len(subjects)} subject(s) "
             f"({', '.join(map(str, subjects))}) x {len(conditions)} condition(s) ({', '.join(conditions)}).")
    doc.table("hmi_by_location", location_table(trials),
              "Per location, pooled over subjects: hits (%) and mean execution time (s) per condition.", digits=2)
    by_subject = summarise_trials(trials[list(TRIAL_COLUMNS)], unit="subject")
    doc.table("hmi_by_subject", _combined_table(by_subject),
              "Per subject (Table 6.10 layout): hits (%) and mean execution time (s) per condition.", digits=2)
    unit_results = by_subject if len(subjects) > 1 else summarise_trials(trials[list(TRIAL_COLUMNS)], unit="location")
    doc.data["hmi_study"] = {"subjects": [str(s) for s in subjects], "conditions": conditions,
                             "trials": int(len(trials)), "hit_pct": float(100.0 * trials["hit"].mean())}
    if len(conditions) > 1:
        from wamctl.report.hmi_stats import add_hmi_analysis
        add_hmi_analysis(doc, unit_results, Path(out_dir) if out_dir is not None else None, "hmi",
                         unit_tables=False)
    return doc
