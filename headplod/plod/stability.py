"""Moved to :mod:`headplod.bench.stability` (it runs the tracker; ``headplod.plod`` is pure numpy).

An alias until the tests import from the new home; nothing else in
``headplod`` may import it (``tests/test_layout.py``).
``python -m headplod.bench.stability`` is the command now.
"""
import sys

from ..bench.stability import (ViewList, format_table, level_changes, levels_sequence, main, plot_stability,
                               stability_report, still_head_views, track_still_head)

__all__ = ["ViewList", "track_still_head", "still_head_views", "level_changes", "levels_sequence",
           "stability_report", "format_table", "plot_stability", "main"]

if __name__ == "__main__":
    sys.exit(main())
