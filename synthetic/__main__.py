"""Command line: ``python -m synthetic render PRESET OUT_DIR [--frames N] [--seed S] [-q]``.

Other commands: ``python -m synthetic list`` prints the presets. The parser is
:mod:`synthetic.cli`, shared with ``headplod synth``.
"""
from .cli import main

if __name__ == "__main__":
    raise SystemExit(main())
