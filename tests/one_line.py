"""The one-line error a command prints for a fault (``headplod: ...``), shared by the fault tests."""
from __future__ import annotations


def one_line_error(err: str) -> str:
    """The single ``headplod:`` line of ``err`` (asserting it is single and no traceback was printed)."""
    lines = [line for line in err.strip().splitlines() if line.startswith("headplod:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    return lines[0]
