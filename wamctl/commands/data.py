"""wamctl export / import (the measured-run format, docs/measured-run.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from wamctl.commands.common import console, emit_json


def export_cmd(run_dir: Annotated[Path, typer.Argument(help="A run directory.", show_default=False)],
               to: Annotated[Path, typer.Option("--to", help="Directory to write meta.yaml and data to.",
                                                show_default=False)],
               csv: Annotated[bool, typer.Option("--csv", help="Write data.csv instead of data.parquet.")] = False):
    """Export a run in the measured-run format (wamctl-measured/1): meta.yaml + data.parquet (or data.csv)."""
    from wamctl.runs.measured import export_run
    p = export_run(run_dir, to, "csv" if csv else "parquet")
    console.print(f"exported {run_dir} -> {p}", highlight=False, soft_wrap=True)   # paths whole


def import_cmd(
    source: Annotated[Path, typer.Argument(help="A measured-run directory (meta.yaml + data), or a log: libbarrett's "
                                           "exported CSV, a JSON list of JointState records, a ROS 1 .bag or a ROS 2 "
                                           "bag directory, a CSV.", show_default=False)],
    fmt: Annotated[str | None, typer.Option("--format", help="measured (a directory with meta.yaml: the default "
                                            "for a directory) | libbarrett-csv | jointstate-json | rosbag | csv | "
                                            "table (a headerless table of numbers, e.g. a recorder's .dat).",
                                            show_default=False)] = None,
    robot: Annotated[str | None, typer.Option("--robot", help="wam7 | wam4: the arm the log is of.",
                                              show_default=False)] = None,
    torque: Annotated[str | None, typer.Option("--torque", help="What the logged torque is: total (incl. gravity "
                                               "compensation: libbarrett's jtSum, wam_node's effort) | controller "
                                               "(the user's controller output; gravity compensation added "
                                               "downstream, not logged) | measured (a torque sensor).",
                                               show_default=False)] = None,
    layout: Annotated[str | None, typer.Option("--layout", help="libbarrett-csv, table: the columns, e.g. "
                                               "\"t,q_ref[4],qd_ref[4],q[4],qd[4],tau[4]\" (t q qd qdd tau q_ref "
                                               "qd_ref qdd_ref skip; [n]: n values, one per joint logged).",
                                               show_default=False)] = None,
    joints: Annotated[str | None, typer.Option("--joints", help="Which joints the log's joint vectors hold, e.g. "
                                               "2,4 (default: all of the robot's).", show_default=False)] = None,
    rate_hz: Annotated[float | None, typer.Option("--rate-hz", help="The logger's rate (libbarrett: 500 / "
                                                  "PERIOD_MULTIPLIER; required there); else checked against the "
                                                  "stamps, which give it when left out.", show_default=False)] = None,
    topic: Annotated[str | None, typer.Option("--topic", help="rosbag: the JointState topic (default: the only "
                                              "one).", show_default=False)] = None,
    columns: Annotated[str | None, typer.Option("--columns", help="csv: QUANTITY=COLUMN pairs, {j} the joint "
                                                "number, e.g. \"t=time,q=pos{j},tau=torque{j}\".",
                                                show_default=False)] = None,
    out: Annotated[Path, typer.Option("--out", help="Parent directory of the new run directory.")] = Path("runs"),
    name: Annotated[str, typer.Option("--name", help="Run name (default: the file's or directory's name).")] = "",
    json: Annotated[bool, typer.Option("--json", help="Print {\"run_dir\": ...} on stdout (for scripts).")] = False,
):
    """Store a measured run, or a lab's log, as a run directory, so `report` and the analyses take it like a
    simulated run. Errors name the key, column, line or record. See docs/measured-run.md."""
    from wamctl.errors import DataFormatError
    from wamctl.runs.importers import ImportOptions, import_log, parse_joints

    if fmt is None:
        if not (source.is_dir() and (source / "meta.yaml").is_file()):
            hint = " (a ROS 2 bag: --format rosbag)" if (source / "metadata.yaml").is_file() else ""
            raise DataFormatError(f"{source}: not a measured-run directory (no meta.yaml){hint}; a log needs "
                                  "--format libbarrett-csv | jointstate-json | rosbag | csv | table")
        fmt = "measured"
    opts = ImportOptions(format=fmt, robot=robot, torque=torque, joints=parse_joints(joints), rate_hz=rate_hz,
                         layout=layout, columns=columns, topic=topic)
    p, notes = import_log(source, opts, out, name or None)
    if json:
        emit_json({"run_dir": str(p)})
        return
    console.print(f"imported {source} -> {p}", highlight=False, soft_wrap=True)
    for note in notes:
        console.print(f"  {note}", highlight=False, soft_wrap=True)


def register(app: typer.Typer) -> None:
    app.command("export")(export_cmd)
    app.command("import")(import_cmd)
