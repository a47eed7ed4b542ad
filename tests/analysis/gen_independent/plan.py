"""The study plan (a fixed, deterministic list of cases) and the command line."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml

from .arm import EFFECTS, JOINT_EFFECTS, LINK_MODES, PAIRS, SIZES
from .simulate import generate
from .truth import _plain


def _seed(seed, *parts):
    return int(np.random.SeedSequence([int(seed)] + [int(p) for p in parts]).generate_state(1)[0])


JOINT_CYCLE = (3, 1, 4, 6, 2, 7, 5)  # 1-based order in which joints are visited by pairs and clean runs


def cases(n_effect_runs_per_effect: int, n_clean: int, seed: int = 0, n_pairs: int | None = None) -> list[dict]:
    """The fixed, deterministic study plan (same arguments, same list): for each effect, n runs crossing joints (a
    seeded permutation, every joint once per 7 runs), sizes (small/medium/large in turn), excitation (sweep/free),
    log rate (500/250 Hz), noise (quiet/noisy) and jitter (stamp/loop) with different strides so that a small n still
    covers each factor; then n_pairs (default n) two-effect runs over ``PAIRS``; then n_clean runs without effects,
    links nominal / heavier_3_4 / random_10pct in turn. Each case carries its own seed."""
    out = []
    n = int(n_effect_runs_per_effect)
    for ei, name in enumerate(EFFECTS):
        perm = np.random.default_rng(_seed(seed, 4, ei)).permutation(7) + 1  # every joint once per 7 runs
        for i in range(n):
            joint = int(perm[i % 7])
            c = dict(id=f"{name}-{i:03d}", seed=_seed(seed, 1, ei, i),
                     effects=[dict(name=name, joint=joint if name in JOINT_EFFECTS else None,
                                   size=SIZES[i % 3])],
                     links="nominal", excitation=("sweep", "free")[(i // 3 + ei) % 2], joint=joint,
                     rate_hz=(500, 250)[(i // 2) % 2], noise=("quiet", "noisy")[(i // 6 + i) % 2],
                     jitter=("stamp", "stamp", "loop")[(i // 2 + ei) % 3])
            out.append(c)
    n_pairs = n if n_pairs is None else int(n_pairs)
    for i in range(n_pairs):
        a, b = PAIRS[i % len(PAIRS)]
        joint = JOINT_CYCLE[(i + 3) % 7]
        excitation = ("free", "sweep")[(i // len(PAIRS)) % 2]
        ja = joint if a in JOINT_EFFECTS else None
        jb = joint if b in JOINT_EFFECTS else None
        if ja and jb and excitation == "free" and i % 2:
            jb = JOINT_CYCLE[(i + 4) % 7]  # two joint effects on two different (moving) joints
        out.append(dict(id=f"pair-{a}+{b}-{i:03d}", seed=_seed(seed, 2, i),
                        effects=[dict(name=a, joint=ja, size=SIZES[(i + 1) % 3]),
                                 dict(name=b, joint=jb, size=SIZES[(i + 2) % 3])],
                        links="nominal", excitation=excitation, joint=joint, rate_hz=(500, 250)[i % 2],
                        noise=("quiet", "noisy")[(i // 2) % 2], jitter=("stamp", "stamp", "loop")[(i // 3) % 3]))
    for i in range(int(n_clean)):
        joint = JOINT_CYCLE[i % 7]
        out.append(dict(id=f"clean-{LINK_MODES[i % 3]}-{i:03d}", seed=_seed(seed, 3, i), effects=[],
                        links=LINK_MODES[i % 3], excitation=("sweep", "free")[(i // 3) % 2], joint=joint,
                        rate_hz=(500, 250)[(i // 2) % 2], noise=("quiet", "noisy")[(i // 4) % 2],
                        jitter=("stamp", "loop", "stamp")[i % 3]))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description="Generate the independent study plan's measured runs")
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--n", type=int, default=3, help="runs per effect (and per pair list); clean runs = n too")
    ap.add_argument("--n-clean", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", default=None, help="substring filter on case ids")
    args = ap.parse_args(argv)
    plan = cases(args.n, args.n if args.n_clean is None else args.n_clean, args.seed)
    if args.only:
        plan = [c for c in plan if args.only in c["id"]]
    args.out_dir.mkdir(parents=True, exist_ok=True)
    index = []
    for i, c in enumerate(plan):
        d = args.out_dir / f"run_{i:04d}"  # opaque names: the directory must not tell the effect
        r = generate(c, d)
        index.append(dict(dir=d.name, case_id=r.case_id, status=r.status, reason=r.reason,
                          expected_effects=r.expected_effects, rows=r.rows, arm_time_s=round(r.arm_time_s, 3),
                          wall_time_s=round(r.wall_time_s, 2)))
        print(f"{d.name} {r.case_id:40s} {r.status:12s} rows={r.rows:6d} {r.wall_time_s:5.2f}s", flush=True)
    with open(args.out_dir / "index.yaml", "w") as fh:
        yaml.safe_dump(_plain(index), fh, sort_keys=False)
    return 0

