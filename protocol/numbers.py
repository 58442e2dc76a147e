"""Numbers in vacc's text files (run logs, human-files) as vacc writes them.

Python's ``int()`` and ``float()`` also take ``1_0``, full-width digits and other
spellings that no vacc tool writes; a file holding one was edited by hand or by
another tool, and is refused rather than read as something it may not mean.
"""

from __future__ import annotations

import re

__all__ = ["PLAIN_INT", "PLAIN_FLOAT", "plain_int", "plain_float"]

PLAIN_INT = re.compile(r"\s*[+-]?[0-9]+\s*")
# digits, one '.', an exponent and a sign; nan/inf are read so that they are refused as
# non-finite (a clearer message) by the caller
PLAIN_FLOAT = re.compile(r"\s*[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\s*|\s*[+-]?(?:nan|inf|infinity)\s*", re.IGNORECASE)


def plain_int(text: str) -> int:
    """``int(text)`` for a plain decimal integer only.

    Raises:
        ValueError: anything else (``1_0``, ``1.0``, ``""``).
    """
    if PLAIN_INT.fullmatch(text) is None:
        raise ValueError(f"{text!r} is not a plain integer")
    return int(text)


def plain_float(text: str) -> float:
    """``float(text)`` for a plain decimal number (or nan/inf) only.

    Raises:
        ValueError: anything else (``1_0``, ``0x1p0``, ``""``).
    """
    if PLAIN_FLOAT.fullmatch(text) is None:
        raise ValueError(f"{text!r} is not a plain number")
    return float(text)
