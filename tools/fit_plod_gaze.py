"""Fit the default PLOD mode's few settings at the true gaze on the training cases, and write the scores.

    python tools/fit_plod_gaze.py out/fit_gaze.json            # the fit behind SelectorConfig's defaults
    python tools/fit_plod_gaze.py out/fit_gaze.json --quick    # one screen, fewer fixations: a look

Every combination of :data:`headplod.bench.plod_gaze.FIT_GRID` is drawn with mode ``hybrid`` on the training
terrains and views (:data:`headplod.bench.plod_gaze.TRAINING`) on both screens, at two budgets, and judged by
FovVideoVDP at the viewer model's fixations; the chosen settings have the best mean margin over the best
geometric mode (``change_share`` 0 is ``sse``, so never below its mean: :func:`headplod.bench.plod_gaze.choose_settings`);
each combination's worst margin is written beside it. The held-out
report is ``headplod bench plod --only judge``. The JSON is written whole (a temporary name, then renamed).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from headplod.bench import plod_gaze as pg  # noqa: E402
from headplod.bench.outputs import write_json  # noqa: E402
from headplod.render.vdp import vdp_available  # noqa: E402
from headplod.progress import note  # noqa: E402

#: The budgets and fixations of the fit (``--quick``: fewer).
FIT_BUDGETS, FIT_FIXATIONS = (120_000, 300_000), 3
QUICK_FIXATIONS = 2


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="JSON to write")
    parser.add_argument("--quick", action="store_true", help="the desk screen only, fewer fixations")
    args = parser.parse_args(argv)
    if not vdp_available("fvvdp"):
        print("fit_plod_gaze: the judge (FovVideoVDP) is not installed: pip install -e '.[vdp]'", file=sys.stderr)
        return 2
    screens = ("desk",) if args.quick else tuple(pg.SCREENS)
    cases = pg.cases_of(("training",), screens)
    config = pg.GazeJudgeConfig(budgets=FIT_BUDGETS, fixations=QUICK_FIXATIONS if args.quick else FIT_FIXATIONS,
                                oracle=False, rings=False)
    fit = pg.fit_settings(cases, config=config, progress=note)
    fit["config"] = {"budgets": list(FIT_BUDGETS), "fixations": config.fixations, "quick": args.quick}
    write_json(args.out, fit)
    print(f"best: {fit['best']} ({len(cases)} cases); {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
