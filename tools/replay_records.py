"""Replay synthetic sequences through ``headplod track`` and compare the pose records of two runs.

A refactoring's no-regression check: the records of a tree before and after
must agree bit for bit, or within a tolerance, except for the timings.

    python tools/replay_records.py write DIR        # track every case into DIR/<case>.jsonl
    python tools/replay_records.py compare A B      # every record of A against B's; exit 1 on a difference
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

CASES = {
    "looking_around": ["--source", "synthetic:looking_around"],
    "looking_around-no-tracking": ["--source", "synthetic:looking_around", "--no-tracking"],
    "looking_around-paper": ["--source", "synthetic:looking_around", "--estimator", "paper",
                             "--uncertainty", "paper_smoothed"],
    "looking_around-rigid": ["--source", "synthetic:looking_around", "--estimator", "rigid",
                             "--paper-detection"],
    "looking_around-paper-estimator": ["--source", "synthetic:looking_around", "--estimator", "paper"],
    "looking_around-rigid-estimator": ["--source", "synthetic:looking_around", "--estimator", "rigid",
                                       "--uncertainty", "first_order"],
    "glints_lamp": ["--source", "synthetic:glints_lamp"],
    "ordinary_webcams": ["--source", "synthetic:ordinary_webcams"],
    "imperfect_rig": ["--source", "synthetic:imperfect_rig"],
    "imperfect_rig-no-refine": ["--source", "synthetic:imperfect_rig", "--refine-rig", "off"],
    "fast_motion": ["--source", "synthetic:fast_motion"],
    "occlusion": ["--source", "synthetic:occlusion"],
    "random_mixed": ["--source", "synthetic:random_mixed"],
    "dim_ir": ["--source", "synthetic:dim_ir"],
    "neck_turns": ["--source", "synthetic:neck_turns"],
}
IGNORED = {"timings_ms", "latency_ms"}   # wall time: differs between any two runs
TOLERANCE = 1e-9                  # relative, for numbers


def write(out: Path, only: list[str]) -> int:
    out.mkdir(parents=True, exist_ok=True)
    for name, args in CASES.items():
        if only and name not in only:
            continue
        print(f"{name} ...", file=sys.stderr, flush=True)
        subprocess.run([sys.executable, "-c", "import sys; from headplod.cli import main; sys.exit(main())", "track", "--quiet", "--no-config", *args,
                        "--out", str(out / f"{name}.jsonl")], check=False,
                       stdout=subprocess.DEVNULL)
    return 0


def _differ(a, b, path: str) -> str | None:
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if key in IGNORED:
                continue
            if key not in a or key not in b:
                return f"{path}.{key}: only in one"
            d = _differ(a[key], b[key], f"{path}.{key}")
            if d:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path}: lengths {len(a)} and {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            d = _differ(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        if math.isclose(a, b, rel_tol=TOLERANCE, abs_tol=TOLERANCE) or (a != a and b != b):
            return None
        return f"{path}: {a!r} and {b!r}"
    return None if a == b else f"{path}: {a!r} and {b!r}"


def compare(a: Path, b: Path) -> int:
    bad = 0
    for fa in sorted(a.glob("*.jsonl")):
        fb = b / fa.name
        if not fb.exists():
            print(f"{fa.stem}: missing in {b}")
            bad += 1
            continue
        ra = [json.loads(x) for x in fa.read_text().splitlines() if x.strip()]
        rb = [json.loads(x) for x in fb.read_text().splitlines() if x.strip()]
        exact = sum(1 for x, y in zip(ra, rb) if {k: v for k, v in x.items() if k not in IGNORED}
                    == {k: v for k, v in y.items() if k not in IGNORED})
        diff = _differ(ra, rb, fa.stem)
        print(f"{fa.stem}: {len(ra)} records, {exact} bit for bit, "
              + ("all within tolerance" if diff is None else f"DIFFERS: {diff}"))
        bad += diff is not None
    return 1 if bad else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    w = sub.add_parser("write")
    w.add_argument("out", type=Path)
    w.add_argument("--only", nargs="*", default=[])
    c = sub.add_parser("compare")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    args = parser.parse_args()
    return write(args.out, args.only) if args.cmd == "write" else compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
