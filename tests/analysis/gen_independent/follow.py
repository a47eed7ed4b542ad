"""A further run of a generated case's arm: the run ``wamctl diagnose`` proposed (``next_experiment.yaml``),
simulated with the SAME truth as the first run (plant, friction, link perturbation, effects and their parameters,
controller, log rate, noise profile and jitter mode), only the reference differing, and the noise and jitter drawn
anew (``noise_seed``).

The reference is evaluated by :class:`.excitation.DesignedRef` (the spec's documented Fourier series between two
holds), the closed loop and physics are this generator's own (:mod:`.simulate`); nothing here imports ``wamctl``.
What stays of the first run's truth, per effect: the drawn parameters (the same seed draws them again, and the
first truth's ``params`` are handed over as overrides); a friction drift keeps its shape and size over the new
run's own length (a warm-up starts again with each run); a gap behind the encoder keeps the first run's contact
stiffness and damping (not recomputed from the link inertia at the new start pose)."""

from __future__ import annotations

from pathlib import Path

import yaml

from .simulate import GeneratedRun, generate


def follow_up_case(first_truth: dict, spec: dict, noise_seed: int) -> dict:
    """The case of the designed run ``spec`` (an excitation spec mapping) on the arm of the run whose truth.yaml
    is ``first_truth``."""
    case = dict(first_truth["case"])
    case.update(id=f"{case.get('id', 'case')}-next", excitation="designed", reference=spec,
                noise_seed=int(noise_seed),
                effects=[{"name": e["name"], "joint": e["joint"], "size": e["size"], "params": dict(e["params"])}
                         for e in first_truth["effects"]])
    case.pop("free_joints", None)
    return case


def follow_up(first_dir: Path, spec_path: Path, out_dir: Path, noise_seed: int | None = None) -> GeneratedRun:
    """Simulate the designed run ``spec_path`` (next_experiment.yaml) on the arm of the generated run in
    ``first_dir`` into ``out_dir`` (meta.yaml, data.parquet, truth.yaml as :func:`.simulate.generate`).
    ``noise_seed`` default: the first case's seed + 1."""
    first = yaml.safe_load((Path(first_dir) / "truth.yaml").read_text())
    spec = yaml.safe_load(Path(spec_path).read_text())
    seed = int(first["case"]["seed"]) + 1 if noise_seed is None else int(noise_seed)
    return generate(follow_up_case(first, spec, seed), Path(out_dir))
