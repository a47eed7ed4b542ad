"""Bad input never crashes: mutated specs, meta.yaml files, data files and model files thrown at ``validate``,
``run --dry-run``, ``import``, ``friction-id --data`` and ``diagnose`` (hypothesis). Every case ends with exit
code 0 or 2, no traceback, and on exit 2 only ``error: ...`` lines on stderr.

Mutations, as a user's files go wrong: keys dropped, renamed or given twice, values of another type (text,
lists, maps, NaN, infinities, huge and negative numbers), bytes flipped, files truncated, other encodings
(UTF-16, Latin-1, a byte-order mark), binary garbage; for the data: columns dropped, renamed or doubled, text
cells, NaN and inf, time running backwards, rows shuffled, another separator, a header alone, Parquet bytes
damaged. The commands run in-process (tests/cli_runs.py); the examples are drawn from a fixed seed
(``derandomize``), so a failure repeats.
"""

from __future__ import annotations

import copy
import io
import shutil

import numpy as np
import pandas as pd
import pytest
import yaml
from cli_runs import FRICTION, HMI, IFT, ROTATION, SWEEP, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.timeout(900)

FUZZ = settings(deadline=None, database=None, derandomize=True, print_blob=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])

CAN_SIM = {"kind": "rotation", "name": "can", "seed": 1,
           "backend": {"kind": "can", "interface": "virtual", "channel": "fuzz", "simulate_pucks": True},
           "rotation": {"joints": [2], "mode": "one_at_a_time", "amplitude_rad": -0.5, "hold_s": 0.2,
                        "settle_s": 0.0}}   # -0.5 rad: the return from +0.5 rad would saturate joint 2 (refused)
FF = {"kind": "rotation", "name": "ff", "controller": {"kind": "pd_g_ff", "friction_ff": "friction_model.yaml"},
      "plant": {"friction": "friction_model.yaml"}, "rotation": {"joints": [7], "hold_s": 0.2}}
SPECS = [ROTATION, FRICTION, IFT, HMI, SWEEP, CAN_SIM, FF]
FRICTION_FILE = {"format": "wamctl-friction/1",
                 "joints": {7: {"fc_pos_Nm": 0.05, "fc_neg_Nm": 0.14, "viscous_pos_Nm_s_rad": 1.07,
                                "viscous_neg_Nm_s_rad": 0.8}}}
MODEL_FILE = {"format": "wamctl-model/1", "friction": FRICTION_FILE,
              "effects": {"position_ripple": {"joints": [1], "amplitude_Nm": 0.3, "period_rad": 0.2}}}
META = {"format": "wamctl-measured/1", "robot": "wam7", "sample_rate_hz": 500.0, "gravity_compensation": True,
        "controller": {"kind": "pd_g", "kp": [900.0, 2500.0, 600.0, 500.0, 50.0, 50.0, 8.0],
                       "kd": [10.0, 20.0, 5.0, 2.0, 0.5, 0.5, 0.05]},
        "experiment": {"kind": "free", "joints": [1, 4]}, "q0": [0.0, 0.0, 0.0, 1.57, 0.0, 0.0, 0.0],
        "payload": {"mass_kg": 0.2, "com_m": [0.0, 0.0, 0.05]}, "notes": "fuzz"}


def measured_frame(n: int = 60) -> pd.DataFrame:
    """A short recording in the measured-run format (60 samples at 500 Hz: joints 1 and 4 moving)."""
    t = np.arange(n) / 500.0
    d = {"t": t}
    for j in range(1, 8):
        qr = (0.3 * np.sin(2 * np.pi * 2.0 * t + j) if j in (1, 4) else 0.0 * t) + (1.57 if j == 4 else 0.0)
        d.update({f"q_ref_{j}": qr, f"q_{j}": qr - 1e-3 * np.sin(t), f"tau_{j}": 2.0 * np.cos(3 * t + j)})
    return pd.DataFrame(d)


# ------------------------------------------------------------------------------------------------ mutations
SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-10**9, 10**9), st.sampled_from([-1, 0, 1, 7, 8, 2**63]),
                    st.floats(allow_nan=True, allow_infinity=True),
                    st.text(st.characters(blacklist_categories=("Cs",)), max_size=12))
