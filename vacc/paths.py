"""Where the shipped models are, for every command that takes ``--models``.

The order, first match wins:

1. ``$VACC_MODELS``, when set (to anything but the empty string);
2. ``./models``, when the current folder has one (a checkout, or a folder of your own);
3. the ``models/`` folder of the checkout vacc is installed from
   (``pip install -e .``), so an installed vacc finds the shipped models from any folder;
4. ``models`` (relative; the command then says that the models are missing).

``--models`` overrides all of them.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["MODELS_ENV", "MODELS_DEFAULT", "models_dir", "checkout_models"]

MODELS_ENV = "VACC_MODELS"
# click's show_default text for --models: the resolved folder depends on where vacc runs.
MODELS_DEFAULT = f"${MODELS_ENV}, else ./models, else the models/ of vacc's checkout"


def checkout_models() -> Path | None:
    """The ``models/`` folder of the checkout this package is imported from, or None.

    A checkout is recognised by its ``pyproject.toml`` next to the package folder, so a
    stray ``site-packages/models`` of some other distribution is never picked.
    """
    root = Path(__file__).resolve().parent.parent
    models = root / "models"
    return models if (root / "pyproject.toml").is_file() and models.is_dir() else None


def models_dir() -> Path:
    """The default models folder (see the module docstring for the order)."""
    env = os.environ.get(MODELS_ENV, "")
    if env:
        return Path(env)
    here = Path("models")
    if here.is_dir():
        return here
    return checkout_models() or here
