"""Setting top-level keys of a TOML file and keeping the rest of it as the person wrote it (comments, order,
tables): what ``headplod preview``'s ``w`` key does to the config file (``headplod.toml``, :mod:`headplod.config`).

Python reads TOML (``tomllib``) but writes none, and a full writer would drop the comments: this edits lines.
"""
from __future__ import annotations

try:
    import tomllib
except ModuleNotFoundError:          # Python 3.10: the same parser, as the tomli package
    import tomli as tomllib
from pathlib import Path
from typing import Mapping

from ._storage import write_atomically

__all__ = ["set_toml_keys", "TomlKeysError"]


class TomlKeysError(ValueError):
    """The file is not valid TOML, before or after the change (nothing is written); one line naming it."""


def _toml_value(value) -> str:
    """A number or a string as TOML (a whole number without '.0', as a person writes it)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise TypeError(f"a key's value is a number or a string here, got {value!r}")
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def _key_of(line: str) -> str | None:
    """The bare key a ``key = value`` line sets, or None (a comment, a table, a blank line)."""
    text = line.strip()
    if not text or text.startswith(("#", "[")) or "=" not in text:
        return None
    return text.split("=", 1)[0].strip()


def set_toml_keys(path, values: Mapping[str, object]) -> Path:
    """Set the top-level keys ``values`` (bare names; numbers or strings) in the TOML file ``path``.

    A key's line at the top level is replaced, or the key is added before the file's first table; the key's
    line in any table (``[preview]``, which wins over the top level in the config file) is replaced too. The
    other lines stay as they are. A missing file is made. The file is written whole under a temporary name,
    then renamed (:func:`~headplod.io.write_atomically`). Raises :class:`TomlKeysError` when the file is not
    valid TOML before or after (nothing is written) and OSError when it cannot be read or written.
    """
    path = Path(path)
    text = path.read_text(encoding="utf-8") if path.exists() else ""
    for label, candidate in (("is", text), ("would be", None)):
        if candidate is None:
            lines = text.splitlines()
            todo = dict(values)
            first_table = next((i for i, line in enumerate(lines) if line.lstrip().startswith("[")), len(lines))
            for i, line in enumerate(lines):
                name = _key_of(line)
                if name in values:
                    lines[i] = f"{name} = {_toml_value(values[name])}"
                    if i < first_table:
                        todo.pop(name, None)
            while first_table > 0 and not lines[first_table - 1].strip() and first_table < len(lines):
                first_table -= 1              # before the blank lines that part the top level from the tables
            lines[first_table:first_table] = [f"{name} = {_toml_value(v)}" for name, v in todo.items()]
            candidate = text = "\n".join(lines) + "\n"
        try:
            tomllib.loads(candidate)
        except tomllib.TOMLDecodeError as exc:    # e.g. a key spelled twice by hand: the file stays as it was
            raise TomlKeysError(f"{path}: {label} not valid TOML ({' '.join(str(exc).split())})") from None

    def write(name: str) -> None:
        with open(name, "w", encoding="utf-8") as f:
            f.write(text)
    write_atomically(path, write, suffix=".toml")
    return path