VALUES = st.one_of(SCALARS, st.lists(SCALARS, max_size=8), st.dictionaries(st.text(max_size=6), SCALARS, max_size=3))


def key_paths(obj, prefix=()) -> list[tuple]:
    """Every path to a value inside nested mappings and lists."""
    out = []
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else []
    for k, v in items:
        out.append(prefix + (k,))
        out += key_paths(v, prefix + (k,))
    return out


def _parent(obj, path):
    for k in path[:-1]:
        obj = obj[k]
    return obj


@st.composite
def mutated_mapping(draw, base: dict) -> dict:
    """``base`` with up to three keys dropped, renamed, or given a value of another type."""
    obj = copy.deepcopy(base)
    for _ in range(draw(st.integers(0, 3))):
        paths = key_paths(obj)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent, key = _parent(obj, path), path[-1]
        op = draw(st.sampled_from(["drop", "rename", "value", "value"]))
        if op == "drop":
            del parent[key]
        elif op == "rename" and isinstance(parent, dict):
            parent[draw(st.text(st.characters(blacklist_categories=("Cs",)), min_size=1, max_size=10))] = \
                parent.pop(key)
        else:
            parent[key] = draw(VALUES)
    return obj


@st.composite
def text_damage(draw, text: str) -> str:
    """A line given twice (a duplicated key), or lines dropped."""
    lines = text.splitlines(keepends=True)
    if lines and draw(st.booleans()):
        i = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["duplicate", "drop"]))
        lines = lines[: i + 1] + lines[i:] if op == "duplicate" else lines[:i] + lines[i + 1:]
    return "".join(lines)


@st.composite
def byte_damage(draw, text: str) -> bytes:
    """``text`` encoded (UTF-8, with a BOM, UTF-16, Latin-1, cp1252), then maybe bytes flipped, truncated, or
    garbage inserted; or garbage alone."""
    if draw(st.integers(0, 19)) == 0:
        return draw(st.binary(max_size=300))
    enc = draw(st.sampled_from(["utf-8"] * 6 + ["utf-8-sig", "utf-16", "latin-1", "cp1252"]))
    if enc in ("latin-1", "cp1252") and draw(st.booleans()):
        text = text.replace("e", "\u00e9", 1)
    raw = bytearray(text.encode(enc, errors="replace"))
    op = draw(st.sampled_from(["none", "none", "flip", "truncate", "insert"]))
    if raw and op == "flip":
        for _ in range(draw(st.integers(1, 4))):
            i = draw(st.integers(0, len(raw) - 1))
            raw[i] ^= draw(st.integers(1, 255))
    elif raw and op == "truncate":
        raw = raw[: draw(st.integers(0, len(raw) - 1))]
    elif op == "insert":
        i = draw(st.integers(0, len(raw)))
        raw[i:i] = draw(st.binary(min_size=1, max_size=8))
    return bytes(raw)


@st.composite
def yaml_file(draw, base: dict) -> bytes:
    return draw(byte_damage(draw(text_damage(yaml.safe_dump(draw(mutated_mapping(base)), sort_keys=False)))))


