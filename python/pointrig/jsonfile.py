"""Reading a JSON file with the one-line errors of :mod:`pointrig.errors`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .errors import InputError

__all__ = ["read_json"]


def read_json(path: str | Path, *, missing: str, invalid: str,
              error: type[InputError] = InputError) -> Any:
    """The parsed content of the JSON file ``path``.

    Parameters
    ----------
    path
        The file.
    missing
        Message when the file does not exist (an :class:`InputError` naming ``path``).
    invalid
        Message prefix when the file is not JSON (or not UTF-8); the parser's reason follows
        after ``": "``.
    error
        Class of the not-JSON error (an :class:`InputError` subclass, e.g. ``FormatError``).

    Raises
    ------
    InputError
        Missing file, or ``error`` when the content is not JSON.
    """
    p = Path(path)
    try:
        return json.loads(p.read_text())
    except FileNotFoundError:
        raise InputError(missing, p) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{invalid}: {exc}", p) from None
