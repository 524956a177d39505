"""Write the tables of ``headplod bench track`` as Markdown, from its JSON, with the command and the date.

    headplod bench track --json out/bench_track.json --chart out/bench_track.png
    python tools/bench_track_tables.py out/bench_track.json docs/bench-track.md

The same as ``python tools/bench_tables.py track JSON PAGE``: ``tools/bench_tables.py`` makes the page of
every bench whose figures the docs show, and this name is kept for the commands already written down. The
figures in ``docs/bench-track.md`` are only ever that script's output: no measurement is copied by hand
into prose.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

_spec = importlib.util.spec_from_file_location("bench_tables", Path(__file__).resolve().parent / "bench_tables.py")
bench_tables = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_tables)

tables = bench_tables.track_page


def main(argv=None) -> int:
    return bench_tables.main(argv, prog="bench_track_tables", kind="track")


if __name__ == "__main__":
    sys.exit(main())