@st.composite
def data_file(draw) -> tuple[str, bytes]:
    """(file name, bytes) of a damaged data.csv or data.parquet."""
    df = measured_frame()
    for _ in range(draw(st.integers(0, 2))):
        op = draw(st.sampled_from(["drop", "rename", "dup", "text", "nan", "inf", "backwards", "shuffle", "short",
                                   "int", "empty"]))
        col = draw(st.sampled_from(list(df.columns))) if len(df.columns) else None
        if col is None:
            break
        if op == "drop":
            df = df.drop(columns=[col])
        elif op == "rename":
            df = df.rename(columns={col: draw(st.text(max_size=8))})
        elif op == "dup":
            df = pd.concat([df, df[[col]]], axis=1)
        elif op in ("text", "nan", "inf") and len(df):
            rows = draw(st.lists(st.integers(0, len(df) - 1), min_size=1, max_size=20))
            df[col] = df[col].astype(object)
            df.loc[rows, col] = {"text": draw(st.text(max_size=6)), "nan": np.nan, "inf": np.inf}[op]
        elif op == "backwards" and len(df) > 2:
            i = draw(st.integers(1, len(df) - 1))
            df.loc[i, "t"] = df["t"].iloc[i - 1] - 0.01 if "t" in df else 0
        elif op == "shuffle":
            df = df.sample(frac=1.0, random_state=draw(st.integers(0, 9))).reset_index(drop=True)
        elif op == "short":
            df = df.iloc[: draw(st.integers(0, 12))]
        elif op == "int":
            df[col] = pd.to_numeric(df[col], errors="coerce").fillna(0).round().astype(int)
        elif op == "empty":
            df = df.iloc[:0]
    if draw(st.booleans()) and not df.columns.duplicated().any():    # Parquet cannot hold a doubled name
        buf = io.BytesIO()
        try:
            df.to_parquet(buf, index=False)
        except Exception:  # noqa: BLE001 - a frame pyarrow cannot store (mixed types): store it as text
            df = df.astype(str)
            buf = io.BytesIO()
            df.to_parquet(buf, index=False)
        raw = bytearray(buf.getvalue())
        if draw(st.booleans()):
            op = draw(st.sampled_from(["flip", "truncate"]))
            i = draw(st.integers(0, len(raw) - 1))
            if op == "flip":
                raw[i] ^= draw(st.integers(1, 255))
            else:
                raw = raw[:i]
        return "data.parquet", bytes(raw)
    sep = draw(st.sampled_from([","] * 8 + [";", "\t"]))
    text = df.to_csv(index=False, sep=sep)
    return "data.csv", draw(byte_damage(draw(text_damage(text))))


# ------------------------------------------------------------------------------------------------ the checks
def check(result, args) -> None:
    """The user's promise: exit 0 or 2, never a traceback; exit 2 says why in ``error:`` lines only."""
    assert result.exc is None, f"{args}: traceback\n{result.tb}"
    assert result.code in (0, 2), f"{args}: exit {result.code}\n{result.out[-1500:]}\n{result.err[-1500:]}"
    assert "Traceback" not in result.err, f"{args}:\n{result.err}"
    if result.code == 2:
        lines = [ln for ln in result.err.splitlines() if ln.strip()]
        assert lines and all(ln.startswith(("error:", "Usage:", "Try ")) or ln.startswith("│")
                             or ln.startswith("╭") or ln.startswith("╰") for ln in lines), f"{args}:\n{result.err}"


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    (d / "friction_model.yaml").write_text(yaml.safe_dump(FRICTION_FILE))
    m = d / "measured"
    m.mkdir()
    measured_frame().to_csv(m / "data.csv", index=False)
    (m / "meta.yaml").write_text(yaml.safe_dump(META, sort_keys=False))
    return d


def _measured(fuzz_dir, meta: bytes | None = None, data: tuple[str, bytes] | None = None):
    """A measured-run directory with the given meta.yaml and data file (the clean ones otherwise)."""
    m = fuzz_dir / "case"
    shutil.rmtree(m, ignore_errors=True)
    shutil.copytree(fuzz_dir / "measured", m)
    if meta is not None:
        (m / "meta.yaml").write_bytes(meta)
    if data is not None:
        (m / "data.csv").unlink()
        (m / data[0]).write_bytes(data[1])
    return m


def _out(fuzz_dir):
    out = fuzz_dir / "out"
    shutil.rmtree(out, ignore_errors=True)
    return out


DATA_COMMANDS = [("import", "{m}", "--out", "{out}"), ("friction-id", "--data", "{m}", "--out", "{out}"),
                 ("diagnose", "{m}", "--out", "{out}", "--quiet")]


def _run(fuzz_dir, command, m):
    args = [a.format(m=m, out=_out(fuzz_dir)) for a in command]
    check(run_cli(*args), args)


