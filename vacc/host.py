"""The machine a run ran on, for its records (`vacc bench`, `vacc reproduce`)."""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path
from typing import Any

__all__ = ["CPU_PATHS", "PINNED", "cpu_model", "describe", "label", "pinned_path", "use_cpu_path"]

CPU_PATHS: dict[str, dict[str, str]] = {
    # torch's own kernels, MKL and oneDNN kept to AVX2, which every x86-64 CPU since 2013 runs: an
    # AVX-512 CPU's kernels round otherwise, and a training drifts apart within 10 k steps
    "avx2": {"ATEN_CPU_CAPABILITY": "avx2", "MKL_ENABLE_INSTRUCTIONS": "AVX2", "ONEDNN_MAX_CPU_ISA": "AVX2"},
    # AVX-512's common level (no VNNI or BF16, which f32 training does not use): where a stage was made on one
    "avx512": {"ATEN_CPU_CAPABILITY": "avx512", "MKL_ENABLE_INSTRUCTIONS": "AVX512", "ONEDNN_MAX_CPU_ISA": "AVX512_CORE"},
    "native": {},  # the machine's widest kernels: faster on some CPUs, bit for bit only with the same CPU
}
"""The CPU code paths a training can be pinned to (``vacc reproduce --cpu-path``)."""

PINNED = "VACC_CPU_PATH"  # the path this process was pinned to; children inherit it (a fresh one starts unpinned)


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
    """``{"cpu", "cores", "gpu"}``; ``gpu`` is the first CUDA device's name, or None; with torch
    loaded, also ``kernels``, the CPU capability its kernels run at (``AVX2``, ``AVX512``)."""
    gpu = None
    if with_gpu:
        import torch

        gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    found = {"cpu": cpu_model(), "cores": os.cpu_count(), "gpu": gpu}
    if "torch" in sys.modules:
        found["kernels"] = sys.modules["torch"].backends.cpu.get_cpu_capability()
    return found


def use_cpu_path(name: str) -> str:
    """Pin this process's and its children's kernels to :data:`CPU_PATHS` ``[name]``; returns
    the capability torch's kernels now run at. It holds only where torch has computed nothing yet.

    Raises:
        RuntimeError: torch already runs this process's kernels at another capability.
    """
    import torch

    for variable in {k for path in CPU_PATHS.values() for k in path}:  # "native" sets none: none left from a shell
        os.environ.pop(variable, None)
    os.environ.update(CPU_PATHS[name])
    got = torch.backends.cpu.get_cpu_capability()
    want = CPU_PATHS[name].get("ATEN_CPU_CAPABILITY", "").upper()
    if want and got not in (want, "DEFAULT"):  # DEFAULT: a CPU without it
        raise RuntimeError(f"torch already runs at {got} in this process: start it with " + " ".join(f"{k}={v}" for k, v in CPU_PATHS[name].items()))
    os.environ[PINNED] = name
    return got


def pinned_path() -> str:
    """The :data:`CPU_PATHS` name this process was pinned to; ``native`` where none was."""
    return os.environ.get(PINNED, "native")


def label(host: dict[str, Any]) -> str:
    """One line: ``AMD EPYC 7B13, 2 cores, no GPU``."""
    return f"{host['cpu']}, {host['cores']} cores, " + (host["gpu"] or "no GPU")
