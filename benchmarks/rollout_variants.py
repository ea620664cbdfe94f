"""Evaluation files of the two variants measured against the worst rollout (issue 16,
docs/evaluation.md, "The worst rollout"): neither changes the default problem or the planner.

    .venv/bin/python benchmarks/rollout_variants.py [--output-dir out/rollout_variants]

- `evaluation_limits.yaml`: the base problem with `limits: {enforce: true}` (the default limits) and
  `timing: {step_s: 0.1, tracker_hz: 10}` (one observation per waypoint, the paper's belief model;
  at 0.05 s per step the enforced OCP is infeasible on many configurations,
  docs/motion_limits_and_export.md); the same files as benchmarks/evaluation_limits.py writes.
- `evaluation_Wo_block.yaml`: the base problem with the rotation's motion noise on the orientation
  block only, `W_o0 = diag(0, 0, 0, 1e-3, 1e-3, 1e-3)` (the paper's `1e-3 I` also puts 1e-3 m^2 of
  *position* variance per rad^2 of commanded rotation: 32 mm std for a 1 rad step, more than a 10 mm
  jaw can move by turning).

Prints the two paths. Evaluate each with `surestep evaluate FILE --configs 100 --rollouts 50 --seed
0 --jobs 2 --rollout-mode both --methods baseline ocp ocp-expected`.
"""

from __future__ import annotations

import harness as h

from pathlib import Path  # noqa: E402

import yaml  # noqa: E402

ROOT, EVAL = h.ROOT, h.EVALUATION


def write(out: Path) -> list[Path]:
    text = EVAL.read_text()
    if "base: ../needle_regrasp_paper_pace.yaml" not in text:
        raise SystemExit(f"{EVAL}: its base is no longer ../needle_regrasp.yaml; update "
                         "this script")
    paths = []
    for name, change in (("limits", {"limits": {"enforce": True},
                                     "timing": {"step_s": 0.1, "tracker_hz": 10.0}}),
                         ("Wo_block", {"noise": {"W_o0": [[1e-3 if i == j and i >= 3 else 0.0
                                                           for j in range(6)]
                                                          for i in range(6)]}})):
        base = yaml.safe_load(h.PAPER_PACE_PROBLEM.read_text())
        for key, value in change.items():
            base[key] = {**base.get(key, {}), **value} if key == "noise" else value
        h.write_result(out / f"needle_regrasp_{name}.yaml", yaml.safe_dump(base, sort_keys=False))
        paths.append(h.write_result(out / f"evaluation_{name}.yaml",
                                       text.replace("base: ../needle_regrasp_paper_pace.yaml",
                                                    f"base: needle_regrasp_{name}.yaml")))
    return paths


def main() -> None:
    ap = h.parser(__doc__)
    ap.add_argument("--output-dir", default=str(ROOT / "out" / "rollout_variants"))
    for p in write(Path(ap.parse_args().output_dir)):
        print(p)


if __name__ == "__main__":
    main()
