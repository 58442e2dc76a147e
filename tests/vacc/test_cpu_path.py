"""The CPU kernels a rebuild is pinned to (`vacc reproduce --cpu-path`): each process starts fresh,
since torch fixes its kernels at its first computation."""

from __future__ import annotations

import functools
import subprocess
import sys

import pytest

pytestmark = pytest.mark.integration

SUM = """
import hashlib, sys, torch
from vacc.host import use_cpu_path
if sys.argv[1] == "late":
    torch.ones(3).add_(1)  # torch has computed: its kernels are fixed
kernels = use_cpu_path(sys.argv[2])
torch.manual_seed(0)
conv = torch.nn.Conv2d(8, 16, 5, stride=2)
out = conv(torch.randn(16, 8, 84, 84))
out.square().mean().backward()
print(kernels, hashlib.sha256(out.detach().numpy().tobytes() + conv.weight.grad.numpy().tobytes()).hexdigest())
"""


def _run(when: str, path: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", SUM, when, path], capture_output=True, text=True, timeout=120)


@functools.cache
def _native() -> str:
    return subprocess.run([sys.executable, "-c", "import torch; print(torch.backends.cpu.get_cpu_capability())"],
                          capture_output=True, text=True, timeout=120, check=True).stdout.strip()  # fmt: skip


def test_avx2_pins_the_kernels_and_their_rounding():
    pinned = _run("early", "avx2")
    assert pinned.returncode == 0, pinned.stderr
    kernels, digest = pinned.stdout.split()
    assert kernels in ("AVX2", "DEFAULT")  # DEFAULT: a CPU without AVX2
    assert _run("early", "avx2").stdout.split()[1] == digest  # the same, run after run
    native = _run("early", "native")
    assert native.stdout.split()[0] == _native()
    if _native() != "AVX2":  # on an AVX-512 CPU the widest kernels round otherwise, which is why recipes pin them
        assert native.stdout.split()[1] != digest


def test_pinning_after_torch_computed_is_refused_naming_the_variables():
    if _native() in ("AVX2", "DEFAULT"):
        pytest.skip("this CPU's own kernels are the pinned ones: nothing to refuse")
    late = _run("late", "avx2")
    assert late.returncode != 0 and f"torch already runs at {_native()} in this process" in late.stderr
    assert "ATEN_CPU_CAPABILITY=avx2 MKL_ENABLE_INSTRUCTIONS=AVX2 ONEDNN_MAX_CPU_ISA=AVX2" in late.stderr


@pytest.mark.slow
def test_vacc_gates_drives_its_runs_on_the_recipes_kernels(tmp_path):
    """The runs of `vacc gates` are worker processes of drive_jobs: they inherit the pin, so a
    report's figures are those the gates at the end of `vacc reproduce` give (AVX2 for ice-gap)."""
    import json

    worker = (  # a worker of a pool as drive_jobs's (fork)
        "import sys, torch\nfrom concurrent.futures import ProcessPoolExecutor\nfrom vacc.host import use_cpu_path\n"
        "use_cpu_path(sys.argv[1])\n"
        "def kernels():\n    torch.ones(2).add_(1)\n    return torch.backends.cpu.get_cpu_capability()\n"
        "with ProcessPoolExecutor(1) as pool:\n    print(pool.submit(kernels).result())\n"
    )
    got = subprocess.run([sys.executable, "-c", worker, "avx2"], capture_output=True, text=True, timeout=120)
    assert got.returncode == 0 and got.stdout.strip() in ("AVX2", "DEFAULT"), got.stderr
    done = subprocess.run([sys.executable, "-m", "vacc", "gates", "ice-gap", "--quick", "--jobs", "1", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode in (0, 1) and "on avx2 kernels" in done.stdout, done.stderr[-2000:]
    report = json.loads((tmp_path / "gates.json").read_text())
    assert report["cpu_path"] == "avx2" and report["kernels"] in ("AVX2", "DEFAULT")


@pytest.mark.slow
def test_vacc_gates_skips_a_set_of_runs_and_says_so(tmp_path):
    """--skip safety --skip random: only the tests' runs (and their energy and comfort), the
    report and the verdict line name what was left out."""
    import json

    done = subprocess.run([sys.executable, "-m", "vacc", "gates", "ice-gap", "--quick", "--skip", "safety", "--skip", "random", "--jobs", "1",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode in (0, 1) and "safety not checked (--skip); random not checked (--skip)" in done.stdout, done.stderr[-2000:]
    report = json.loads((tmp_path / "gates.json").read_text())
    assert report["skipped"] == ["safety", "random"] and {c["gate"] for c in report["checks"]} <= {"tests", "energy", "comfort"}
    assert sorted(p.name for p in (tmp_path / "logs").glob("*.csv")) == sorted(f"{m}-test-{i}.csv" for m in ("acc", "ddqn") for i in range(1, 5))
    assert not (tmp_path / "random").exists()
    bad = subprocess.run([sys.executable, "-m", "vacc", "gates", "ice-gap", "--skip", "tests", "--out", str(tmp_path / "x")], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "'tests' is not one of 'safety', 'random'" in bad.stderr
