"""The machine a run ran on, for its records (`vacc bench`, `vacc reproduce`)."""

from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Any

__all__ = ["cpu_model", "describe", "label"]


def cpu_model() -> str:
    """The CPU's model name, from ``/proc/cpuinfo`` where there is one."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def describe(with_gpu: bool = True) -> dict[str, Any]:
    """``{"cpu", "cores", "gpu"}``; ``gpu`` is the first CUDA device's name, or None."""
    gpu = None
    if with_gpu:
        import torch

        gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "gpu": gpu}


def label(host: dict[str, Any]) -> str:
    """One line: ``AMD EPYC 7B13, 2 cores, no GPU``."""
    return f"{host['cpu']}, {host['cores']} cores, " + (host["gpu"] or "no GPU")