@settings(FUZZ, max_examples=900)
@given(data=st.data(), base=st.sampled_from(range(len(SPECS))), dry=st.booleans())
def test_mutated_specs_validate_and_dry_run(fuzz_dir, data, base, dry):
    spec = fuzz_dir / "spec.yaml"
    spec.write_bytes(data.draw(yaml_file(SPECS[base])))
    args = ["run", "--dry-run", spec] if dry else ["validate", spec]
    check(run_cli(*args), args)


@settings(FUZZ, max_examples=450)
@given(data=st.data(), command=st.sampled_from(DATA_COMMANDS))
def test_mutated_meta_yaml(fuzz_dir, data, command):
    _run(fuzz_dir, command, _measured(fuzz_dir, meta=data.draw(yaml_file(META))))


@settings(FUZZ, max_examples=600)
@given(data=st.data(), command=st.sampled_from(DATA_COMMANDS))
def test_mutated_data_files(fuzz_dir, data, command):
    _run(fuzz_dir, command, _measured(fuzz_dir, data=data.draw(data_file())))


@settings(FUZZ, max_examples=250)
@given(data=st.data(), which=st.sampled_from([FRICTION_FILE, MODEL_FILE]))
def test_mutated_model_files_for_diagnose(fuzz_dir, data, which):
    model = fuzz_dir / "model.yaml"
    model.write_bytes(data.draw(yaml_file(which)))
    args = ["diagnose", fuzz_dir / "measured", "--model", model, "--out", _out(fuzz_dir), "--quiet"]
    check(run_cli(*args), args)


def test_what_the_fuzz_found_stays_fixed(fuzz_dir):
    """Cases once found by hand or by the fuzz, each a one-line error and exit 2."""
    cases = {
        "binary spec": (b"\x89PNG\r\n\x1a\n\x00\x00garbage", "validate", "binary data"),
        "latin-1 spec": ("kind: rotation\nname: caf\u00e9\n".encode("latin-1"), "validate", "not UTF-8 text"),
        "duplicate key": (b"kind: rotation\nseed: 1\nseed: 2\n", "validate", "line 3, column 1: duplicate key 'seed'"),
        "seed -1": (b"kind: rotation\nseed: -1\n", "run", "seed = -1: Input should be greater than or equal to 0"),
        "missing friction file": (b"kind: rotation\nplant: {friction: nowhere.yaml}\n", "run",
                                  "plant.friction: friction model file not found: nowhere.yaml"),
        "q0 once": (b"kind: rotation\nq0_rad: [0, 0, 0, 9, 0, 0, 0]\n", "validate",
                    "spec.yaml: q0_rad: joint 4 would reach 9.0000 rad"),
    }
    spec = fuzz_dir / "spec.yaml"
    for name, (raw, cmd, expected) in cases.items():
        spec.write_bytes(raw)
        args = [cmd, "--dry-run", spec] if cmd == "run" else [cmd, spec]
        r = run_cli(*args)
        check(r, args)
        lines = [ln for ln in r.err.splitlines() if ln.strip()]
        assert r.code == 2 and len(lines) == 1 and expected in lines[0], (name, r.err)
    r = run_cli("validate", fuzz_dir)                                   # a directory given as the spec
    assert r.code == 2 and "is a directory" in r.err
    for out in (fuzz_dir / "friction_model.yaml", "/proc/no/such/place"):   # --out a file, or unwritable
        r = run_cli("import", fuzz_dir / "measured", "--out", out)
        check(r, ["import", out])
        assert r.code == 2 and ("is a file" in r.err or "cannot create" in r.err), r.err
    m = _measured(fuzz_dir, data=("data.csv", measured_frame().to_csv(index=False, sep=";").encode()))
    r = run_cli("import", m, "--out", _out(fuzz_dir))
    assert r.code == 2 and "separated by semicolons" in r.err, r.err
    df = measured_frame().astype(object)
    df.loc[9, "q_2"] = "abc"
    m = _measured(fuzz_dir, data=("data.csv", df.to_csv(index=False).encode()))
    r = run_cli("import", m, "--out", _out(fuzz_dir))
    assert r.code == 2 and "data row 10, column q_2: 'abc' is not a number" in r.err, r.err
